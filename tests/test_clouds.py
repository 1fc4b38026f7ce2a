"""Point clouds as obstacles (scenes/clouds.py, World.set_cloud): one sphere per occupied cube at its points'
centroid, the nearest cubes kept when there are more than the set's members, missing returns dropped; a cloud
replaces the set's members, and the tree then equals the tree of those spheres."""

from __future__ import annotations

import math

import pytest
import torch

from rmpfusion.scenes import ObstacleSet, World, WorldError
from rmpfusion.scenes.clouds import cloud_members, keep_nearest, voxel_centroids


def test_each_occupied_cube_becomes_the_centroid_of_its_points():
    pts = torch.tensor(
        [
            [0.01, 0.01, 0.01],
            [0.03, 0.05, 0.07],  # cube (0, 0, 0) at voxel 0.1
            [0.15, 0.02, 0.02],
            [0.17, 0.04, 0.06],  # cube (1, 0, 0)
            [-0.05, 0.0, 0.0],
            [float("nan"), 0.0, 0.0],
        ],
        dtype=torch.float64,
    )  # cube (-1, 0, 0); a missing return
    c = voxel_centroids(pts, 0.1)
    expected = {(-1, 0, 0): [-0.05, 0.0, 0.0], (0, 0, 0): [0.02, 0.03, 0.04], (1, 0, 0): [0.16, 0.03, 0.04]}
    got = {tuple(torch.floor(row / 0.1).long().tolist()): row for row in c}
    assert set(got) == set(expected)
    for k, v in expected.items():
        torch.testing.assert_close(got[k], torch.tensor(v, dtype=torch.float64))


def test_the_nearest_cubes_are_kept_when_the_set_is_too_small():
    centres = torch.tensor([[float(i), 0.0, 0.0] for i in range(6)], dtype=torch.float64)
    near = torch.tensor([[4.2, 0.0, 0.0]], dtype=torch.float64)
    kept = keep_nearest(centres, 3, near)
    assert sorted(kept[:, 0].tolist()) == [3.0, 4.0, 5.0]
    assert keep_nearest(centres, 10, near).shape == (6, 3)
    _members, mask = cloud_members(centres, 0.5, 8)
    assert mask.tolist() == [1.0] * 6 + [0.0] * 2


def box_surface(n: int, seed: int) -> torch.Tensor:
    """Points on the faces of a 0.2 × 0.1 × 0.3 m box centred at (0.5, 0, 0.3): what a depth camera samples."""
    g = torch.Generator().manual_seed(seed)
    u = torch.rand(n, 3, generator=g, dtype=torch.float64) * 2 - 1
    face = torch.randint(0, 3, (n,), generator=g)
    side = torch.where(torch.rand(n, generator=g) < 0.5, -1.0, 1.0).to(torch.float64)
    u[torch.arange(n), face] = side
    return u * torch.tensor([0.1, 0.05, 0.15], dtype=torch.float64) + torch.tensor([0.5, 0.0, 0.3], dtype=torch.float64)


def test_a_cloud_fills_and_replaces_a_sphere_set():
    cloud_set = ObstacleSet(shape="sphere", n_max=64, name="cloud")
    world = World([cloud_set, ObstacleSet(shape="box", n_max=1)])
    pts = box_surface(2000, seed=0)
    voxel = 0.05
    filled = world.set_cloud("cloud", pts, voxel=voxel, radius=math.sqrt(3) / 2 * voxel)
    assert 0 < filled <= 64
    mask = world.tensors["cloud_mask"][0]
    centres = world.tensors["cloud_center"][0][mask > 0]
    # every point lies within a member's sphere: the spheres cover the sampled surface
    d = torch.cdist(pts, centres).min(-1).values
    assert float(d.max()) <= math.sqrt(3) * voxel
    fewer = world.set_cloud("cloud", pts[:50], voxel=voxel, radius=0.05)
    assert fewer < filled and int(world.tensors["cloud_mask"][0].sum()) == fewer  # replaced, not added
    assert world.set_cloud("cloud", torch.full((5, 3), float("nan")), voxel=voxel, radius=0.05) == 0


def test_a_cloud_refuses_what_it_cannot_fill():
    world = World([ObstacleSet(shape="sphere", n_max=4), ObstacleSet(shape="box", n_max=1)])
    world.add("sphere", center=[0.0, 0.0, 0.5], radius=0.1)
    pts = box_surface(100, seed=1)
    for call, words in [
        (lambda: world.set_cloud("boxes", pts, 0.05, 0.05), "a point cloud fills a set of spheres"),
        (lambda: world.set_cloud("spheres", pts, 0.05, 0.05), "holds obstacles added one by one"),
        (lambda: world.set_cloud("nope", pts, 0.05, 0.05), "no obstacle set 'nope'"),
        (lambda: world.set_cloud("spheres", pts, 0.05, 0.0), "radius > 0"),
    ]:
        with pytest.raises(WorldError) as err:
            call()
        assert words in str(err.value)
    with pytest.raises(ValueError, match="voxel must be > 0"):
        voxel_centroids(pts, 0.0)
