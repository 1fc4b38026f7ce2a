"""The one definition of a reach crossing an obstacle (rmpfusion/scenes/crossing.py): the segment's clearance from
every shape's surface, checked against closed forms and against a dense sampling of the segment."""

from __future__ import annotations

import pytest
import torch

import rmpfusion  # noqa: F401  (registers the distance maps)
from rmpfusion.scenes import Scene, scene_aux
from rmpfusion.scenes.crossing import crosses, segment_clearance, summarize

CYLINDER = Scene(obstacles=[{"type": "cylinder", "center": [0.5, 0.0, 0.3], "radius": 0.05, "height": 0.6}])


def _aux(scene: Scene, n: int) -> dict:
    centres = torch.tensor([o.center for o in scene.obstacles], dtype=torch.float64).expand(n, -1, -1)
    return scene_aux(scene, centres, torch.float64)


def _segments(rows) -> tuple[torch.Tensor, torch.Tensor]:
    t = torch.tensor(rows, dtype=torch.float64)
    return t[:, 0], t[:, 1]


def test_a_cylinders_clearance_is_the_distance_from_its_axis_inside_its_height_and_from_its_cap_above():
    start, end = _segments(
        [
            [[0.2, 0.12, 0.3], [0.8, 0.12, 0.3]],  # beside the axis at 0.12 m, inside the height: 0.12 − 0.05
            [[0.2, -0.3, 0.3], [0.8, 0.3, 0.3]],  # diagonally through the axis: −radius
            [[0.2, 0.0, 0.68], [0.8, 0.0, 0.68]],  # over the top cap (z = 0.6) by 0.08 m
            [[0.2, 0.3, 0.3], [0.3, 0.3, 0.3]],  # ends before the cylinder: its end's distance
        ]
    )
    got = segment_clearance(CYLINDER, _aux(CYLINDER, 4), start, end)[:, 0]
    far = ((0.5 - 0.3) ** 2 + 0.3**2) ** 0.5 - 0.05
    torch.testing.assert_close(got, torch.tensor([0.07, -0.05, 0.08, far], dtype=torch.float64), atol=1e-9, rtol=0)
    assert crosses(got[:, None], 0.095).tolist() == [True, True, True, False]
    assert crosses(got[:, None], 0.06).tolist() == [False, True, False, False]


@pytest.mark.parametrize(
    "obstacle",
    [
        {"type": "sphere", "center": [0.5, 0.1, 0.3], "radius": 0.07},
        {"type": "box", "center": [0.5, 0.0, 0.3], "half_extents": [0.04, 0.08, 0.3], "rpy": [0.1, 0.0, 0.5]},
        {"type": "capsule", "center": [0.45, 0.05, 0.25], "radius": 0.06, "length": 0.4, "axis": [-0.2, 0.0, 1.0]},
        {"type": "cylinder", "center": [0.5, 0.0, 0.3], "radius": 0.05, "height": 0.6, "axis": [0.3, 0.1, 1.0]},
    ],
)
def test_every_shapes_segment_clearance_is_the_least_distance_along_the_segment(obstacle):
    scene = Scene(obstacles=[obstacle])
    g = torch.Generator().manual_seed(0)
    n = 16
    start = torch.tensor([0.5, 0.0, 0.3], dtype=torch.float64) + 0.5 * (
        torch.rand(n, 3, generator=g, dtype=torch.float64) - 0.5
    )
    end = torch.tensor([0.5, 0.0, 0.3], dtype=torch.float64) + 0.6 * (
        torch.rand(n, 3, generator=g, dtype=torch.float64) - 0.5
    )
    aux = _aux(scene, n)
    got = segment_clearance(scene, aux, start, end)[:, 0]
    # independent: the distance at 20001 points of each segment, the least of them
    from rmpfusion.scenes import distances

    t = torch.linspace(0, 1, 20001, dtype=torch.float64)
    dense = torch.stack(
        [
            distances(
                scene,
                {k: v[b : b + 1].expand(len(t), -1) for k, v in aux.items()},
                start[b] + t[:, None] * (end[b] - start[b]),
            )[:, 0].min()
            for b in range(n)
        ]
    )
    assert (got <= dense + 1e-12).all()  # never above a sampled distance
    # a point of the grid lies within half a spacing (≤ 2e-5 m on these segments) of the least one, and a
    # distance changes at most at slope 1
    torch.testing.assert_close(got, dense, atol=3e-5, rtol=0)


def test_the_summary_counts_paths_within_the_radius_and_gives_their_clearance_distribution():
    clearance = torch.tensor([[0.01, 0.5], [0.2, 0.3], [-0.02, 0.1], [0.09, 0.4]], dtype=torch.float64)
    s = summarize(clearance, 0.095)
    assert s.paths == 4 and s.crossing_fraction == 0.75
    assert s.clearance_quantiles["min"] == pytest.approx(-0.02)
    assert s.clearance_quantiles["max"] == pytest.approx(0.2)
    assert s.clearance_quantiles["median"] == pytest.approx((0.01 + 0.09) / 2)
