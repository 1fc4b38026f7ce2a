"""Each control point's nearest members of an obstacle set (scenes/nearest.py): the selection against a brute-force
sort of independently measured distances, and the tree reading k members per control point against the tree reading
all N_max of them, equal in values and gradients wherever the members left out lie beyond the barrier's support."""

from __future__ import annotations

import pytest
import torch
import yaml
from conftest import ROOT
from test_clouds import _panda_tree

from rmpfusion.envs.manipulator_tree import copy_weights
from rmpfusion.robots import RobotDescription, build_robot
from rmpfusion.scenes import ObstacleSet, sets_read, with_slots
from rmpfusion.scenes.nearest import member_distances, nearest_members, selection_exact
from rmpfusion.scenes.sets import set_distances

N, K = 30, 4
#: the obstacle barrier's support in conf/tree/arm_reach.yaml (obstacle_rmp.r_w)
SUPPORT = yaml.safe_load((ROOT / "conf/tree/arm_reach.yaml").read_text())["obstacle_rmp"]["r_w"]


def panda():
    return build_robot(RobotDescription.model_validate(yaml.safe_load((ROOT / "conf/robot/panda.yaml").read_text())))


def scattered(s: ObstacleSet, B: int, seed: int, present: float = 0.8) -> dict[str, torch.Tensor]:
    """A set's tensors for ``B`` samples: members anywhere in a 1.6 m cube around the arm, some absent."""
    g = torch.Generator().manual_seed(seed)
    out = {}
    for f, k in s.fields().items():
        t = torch.rand(B, s.n_max, k, generator=g, dtype=torch.float64)
        if f == "center":
            t = (t - 0.5) * 1.6 + torch.tensor([0.3, 0.0, 0.5], dtype=torch.float64)
        elif f in ("radius", "half_height", "half_length"):
            t = 0.02 + 0.05 * t
        elif f == "half_extents":
            t = 0.02 + 0.08 * t
        elif f in ("axis", "normal"):
            t = torch.nn.functional.normalize(t - 0.5, dim=-1)
        elif f == "rotation":
            t = torch.linalg.qr(torch.randn(B, s.n_max, 3, 3, generator=g, dtype=torch.float64))[0].reshape(B, -1, 9)
        out[f"{s.prefix}_{f}"] = t
    out[f"{s.prefix}_mask"] = (torch.rand(B, s.n_max, generator=g) < present).double()
    return out


@pytest.mark.parametrize("shape", ["sphere", "box", "cylinder", "capsule"])
def test_each_control_point_gets_its_k_nearest_present_members(shape):
    """The selection against the distances ``set_distances`` measures member by member (one map per slot, as the
    tree's edges do), sorted in full: the same members, nearest first, and the nearest one left out."""
    s = ObstacleSet(shape=shape, n_max=N, nearest=K)
    B, C = 3, 5
    aux = scattered(s, B, seed=1)
    points = (torch.rand(B, C, 3, generator=torch.Generator().manual_seed(2), dtype=torch.float64) - 0.5) * 1.2
    distance = member_distances(s, aux, points)
    chosen, left_out = nearest_members(s, aux, points)
    for b in range(B):
        one = {k: v[b : b + 1] for k, v in aux.items()}
        brute = set_distances([ObstacleSet(shape=shape, n_max=N)], one, points[b])  # (C, N), inf where absent
        torch.testing.assert_close(distance[b], brute, rtol=1e-12, atol=1e-12)
        order = torch.argsort(brute, dim=-1, stable=True)
        for i in range(C):
            own = s.for_control_point(i + 1).prefix
            want = aux[f"{s.prefix}_center"][b, order[i, :K]]
            torch.testing.assert_close(chosen[f"{own}_center"][b], want)
            assert chosen[f"{own}_mask"][b].eq(1).all()
            assert left_out[b, i] == brute[i, order[i, K]]


def test_fewer_present_than_k_leaves_the_rest_absent():
    s = ObstacleSet(shape="sphere", n_max=N, nearest=K)
    aux = scattered(s, 2, seed=3)
    aux["spheres_mask"][:] = 0.0
    aux["spheres_mask"][0, [4, 9]] = 1.0
    chosen, left_out = nearest_members(s, aux, torch.zeros(2, 3, 3, dtype=torch.float64))
    assert chosen["cp1_spheres_mask"].tolist() == [[1.0, 1.0, 0.0, 0.0], [0.0] * 4]
    assert torch.isinf(left_out).all()


def _states(B: int, seed: int):
    g = torch.Generator().manual_seed(seed)
    q = torch.tensor([0.0, -0.3, 0.0, -2.2, 0.0, 2.0, 0.8], dtype=torch.float64) + 0.4 * torch.randn(
        B, 7, generator=g, dtype=torch.float64
    )
    return q, 0.3 * torch.randn(B, 7, generator=g, dtype=torch.float64)


def _outputs(tree, q, qd, aux):
    """f, M, q̈, V and the gradient of a scalar of them with respect to q and every learnable parameter."""
    q = q.clone().requires_grad_(True)
    out = tree(q, qd, aux)
    scalar = out.qdd.square().sum() + out.f.sum() + out.M.sum() + out.V.sum()
    params = [p for p in tree.parameters() if p.requires_grad]
    grads = torch.autograd.grad(scalar, [q, *params])
    return [out.f, out.M, out.qdd, out.V, *grads]


def test_the_tree_of_k_nearest_equals_the_tree_of_every_member_where_the_rest_lie_beyond_the_support():
    """Members around the arm, some within the barrier's reach and most beyond it: on every sample where the
    selection is exact (``selection_exact``) f, M, q̈, V and the gradients (q and every weight parameter) equal the
    tree of all N_max members to 1e-12; with k = 1 the selection is not exact on some samples and there the two
    trees differ, so the comparison can fail."""
    robot = panda()
    radii = torch.tensor([cp.radius for cp in robot.params.control_points], dtype=torch.float64)
    full_set = ObstacleSet(shape="sphere", n_max=N)
    full = _panda_tree([full_set])
    q, qd = _states(6, seed=4)
    points = robot.sphere_centres(q)
    aux = scattered(full_set, 6, seed=5)
    aux["spheres_radius"] = torch.full_like(aux["spheres_radius"], 0.03)
    goal = {"goal": torch.tensor([[0.5, 0.2, 0.4]], dtype=torch.float64).expand(6, 3)}
    want = _outputs(full, q, qd, with_slots([full_set], {**goal, **aux}))
    seen = {}
    for k in (K, 1):
        near_set = ObstacleSet(shape="sphere", n_max=N, nearest=k)
        near = _panda_tree([near_set])
        copy_weights(full, near)
        _, left_out = nearest_members(near_set, aux, points)
        exact = selection_exact(left_out, radii, SUPPORT)
        got = _outputs(near, q, qd, with_slots([near_set], {**goal, **aux}, points=points))
        seen[k] = exact
        for a, b in zip(got[:4], want[:4]):
            torch.testing.assert_close(a[exact], b[exact], rtol=1e-12, atol=1e-12)
        if exact.all():
            for a, b in zip(got[4:], want[4:]):
                torch.testing.assert_close(a, b, rtol=1e-10, atol=1e-12)
        else:
            assert (got[2] - want[2])[~exact].abs().amax() > 1e-6
    assert seen[K].all(), "the test's layout must leave every sample exact at k = 4"
    assert not seen[1].all(), "the test's layout must leave some sample inexact at k = 1"


def test_a_nearest_set_is_read_per_control_point_with_k_slots_each():
    s = ObstacleSet(shape="box", n_max=50, nearest=6, name="clutter")
    read = sets_read([s], 3)
    assert [r.prefix for r in read] == ["cp1_clutter", "cp2_clutter", "cp3_clutter"]
    assert {r.n_max for r in read} == {6} and all(r.nearest is None for r in read)
    assert s.set_dims()["clutter_center"] == (50, 3)  # the caller passes all 50


@pytest.mark.parametrize(
    "settings, match",
    [
        ({"n_max": 8, "nearest": 8}, "must be < n_max"),
        ({"n_max": 8, "nearest": 2, "per_control_point": True}, "choose one"),
        ({"n_max": 8, "nearest": 0}, "greater than or equal to 1"),
    ],
)
def test_bad_nearest_settings_are_clear_errors(settings, match):
    with pytest.raises(ValueError, match=match):
        ObstacleSet(shape="sphere", **settings)


def test_slots_without_the_control_points_are_a_clear_error():
    s = ObstacleSet(shape="sphere", n_max=N, nearest=K)
    with pytest.raises(ValueError, match="pass points="):
        with_slots([s], scattered(s, 1, seed=0))
    with pytest.raises(ValueError, match="nearest members"):
        s.slots(scattered(s, 1, seed=0))


def test_an_exported_controller_selects_the_nearest_members_itself(tmp_path):
    """``export_with_sets`` with a nearest set: the program takes the whole set (12 spheres) and selects each control
    point's 3 nearest from the control spheres' centres at its q; saved and loaded, it equals the eager tree as
    spheres appear near the arm, move (changing which are nearest) and vanish."""
    from rmpfusion.learn.export import export_with_sets
    from rmpfusion.scenes import World

    s = ObstacleSet(shape="sphere", n_max=12, nearest=3)
    tree = _panda_tree([s])
    robot = panda()
    world = World([s], goal=[0.5, 0.2, 0.4])
    for k in range(6):
        world.add("sphere", name=f"b{k}", center=[0.9, -0.5 + 0.2 * k, 0.5], radius=0.03)
    q, qd = _states(1, seed=6)
    exported = export_with_sets(tree, [s], q, qd, world.set_aux(), robot.sphere_centres)
    torch.export.save(exported, tmp_path / "policy.pt2")
    loaded = torch.export.load(tmp_path / "policy.pt2").module()
    centre = robot.sphere_centres(q)[0, 6]
    commands = []
    for change in (
        lambda: None,
        lambda: world.move("b0", center=(centre + torch.tensor([0.12, 0.0, 0.0])).tolist()),
        lambda: world.add(
            "sphere", name="near", center=(centre + torch.tensor([0.0, 0.13, 0.0])).tolist(), radius=0.03
        ),
        lambda: world.remove("b0"),
    ):
        change()
        with torch.no_grad():
            want = tree(q, qd, world.aux(robot.sphere_centres(q))).qdd
            got = loaded(q, qd, *world.set_aux().values())
        torch.testing.assert_close(got, want, rtol=1e-12, atol=1e-12)
        commands.append(got)
    assert (commands[1] - commands[0]).abs().max() > 1e-6  # a sphere moved near the arm is read and changes q̈


@pytest.mark.parametrize(
    "text, match",
    [
        ("sphere:12:nearest=x", "SHAPE:N:nearest=K"),
        ("sphere:12:closest=3", "SHAPE:N:nearest=K"),
        ("sphere:4:nearest=4", "< n_max"),
    ],
)
def test_a_bad_nearest_export_set_says_how_to_write_it(text, match):
    from rmpfusion.cli.export import parse_set

    assert parse_set("sphere:12:nearest=3").nearest == 3
    with pytest.raises(ValueError, match=match):
        parse_set(text)
