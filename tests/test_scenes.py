"""Scenes (conf/scene/, rmpfusion/scenes/): every obstacle shape measured by its distance map agrees with pybullet's
closest points; moving obstacles' maps give the rate and curvature of the distance in time; the paths of moving
obstacles; an environment with every shape, a ground plane and a moving obstacle runs, and its rollouts are
reported apart by the Lyapunov monitor."""

from __future__ import annotations

import numpy as np
import pytest
import torch

pybullet = pytest.importorskip("pybullet")

from manipulators import franka_env, robot

import rmpfusion
from rmpfusion.envs.manipulator.worlds import sample_aux
from rmpfusion.envs.manipulator_tree import manipulator_tree_spec, with_weights
from rmpfusion.evaluate.metrics import rollout_rates, task_stage
from rmpfusion.registry import TASK_MAPS
from rmpfusion.scenes import Scene, aux_at, distances, scene_aux
from rmpfusion.sims.obstacles import rotation_z_to
from rmpfusion.sims.pybullet_backend import quaternion_of

F64 = torch.float64
EVERY_SHAPE = {
    "obstacles": [
        {"type": "sphere", "center": [0.5, 0.0, 0.3], "radius": 0.1},
        {"type": "box", "center": [0.5, 0.2, 0.3], "half_extents": [0.1, 0.05, 0.2], "rpy": [0.3, 0.2, 0.5]},
        {"type": "cylinder", "center": [0.4, -0.3, 0.3], "radius": 0.08, "height": 0.4, "axis": [0.3, 0.0, 1.0]},
        {"type": "capsule", "center": [0.2, 0.3, 0.2], "radius": 0.06, "length": 0.3, "axis": [1.0, 1.0, 0.5]},
    ]
}
#: pybullet's closest points on boxes and cylinders carry its convex margins; spheres and capsules are exact
PYBULLET_TOLERANCE = {"sphere": 1e-9, "capsule": 1e-9, "box": 1e-3, "cylinder": 1e-3}


def _pybullet_bodies(scene: Scene, a: dict) -> list[int]:
    bodies = []
    for k, o in enumerate(scene.obstacles, 1):
        pre, r = f"obstacle{k}_", float(a[f"obstacle{k}_radius"][0])
        if o.type == "sphere":
            col, q = pybullet.createCollisionShape(pybullet.GEOM_SPHERE, radius=r), [0, 0, 0, 1]
        elif o.type == "box":
            col = pybullet.createCollisionShape(pybullet.GEOM_BOX, halfExtents=a[pre + "half_extents"].tolist())
            q = quaternion_of(a[pre + "rotation"].reshape(3, 3))
        else:
            half = float(a[pre + ("half_height" if o.type == "cylinder" else "half_length")][0])
            shape = pybullet.GEOM_CYLINDER if o.type == "cylinder" else pybullet.GEOM_CAPSULE
            col, q = (
                pybullet.createCollisionShape(shape, radius=r, height=2 * half),
                quaternion_of(rotation_z_to(a[pre + "axis"])),
            )
        bodies.append(pybullet.createMultiBody(0, col, -1, a[pre + "center"].tolist(), q))
    return bodies


def test_every_shape_measures_the_distance_pybullet_finds():
    """Independent geometry: a 1 cm probe sphere at 300 random points, pybullet's closest distance to each shape
    (built from the same aux numbers) against the shape's distance map. This also checks the conversions of
    orientations (rpy, axes) both sides use."""
    scene = Scene.model_validate(EVERY_SHAPE)
    aux = scene_aux(scene, torch.tensor([[o.center for o in scene.obstacles]], dtype=F64), F64)
    cid = pybullet.connect(pybullet.DIRECT)
    try:
        with_cid = {"physicsClientId": cid}
        bodies = _pybullet_bodies_in(cid, scene, sample_aux(aux, 0))
        probe = pybullet.createMultiBody(
            0, pybullet.createCollisionShape(pybullet.GEOM_SPHERE, radius=0.01, **with_cid), -1, [0, 0, 0], **with_cid
        )
        pts = np.random.default_rng(0).uniform([0.0, -0.6, -0.1], [0.9, 0.6, 0.7], (300, 3))
        ours = distances(scene, {k: v.expand(len(pts), -1) for k, v in aux.items()}, torch.tensor(pts))
        checked = {o.type: 0 for o in scene.obstacles}
        for i, x in enumerate(pts):
            pybullet.resetBasePositionAndOrientation(probe, x.tolist(), [0, 0, 0, 1], **with_cid)
            for k, (o, b) in enumerate(zip(scene.obstacles, bodies)):
                d = float(ours[i, k])
                found = pybullet.getClosestPoints(probe, b, 0.3, **with_cid)
                if found and 0.02 < d < 0.25:  # outside, within the query distance
                    assert abs(found[0][8] + 0.01 - d) < PYBULLET_TOLERANCE[o.type], (o.type, x, d, found[0][8])
                    checked[o.type] += 1
        assert min(checked.values()) > 30, checked  # every shape was compared at many points
    finally:
        pybullet.disconnect(cid)


def _pybullet_bodies_in(cid: int, scene: Scene, a: dict) -> list[int]:
    pybullet.resetSimulation(physicsClientId=cid)
    orig = pybullet.createCollisionShape, pybullet.createMultiBody
    try:  # the helper's calls in this client
        pybullet.createCollisionShape = lambda *x, **k: orig[0](*x, physicsClientId=cid, **k)
        pybullet.createMultiBody = lambda *x, **k: orig[1](*x, physicsClientId=cid, **k)
        return _pybullet_bodies(scene, a)
    finally:
        pybullet.createCollisionShape, pybullet.createMultiBody = orig


@pytest.mark.parametrize(
    "name,params",
    [
        ("sphere_obstacle", {"radius": 0.2}),
        ("capsule_obstacle", {"radius": 0.1, "half_length": 0.3, "axis": [0.0, 0.6, 0.8]}),
        ("cylinder_obstacle", {"radius": 0.2, "half_height": 0.25, "axis": [0.6, 0.0, 0.8]}),
        ("box_obstacle", {"half_extents": [0.1, 0.2, 0.15]}),
    ],
)
def test_a_moving_obstacles_distance_changes_as_its_map_says(name, params):
    """y(t) = d(x(t) − c(t)) with x(t) = x0 + ẋt + ½ẍt² and c(t) = c0 + vt: the map's ẏ is dy/dt and its
    curvature term is d²y/dt² − Jẍ, by central differences in time."""
    entry = TASK_MAPS.get(name)
    m = entry.obj(entry.validate({"center": "c", "velocity": "v", **params}), 3, {"c": 3, "v": 3})
    g = torch.Generator().manual_seed(1)
    B = 16
    x0, xd, xdd = (torch.randn(B, 3, generator=g, dtype=F64) * s for s in (0.6, 1.0, 1.0))
    c0, v = torch.randn(B, 3, generator=g, dtype=F64) * 0.1, torch.randn(B, 3, generator=g, dtype=F64)
    y = lambda t: m.psi(x0 + xd * t + 0.5 * xdd * t * t, {"c": c0 + v * t})
    h = 1e-4
    y0, yd, J, curv = m(x0, xd, {"c": c0, "v": v})
    torch.testing.assert_close(yd, (y(h) - y(-h)) / (2 * h), rtol=1e-6, atol=1e-7)
    ydd = (y(h) - 2 * y0 + y(-h)) / h**2
    torch.testing.assert_close(curv, ydd - (J @ xdd.unsqueeze(-1)).squeeze(-1), rtol=1e-4, atol=1e-4)
    static = m(x0, xd, {"c": c0, "v": torch.zeros_like(v)})  # at rest: ẏ = Jẋ, as for any map
    torch.testing.assert_close(static[1], (static[2] @ xd.unsqueeze(-1)).squeeze(-1))


def test_obstacle_paths_are_at_constant_speed_through_the_waypoints():
    scene = Scene.model_validate(
        {
            "obstacles": [
                {
                    "type": "sphere",
                    "center": [1.0, 0.0, 0.0],
                    "radius": 0.1,
                    "motion": {"type": "waypoints", "points": [[0.3, 0.0, 0.0], [0.3, 0.4, 0.0]], "speed": 0.1},
                },
                {
                    "type": "sphere",
                    "center": [0.0, 0.0, 1.0],
                    "radius": 0.1,
                    "motion": {"type": "linear", "velocity": [0.0, 0.0, -0.2]},
                },
            ]
        }
    )
    aux0 = scene_aux(scene, torch.tensor([[o.center for o in scene.obstacles]], dtype=F64), F64)
    t = torch.tensor([0.0, 1.5, 3.0, 5.0, 10.0, 12.0, 15.0], dtype=F64)  # the loop is 0.3 + 0.4 + 0.5 = 1.2 m: 12 s
    a = aux_at(scene, {k: v.expand(len(t), -1) for k, v in aux0.items()}, t)
    expected = [
        [1.0, 0.0, 0.0],
        [1.15, 0.0, 0.0],
        [1.3, 0.0, 0.0],
        [1.3, 0.2, 0.0],
        [1.12, 0.16, 0.0],
        [1.0, 0.0, 0.0],
        [1.3, 0.0, 0.0],
    ]
    torch.testing.assert_close(a["obstacle1_center"], torch.tensor(expected, dtype=F64))
    torch.testing.assert_close(a["obstacle1_velocity"][3], torch.tensor([0.0, 0.1, 0.0], dtype=F64))
    torch.testing.assert_close(a["obstacle1_velocity"][4], torch.tensor([-0.06, -0.08, 0.0], dtype=F64))
    torch.testing.assert_close(a["obstacle2_center"][:, 2], 1.0 - 0.2 * t)
    assert "obstacle2_velocity" in a and "obstacle1_velocity" in aux0


def _moving_scene() -> dict:
    moving = {
        **EVERY_SHAPE["obstacles"][0],
        "center": [0.4, -0.3, 0.75],
        "motion": {"type": "waypoints", "points": [[0.0, 0.3, 0.0]], "speed": 0.2},
    }
    return {"obstacles": [moving, *EVERY_SHAPE["obstacles"][1:]], "ground": {"height": 0.0}}


def test_an_env_with_every_shape_a_ground_and_a_moving_obstacle_runs_and_is_monitored_apart():
    spec = manipulator_tree_spec(robot("panda"), _moving_scene())
    nodes = spec["nodes"]
    assert {nodes[f"cp1_obstacle{k}"]["map"]["maps"][0]["type"] for k in range(1, 5)} == {
        "sphere_obstacle",
        "box_obstacle",
        "cylinder_obstacle",
        "capsule_obstacle",
    }
    assert nodes["cp1_obstacle1"]["map"]["maps"][0]["velocity"] == "obstacle1_velocity"
    assert "velocity" not in nodes["cp1_obstacle2"]["map"]["maps"][0]
    assert nodes["cp3_ground"]["weight"] == {"shared": "ground"}
    # every obstacle edge of a control point shares its one weight
    assert {nodes[f"cp2_obstacle{k}"]["weight"]["shared"] for k in range(1, 5)} == {"cp2_obstacle"}
    env = franka_env(_moving_scene(), control_rate=100.0, goal_clearance=0.05, start_clearance=0.0)
    expert = rmpfusion.build_tree(with_weights(spec, {"attractor": 40.0}), aux_dims=env.aux_dims())
    q0, qd0, aux = env.sample(1, 2, seed=0)
    with torch.no_grad():
        for mode in ("kinematic", "torque"):
            ro = env.rollout(expert, q0, qd0, aux, horizon=0.3, record_every=0.1, mode=mode)
            assert ro.error == [None, None] and ro.moving and ro.q.isfinite().all()
            rates = rollout_rates(ro)
            assert "lyapunov_monotone_fraction" not in rates and "lyapunov_monotone_fraction_moving" in rates
            assert task_stage("expert", ro, env).lyapunov["theorem2_applies"] is False
    env.close()


def test_a_test_scene_must_fit_the_tree_of_the_training_scene():
    with pytest.raises(
        ValueError,
        match=r"test_scene must have the obstacles of the training scene, with the same "
        r"shapes in the same order.*training: \[\('sphere', 'moving'\)",
    ):
        franka_env(_moving_scene(), test_scene=EVERY_SHAPE)
