"""Point clouds as obstacles (scenes/clouds.py, World.set_cloud): one sphere per occupied cube at its points'
centroid, the nearest cubes kept when there are more than the set's members, missing returns dropped; a cloud
replaces the set's members, and the tree then equals the tree of those spheres."""

from __future__ import annotations

import math

import pytest
import torch
from conftest import ROOT

from rmpfusion.scenes import ObstacleSet, World, WorldError
from rmpfusion.scenes.clouds import cloud_members, keep_nearest, member_velocities, voxel_centroids


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


def test_each_control_point_reads_its_k_nearest_points():
    """``nearest_per_point`` against a brute-force sort: every centre's k nearest points, nearest first; missing
    returns dropped; a cloud of fewer than k points leaves the rest of the members absent."""
    from rmpfusion.scenes.clouds import nearest_per_point

    pts = box_surface(300, seed=2)
    pts[7] = float("nan")
    centres = torch.tensor([[0.3, 0.0, 0.3], [0.6, 0.2, 0.5], [0.5, -0.3, 0.1]], dtype=torch.float64)
    members, mask = nearest_per_point(pts, centres, 8)
    finite = pts[torch.isfinite(pts).all(-1)]
    for c in range(3):
        expected = finite[torch.argsort((finite - centres[c]).norm(dim=-1))[:8]]
        torch.testing.assert_close(members[c], expected)
    assert mask.eq(1).all()
    few, few_mask = nearest_per_point(pts[:5], centres, 8)
    assert few_mask.sum(-1).tolist() == [5.0, 5.0, 5.0] and few[:, 5:].eq(0).all()


def _panda_tree(sets: list[ObstacleSet]):
    import yaml

    from rmpfusion import build_tree
    from rmpfusion.assembly.generated import expand_tree

    decl = yaml.safe_load((ROOT / "conf/tree/arm_reach.yaml").read_text())
    decl.pop("defaults", None)
    decl.update(
        robot=yaml.safe_load((ROOT / "conf/robot/panda.yaml").read_text()),
        scene={"obstacles": []},
        obstacle_sets=[s.model_dump() for s in sets],
    )
    return build_tree(expand_tree(decl)).double()


def test_per_control_point_members_equal_a_shared_set_holding_the_same_points():
    """A cloud of k points: every control point's k nearest are all of them, so the tree whose control points each
    read their own k members equals the tree whose control points share one set of those k (f, M, q̈, V to 1e-12);
    with a larger cloud the two differ (each control point then keeps its own nearest)."""
    import yaml

    from rmpfusion.envs.manipulator_tree import copy_weights
    from rmpfusion.robots import RobotDescription, build_robot
    from rmpfusion.scenes import sets_read, with_slots
    from rmpfusion.scenes.clouds import nearest_per_point, per_point_aux

    k = 4
    own = ObstacleSet(shape="sphere", n_max=k, name="points", per_control_point=True)
    shared = ObstacleSet(shape="sphere", n_max=k, name="points")
    t_own, t_shared = _panda_tree([own]), _panda_tree([shared])
    copy_weights(t_own, t_shared)
    robot = build_robot(RobotDescription.model_validate(yaml.safe_load((ROOT / "conf/robot/panda.yaml").read_text())))
    q = torch.tensor([[0.0, -0.3, 0.0, -2.2, 0.0, 2.0, 0.8]], dtype=torch.float64)
    qd = torch.full_like(q, 0.1)
    centres = robot.sphere_centres(q)[0]
    goal = torch.tensor([[0.5, 0.2, 0.4]], dtype=torch.float64)

    def outputs(pts):
        members, mask = nearest_per_point(pts, centres, k)
        a_own = with_slots(sets_read([own], len(centres)), {"goal": goal, **per_point_aux(own, members, mask, 0.03)})
        a_shared = with_slots(
            [shared],
            {
                "goal": goal,
                "points_center": pts[:k].unsqueeze(0),
                "points_radius": torch.full((1, k, 1), 0.03, dtype=torch.float64),
                "points_mask": torch.ones(1, k, dtype=torch.float64),
            },
        )
        with torch.no_grad():
            return t_own(q, qd, a_own), t_shared(q, qd, a_shared)

    near_arm = centres[3] + torch.tensor([[0.1, 0.0, 0.0], [0.0, 0.12, 0.0], [0.0, 0.0, 0.15], [0.1, 0.1, 0.0]])
    a, b = outputs(near_arm)
    for x, y in ((a.f, b.f), (a.M, b.M), (a.qdd, b.qdd), (a.V, b.V)):
        torch.testing.assert_close(x, y, rtol=1e-12, atol=1e-12)
    more = torch.cat([near_arm, centres[8:9] + torch.tensor([[0.08, 0.0, 0.0]])])
    a, b = outputs(more)
    assert (a.qdd - b.qdd).abs().max() > 1e-6
    with pytest.raises(ValueError, match="members per control point"):
        with_slots([own], {"goal": goal})


def test_members_of_a_moving_cloud_get_its_velocity():
    """A box's surface seen twice, 1/30 s apart, after it moved 1 cm along x (0.3 m/s). The members on the faces
    across the motion (±x) move with it; those on the faces along it slide along themselves and show little of it
    (the aperture problem the docstring states). A cloud at rest gets no velocity."""
    moving = ObstacleSet(shape="sphere", n_max=400, name="cloud", moving=True)
    world = World([moving])
    interval, shift = 1 / 30, torch.tensor([0.01, 0.0, 0.0], dtype=torch.float64)
    pts = box_surface(3000, seed=2)
    world.set_cloud("cloud", pts, voxel=0.04, radius=0.035)
    assert torch.all(world.tensors["cloud_velocity"] == 0)  # the first cloud has nothing to move from
    world.set_cloud("cloud", pts, voxel=0.04, radius=0.035, since=interval)
    assert torch.all(world.tensors["cloud_velocity"] == 0)  # at rest: the same members
    world.set_cloud("cloud", pts + shift, voxel=0.04, radius=0.035, since=interval)
    mask = world.tensors["cloud_mask"][0] > 0
    v, c = world.tensors["cloud_velocity"][0][mask], world.tensors["cloud_center"][0][mask]
    across = (c[:, 0] - 0.51).abs() > 0.095  # the members on the ±x faces (the box's centre is now at x = 0.51)
    assert across.sum() >= 20
    mean = v[across].mean(0)
    assert float(mean[0]) == pytest.approx(0.3, rel=0.15)
    assert float(mean[1:].abs().max()) < 0.03
    assert float(v[~across].mean(0)[0]) < 0.5 * float(mean[0])  # along the motion: underestimated
    assert torch.all(world.tensors["cloud_velocity"][0][~mask] == 0)


def test_cloud_velocities_exact_for_separate_points_and_zero_for_what_appears():
    previous = torch.tensor([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]], dtype=torch.float64)
    now = torch.tensor([[0.01, 0.0, 0.0], [1.0, 0.02, 0.0], [3.0, 0.0, 0.0]], dtype=torch.float64)
    v = member_velocities(now, torch.ones(3), previous, torch.ones(2), interval=0.1, max_speed=1.0)
    torch.testing.assert_close(v, torch.tensor([[0.1, 0, 0], [0, 0.2, 0], [0, 0, 0]], dtype=torch.float64))
    # an absent previous member is never matched; an absent member has no velocity
    v = member_velocities(now, torch.tensor([1.0, 1.0, 0.0]), previous, torch.tensor([0.0, 1.0]), 0.1, 100.0)
    torch.testing.assert_close(v[0], torch.tensor([-9.9, 0.0, 0.0], dtype=torch.float64))
    assert torch.all(v[2] == 0)
    with pytest.raises(WorldError, match="not moving"):
        World([ObstacleSet(shape="sphere", n_max=4, name="cloud")]).set_cloud("cloud", now, 0.05, 0.05, since=0.1)
    with pytest.raises(ValueError, match="interval between two clouds must be > 0"):
        member_velocities(now, torch.ones(3), previous, torch.ones(2), interval=0.0, max_speed=1.0)


def test_the_camera_fed_policy_gives_its_moving_members_the_clouds_velocity():
    """tools/camera_run.py's camera-fed tree with ``--velocities``: each frame's members get their displacement from
    the previous frame's over the frames' interval (at rest in the first frame), as World.set_cloud does."""
    from types import SimpleNamespace

    from tools.camera_run import CameraFed

    period, dt, shift = 4, 0.01, torch.tensor([0.01, 0.0, 0.0], dtype=torch.float64)
    pts = box_surface(3000, seed=2)
    seen: list[dict] = []

    class Env:
        params = SimpleNamespace(depth_camera=SimpleNamespace(seed=0))
        dt = 0.01
        frames = 0

        def point_cloud(self, q, aux, sample, rng):
            return pts + Env.frames * shift  # the box moves 1 cm between two frames

    robot = SimpleNamespace(
        params=SimpleNamespace(control_points=[None, None]),
        sphere_centres=lambda q: torch.zeros(q.shape[0], 2, 3, dtype=torch.float64),
    )
    learner = SimpleNamespace(policy=lambda q, qd, aux: seen.append(aux) or torch.zeros_like(q))
    moving = ObstacleSet(shape="sphere", n_max=400, name="points", moving=True)
    fed = CameraFed(learner, Env(), robot, moving, voxel=0.04, radius=0.035, period=period, latency=0)
    q = torch.zeros(1, 7, dtype=torch.float64)
    for step in range(2 * period):
        Env.frames = step // period
        fed(q, q, {"goal": torch.zeros(1, 3, dtype=torch.float64)})
    first, second = seen[0], seen[period]
    assert torch.all(first["points_velocity"] == 0)
    mask = second["points_mask"][0] > 0
    across = (second["points_center"][0][mask][:, 0] - 0.51).abs() > 0.095  # the faces across the motion
    speed = float(second["points_velocity"][0][mask][across].mean(0)[0])
    assert speed == pytest.approx(0.01 / (period * dt), rel=0.15)
    assert torch.equal(seen[period + 1]["points_velocity"], second["points_velocity"])  # held between frames
