"""Simulators as backends (rmpfusion/sims/): pybullet and MuJoCo agree with rmpfusion's kinematics and with each
other (inverse dynamics, signed distances, renders through one camera, torque-mode rollouts), the ``sim:`` block
refuses what cannot work, and a third simulator registered by a plugin runs an experiment without an edit to
rmpfusion."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch
import yaml
from conftest import compose_cfg, needs_mujoco_rendering
from manipulators import CONF, franka_env, robot

from rmpfusion.registry import SIMULATORS
from rmpfusion.robots import RobotDescription, URDFRobot, build_robot
from rmpfusion.sims import (
    BACKGROUND,
    GOAL_MARKER,
    GROUND,
    ROBOT,
    Camera,
    Images,
    Obstacle,
    SimulationError,
    SimulatorParams,
    SimWorld,
    WorldSettings,
    open_world,
)
from rmpfusion.sims.obstacles import rotation_z_to

pytest.importorskip("pybullet")
pytest.importorskip("mujoco")

F64 = torch.float64
ROBOTS = sorted(p.stem for p in (CONF / "robot").glob("*.yaml"))
SIMS = ("pybullet", "mujoco")


def _robot(name: str) -> URDFRobot:
    return build_robot(RobotDescription.model_validate(robot(name)))


def _params(sim: str) -> SimulatorParams:
    return SIMULATORS.get(sim).params.model_validate({"type": sim})


def _random_q(r: URDFRobot, n: int, seed: int) -> np.ndarray:
    lo, hi = np.maximum(r.lower.numpy(), -math.pi), np.minimum(r.upper.numpy(), math.pi)
    return lo + (hi - lo) * np.random.default_rng(seed).random((n, r.dof))


def _full(r: URDFRobot, q: np.ndarray) -> np.ndarray:
    """Every simulated joint at the actuated q, the held ones where the robot holds them."""
    return r.simulated_state(q)[0]


# ---------------------------------------------------------------- kinematics and dynamics


@pytest.mark.parametrize("sim", SIMS)
@pytest.mark.parametrize("name", ROBOTS)
def test_every_link_frame_agrees_with_rmpfusion(name, sim):
    """Every link frame of every robot of conf/robot/, in each simulator, against rmpfusion's chain (the mount and
    mimic followers included), to 1e-6 m and 1e-6 in rotation, at 5 random configurations."""
    r = _robot(name)
    world = open_world(r, WorldSettings(), _params(sim))
    try:
        worst, seen = 0.0, set()
        for q in _random_q(r, 5, seed=0):
            world.reset(_full(r, q), np.zeros(r.dof + len(r.held_joints())))
            frames = world.link_frames()
            ours = r.chain.forward_kinematics(torch.tensor(q[None]))
            for link, (R, p) in ours.items():
                if link not in frames:  # a link of no body: MuJoCo's world, when the URDF's root is named so
                    continue
                theirs_p, theirs_R = frames[link]
                worst = max(
                    worst, float(np.abs(p[0].numpy() - theirs_p).max()), float(np.abs(R[0].numpy() - theirs_R).max())
                )
                seen.add(link)
        assert worst < 1e-6, (name, sim, worst)
        assert r.params.end_effector.link in seen and len(seen) >= r.dof
    finally:
        world.close()


@pytest.mark.parametrize("name", ["panda", "iiwa"])
def test_inverse_dynamics_agree_across_simulators(name):
    """M(q)q̈ + C(q, q̇)q̇ + g(q) from pybullet and from MuJoCo (mj_rne) at random states, to 1e-8 relative (the
    URDF's own inertias: these two arms need no balancing)."""
    r = _robot(name)
    worlds = [open_world(r, WorldSettings(), _params(s)) for s in SIMS]
    try:
        g = np.random.default_rng(1)
        n = r.dof + len(r.held_joints())
        for q in _random_q(r, 4, seed=1):
            qd, qdd = g.standard_normal(n), g.standard_normal(n)
            tau = [w.inverse_dynamics(_full(r, q), qd, qdd) for w in worlds]
            assert np.abs(tau[0] - tau[1]).max() <= 1e-8 * max(1.0, np.abs(tau[0]).max()), tau
    finally:
        for w in worlds:
            w.close()


def _near_obstacle(kind: str, centre: np.ndarray, axis: np.ndarray) -> Obstacle:
    R = rotation_z_to(axis)
    return {
        "sphere": Obstacle("sphere", centre, radius=0.05),
        "box": Obstacle("box", centre, R, half_extents=(0.04, 0.05, 0.06)),
        "cylinder": Obstacle("cylinder", centre, R, radius=0.04, half_length=0.1),
        "capsule": Obstacle("capsule", centre, R, radius=0.04, half_length=0.1),
    }[kind]


@pytest.mark.parametrize("kind", ["sphere", "box", "cylinder", "capsule"])
def test_signed_distances_agree_across_simulators(kind):
    """The Panda's distance to an obstacle placed beside one of its links, in both simulators: within 6 mm (pybullet
    keeps a collision margin around meshes, ~1 mm here; boxes' penetration depths are estimated differently), and the
    same sign wherever either is more than 6 mm from contact; the ground too."""
    r = _robot("panda")
    worlds = [open_world(r, WorldSettings(), _params(s)) for s in SIMS]
    try:
        g = np.random.default_rng(2)
        home = np.array(r.params.home)
        pairs = []
        for i in range(8):
            q = np.clip(home + 0.3 * g.standard_normal(r.dof), r.lower.numpy(), r.upper.numpy())
            c = r.sphere_centres(torch.tensor(q[None]))[0].numpy()
            beside = c[g.integers(len(c))] + [0.08 if i % 2 else 0.25, 0, 0] + 0.03 * g.standard_normal(3)
            o = _near_obstacle(kind, beside, g.standard_normal(3))
            for w in worlds:
                w.set_obstacles([o])
                w.set_ground(0.0)
                w.reset(_full(r, q), np.zeros(r.dof + 2))
            pairs.append([w.obstacle_distance(0.3) for w in worlds])
            pairs.append([w.ground_distance("panda_link4", 1.0) for w in worlds])
        pairs_np = np.array(pairs)
        assert np.abs(pairs_np[:, 0] - pairs_np[:, 1]).max() <= 6e-3, pairs
        far = np.abs(pairs_np).min(1) > 6e-3
        assert (np.sign(pairs_np[far, 0]) == np.sign(pairs_np[far, 1])).all(), pairs
        assert (pairs_np[::2, 0] < 0).any() and (pairs_np[::2, 0] > 0).any(), pairs  # contact and clearance both met
    finally:
        for w in worlds:
            w.close()


@pytest.mark.parametrize("sim", SIMS)
def test_renders_show_the_scene_where_the_camera_projects_it(sim):
    """Colour, depth and segmentation through one camera: the goal marker, an obstacle and the robot are labelled
    where ``Camera.project`` puts them, at the depth the geometry gives (to 2 cm)."""
    if sim == "mujoco":
        needs_mujoco_rendering()
    r = _robot("panda")
    world = open_world(r, WorldSettings(pictures=True), _params(sim))
    try:
        goal, centre = np.array([0.5, -0.25, 0.45]), np.array([0.55, 0.2, 0.3])
        world.set_obstacles([Obstacle("sphere", centre, radius=0.06)])
        world.set_ground(0.0)
        world.set_goal_marker(goal)
        world.reset(_full(r, np.array(r.params.home)), np.zeros(r.dof + 2))
        cam = Camera(1.4, -30.0, -35.0, (0.3, 0.0, 0.3))
        im = world.render(cam, 160, 120)
        assert isinstance(im, Images) and im.rgb.shape == (120, 160, 3) and im.rgb.dtype == np.uint8
        for point, label, radius in ((goal, GOAL_MARKER, 0.03), (centre, 1, 0.06)):
            col, row = cam.project(point[None], 160, 120)[0].round().astype(int)
            assert im.segmentation[row, col] == label, (
                sim,
                label,
                im.segmentation[row - 1 : row + 2, col - 1 : col + 2],
            )
            along = float(-(cam.view_matrix() @ np.r_[point, 1.0])[2])  # depth of the centre along the optical axis
            assert along - radius - 0.02 <= im.depth[row, col] <= along, (sim, label, im.depth[row, col], along)
        labels = set(np.unique(im.segmentation).tolist())
        assert {ROBOT, GROUND, GOAL_MARKER, 1} <= labels <= {ROBOT, GROUND, GOAL_MARKER, 1, BACKGROUND}
        assert np.isfinite(im.depth[im.segmentation == ROBOT]).all()
    finally:
        world.close()


def test_torque_rollouts_agree_across_simulators():
    """The Franka expert's torque-mode rollouts in pybullet and in MuJoCo from the same starts (no contact): both
    realise the tree's q̈ by computed torque, so they agree to 1e-6 rad over 0.5 s at 1 kHz; the clearances differ
    by pybullet's margin (< 3 mm)."""
    from manipulators import franka_tree_spec

    import rmpfusion
    from rmpfusion.envs.manipulator_tree import with_weights

    weights = yaml.safe_load((CONF / "expert" / "franka.yaml").read_text())
    out = []
    for sim in SIMS:
        env = franka_env(sim={"type": sim}, control_rate=1000.0)
        expert = rmpfusion.build_tree(with_weights(franka_tree_spec(1), weights), aux_dims=env.aux_dims())
        g = torch.Generator().manual_seed(0)
        q0, qd0, aux = env.sample_initial_states(env.sample_envs(1, g), 2, g)
        with torch.no_grad():
            out.append((q0, env.rollout(expert, q0, qd0, aux, horizon=0.5, record_every=0.1, mode="torque")))
        env.close()
    (qa, a), (qb, b) = out
    assert torch.equal(qa, qb)  # the same starts: the clearance checks agree on them
    assert a.error == b.error == [None, None]
    assert float((a.q - b.q).abs().max()) < 1e-6
    assert float((a.min_clearance - b.min_clearance).abs().max()) < 3e-3


# ---------------------------------------------------------------- the sim: block


def test_the_sim_block_refuses_what_cannot_work():
    from rmpfusion.pipeline.validate import ConfigError, resolve_and_validate

    with pytest.raises(ConfigError, match=r"env\.sim.*unknown simulator 'mujuco'; did you mean 'mujoco'"):
        resolve_and_validate(compose_cfg(["experiment=franka", "+env.sim.type=mujuco"]))
    with pytest.raises(ConfigError, match=r"env\.sim.*integrator"):
        resolve_and_validate(compose_cfg(["experiment=franka", "sim=mujoco", "env.sim.integrator=leapfrog"]))
    with pytest.raises(ConfigError, match=r"sim 'mujoco' has no window.*env\.gui=false"):
        resolve_and_validate(compose_cfg(["experiment=franka", "sim=mujoco", "env.gui=true"]))
    run = resolve_and_validate(compose_cfg(["experiment=franka", "sim=mujoco"]))
    assert run.env.sim.type == "mujoco"
    assert resolve_and_validate(compose_cfg(["experiment=franka"])).env.sim.type == "pybullet"  # the default


# ---------------------------------------------------------------- a third simulator, as a plugin writes one


class IdealParams(SimulatorParams):
    pass


class IdealWorld(SimWorld):
    """A simulator a plugin could ship: the robot as its control spheres, a unit-inertia double integrator (q̈ is the
    torque), sphere and cylinder obstacles measured analytically, pictures drawn as discs through the camera."""

    Params = IdealParams

    def __init__(self, robot, settings, params):
        super().__init__(robot, settings, params)
        n = robot.dof + len(robot.held_joints())
        self.q, self.qd = np.zeros(n), np.zeros(n)
        self.obstacles: list[Obstacle] = []
        self.ground: float | None = None
        self.steps = 0

    def set_obstacles(self, obstacles):
        if any(o.kind not in ("sphere", "cylinder") for o in obstacles):
            raise SimulationError("ideal: spheres and cylinders only")
        self.obstacles = list(obstacles)

    def move_obstacle(self, slot, center):
        o = self.obstacles[slot]
        self.obstacles[slot] = Obstacle(o.kind, np.asarray(center), o.rotation, o.radius, o.half_extents, o.half_length)

    def set_ground(self, height):
        self.ground = height

    def set_goal_marker(self, position):
        pass

    def reset(self, q, qd):
        self.q, self.qd = np.array(q, dtype=float), np.array(qd, dtype=float)

    def state(self):
        return self.q.copy(), self.qd.copy()

    def inverse_dynamics(self, q, qd, qdd):
        return np.asarray(qdd, dtype=float)

    def step(self, torque):
        self.qd = self.qd + self.settings.timestep * np.asarray(torque)
        self.q = self.q + self.settings.timestep * self.qd
        self.steps += 1

    def _spheres(self):
        q = torch.tensor(self.q[None, : self.robot.dof])
        return self.robot.sphere_centres(q)[0].numpy(), np.array([cp.radius for cp in self.robot.params.control_points])

    def obstacle_distance(self, query):
        centres, radii = self._spheres()
        best = query
        for o in self.obstacles:
            rel = centres - o.center
            if o.kind == "sphere":
                d = np.linalg.norm(rel, axis=1) - o.radius
            else:
                axis = o.rotation[:, 2]
                along = rel @ axis
                radial = np.linalg.norm(rel - along[:, None] * axis, axis=1) - o.radius
                d = np.maximum(radial, np.abs(along) - o.half_length)
            best = min(best, float((d - radii).min()))
        return best

    def ground_distance(self, link, query):
        if self.ground is None:
            return query
        centres, radii = self._spheres()
        mine = [i for i, cp in enumerate(self.robot.params.control_points) if cp.link == link]
        return min([query, *(float(centres[i, 2] - radii[i] - self.ground) for i in mine)])

    def link_frames(self):
        fk = self.robot.chain.forward_kinematics(torch.tensor(self.q[None, : self.robot.dof]))
        return {k: (p[0].numpy(), R[0].numpy()) for k, (R, p) in fk.items()}

    def link_boxes(self):
        centres, radii = self._spheres()
        out = {}
        for i, cp in enumerate(self.robot.params.control_points):
            lo, hi = centres[i] - radii[i], centres[i] + radii[i]
            old = out.get(cp.link, (lo, hi))
            out[cp.link] = (np.minimum(old[0], lo), np.maximum(old[1], hi))
        return out

    def render(self, camera, width, height):
        rgb = np.full((height, width, 3), 255, np.uint8)
        depth, seg = np.full((height, width), np.inf), np.full((height, width), BACKGROUND)
        centres, _ = self._spheres()
        rows, cols = np.mgrid[:height, :width]
        for label, points in ((ROBOT, centres), *((k + 1, o.center[None]) for k, o in enumerate(self.obstacles))):
            for c, r in camera.project(points, width, height):
                disc = (cols - c) ** 2 + (rows - r) ** 2 <= 9
                rgb[disc], seg[disc] = (80, 80, 80) if label == ROBOT else (200, 40, 40), label
        return Images(rgb, depth, seg)

    def close(self):
        pass


@pytest.fixture
def ideal_simulator():
    SIMULATORS.register("ideal")(IdealWorld)
    yield IdealWorld
    SIMULATORS.unregister("ideal")


def test_a_plugin_simulator_runs_an_experiment(ideal_simulator, tmp_path, monkeypatch):
    """A simulator registered from outside rmpfusion (this test's IdealWorld) is chosen with ``env.sim.type``, and
    a tiny Franka experiment runs through it end to end: start sampling, torque-mode evaluation, collisions and the
    figures all go through the protocol (the worlds it opened stepped), with no simulator-specific code in the task."""
    from rmpfusion.pipeline.run import run_experiment
    from rmpfusion.pipeline.validate import resolve_and_validate

    opened: list[IdealWorld] = []
    real_init = IdealWorld.__init__

    def recording_init(self, *a, **kw):
        real_init(self, *a, **kw)
        opened.append(self)

    monkeypatch.setattr(IdealWorld, "__init__", recording_init)
    overrides = [
        "experiment=franka", "+env.sim.type=ideal", "logger=disabled", "env.control_rate=60",
        "data.train_trajectories=3", "data.test_trajectories=2", "data.points=6", "env.demo_min_duration=0.2",
        "train.iterations=2", "train.batch_size=8", "train.snapshots=[0,2]", "train.checkpoint_every=2",
        "eval.horizon=0.5", "eval.compile=false", "env.render_times=[0.0,0.5]", "env.render_size=[64,48]",
    ]  # fmt: skip
    run = resolve_and_validate(compose_cfg(overrides))
    assert run.env.sim.type == "ideal"
    run_experiment(run, tmp_path, progress=False)
    m = json.loads((tmp_path / "metrics.json").read_text())
    rows = {r["policy"] for r in m["task_table"]}
    assert rows == {"expert", "learner-0", "learner-2"}
    assert opened and sum(w.steps for w in opened) >= 2 * 30  # torque-mode worlds: 2 test starts × 0.5 s at 60 Hz
    assert (tmp_path / "figures" / "task_execution.png").is_file()


def test_a_run_time_worlds_bodies_appear_move_and_vanish_in_both_simulators():
    """``obstacles_of_sets``: the present members of a run-time world (scenes.World) become simulator bodies with
    the world's numbers; after each change the two simulators measure the same clearance (to their margins), and a
    removed obstacle no longer counts."""
    from rmpfusion.scenes import ObstacleSet
    from rmpfusion.scenes import World as RunTimeWorld
    from rmpfusion.sims import obstacles_of_sets

    sets = [ObstacleSet(shape="sphere", n_max=3), ObstacleSet(shape="box", n_max=2)]
    world = RunTimeWorld(sets, goal=[0.5, 0.0, 0.4])
    r = _robot("panda")
    sims = [open_world(r, WorldSettings(), _params(s)) for s in SIMS]
    q = np.array(r.params.home)
    ee = r.ee_position(torch.tensor(q[None]))[0].numpy()
    try:
        for w in sims:
            w.reset(_full(r, q), np.zeros(r.dof + 2))
        seen = []
        for change in (
            lambda: world.add("sphere", name="ball", center=(ee + [0.25, 0.0, 0.0]).tolist(), radius=0.05),
            lambda: world.add(
                "box", name="wall", center=(ee + [0.0, 0.4, 0.0]).tolist(), half_extents=[0.05, 0.05, 0.1]
            ),
            lambda: world.move("ball", center=(ee + [0.2, 0.0, 0.0]).tolist()),
            lambda: world.remove("ball"),
        ):
            change()
            bodies = obstacles_of_sets(sets, world.aux())
            assert len(bodies) == len(world.present())
            for w in sims:
                w.set_obstacles(bodies)
            seen.append([w.obstacle_distance(0.5) for w in sims])
        d = np.array(seen)
        assert np.abs(d[:, 0] - d[:, 1]).max() < 4e-3, d
        assert d[1, 0] == pytest.approx(d[0, 0], abs=1e-9)  # the wall is farther than the ball
        assert d[2, 0] < d[1, 0] - 0.03  # the ball moved 5 cm nearer to the hand
        assert d[3, 0] > d[2, 0] + 0.03  # ... and its removal leaves the wall, farther away
        ball = obstacles_of_sets(sets, world.aux())
        assert [o.kind for o in ball] == ["box"] and np.allclose(ball[0].center, ee + [0.0, 0.4, 0.0])
    finally:
        for w in sims:
            w.close()
