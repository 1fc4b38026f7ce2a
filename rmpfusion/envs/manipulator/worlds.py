"""The manipulator task's side of a simulated world: a scene placed from one sample's aux state, the robot's held
joints driven with its actuated ones, and the clearance that defines collision in both rollout modes.

Everything here talks to the simulator through ``rmpfusion.sims.SimWorld`` alone (pybullet, MuJoCo or a plugin's,
``env.sim``); obstacles are built from a sample's aux state (``scenes/aux.py``), the same numbers the tree reads,
so what the tree avoids and what the simulator collides with are one geometry.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from torch import Tensor

from ...robots import URDFRobot
from ...robots.description import HeldJointGains
from ...scenes import Scene
from ...sims import SimulatorParams, SimWorld, WorldSettings, obstacles_of, open_world


def sample_aux(aux: Mapping[str, Tensor], b: int) -> dict[str, np.ndarray]:
    """Sample ``b``'s aux state as numpy vectors."""
    return {k: v[b].detach().cpu().numpy().reshape(-1) for k, v in aux.items()}


class TaskWorld:
    """A simulated world as the task uses it: the scene of one sample, the robot at (q, q̇) of its actuated joints
    (held joints where they follow or stay, ``URDFRobot.held_targets``), and its clearance from obstacles and ground."""

    def __init__(self, robot: URDFRobot, settings: WorldSettings, sim: SimulatorParams):
        self.robot = robot
        self.sim = open_world(robot, settings, sim)
        self.ground_reach = links_that_can_touch_the_ground(self.sim, robot, sim)
        self.ground_height: float | None = None

    def set_env(self, scene: Scene, a: Mapping[str, np.ndarray]) -> None:
        """Build sample ``a``'s obstacles (its aux as numpy, ``sample_aux``), the ground plane and the goal marker."""
        self.sim.set_obstacles(obstacles_of(scene, a))
        self.ground_height = None if scene.ground is None else scene.ground.height
        self.sim.set_ground(self.ground_height)
        self.sim.set_goal_marker(a.get("goal"))

    def move_obstacles(self, scene: Scene, a: Mapping[str, np.ndarray]) -> None:
        """Put the moving obstacles where sample ``a`` (aux at the current time) has them."""
        for k, o in enumerate(scene.obstacles, start=1):
            if o.moving:
                self.sim.move_obstacle(k - 1, a[f"obstacle{k}_center"])

    def reset(self, q: np.ndarray, qd: np.ndarray | None = None) -> None:
        """The actuated joints at (q, q̇); the held ones where they follow (mimic joints) or stay (``held_targets``)."""
        self.sim.reset(*self.robot.simulated_state(q, qd))

    def step_computed_torque(self, qdd: np.ndarray, gains: HeldJointGains) -> None:
        """One simulator step under the torques that realise the actuated joints' accelerations ``qdd`` (computed
        torque: the simulator's own inverse dynamics at its current state); the held joints get a PD acceleration
        toward where they follow their leader (mimic) or stay, inside the same inverse dynamics."""
        q_all, qd_all = self.sim.state()
        n = len(qdd)
        index, gain, _ = self.robot.held_targets()
        target, target_v = self.robot.held_state(q_all[:n], qd_all[:n])
        held = gain * qdd[index] - gains.kp * (q_all[n:] - target) - gains.kd * (qd_all[n:] - target_v)
        self.sim.step(self.sim.inverse_dynamics(q_all, qd_all, np.concatenate([qdd, held])))

    def clearance(self, query: float) -> float:
        """Smallest robot–obstacle distance (the ground counts for the links the joints move), or ``query``
        when nothing is closer than that."""
        best = self.sim.obstacle_distance(query)
        if self.ground_height is not None:
            for link in self.ground_reach:
                best = min(best, self.sim.ground_distance(link, query))
        return best

    def start_margin(self, required: float, query: float) -> float:
        """How far the robot is from being a fit start (≥ 0: it is): its distance to every obstacle minus
        ``required``, and each ground-checked link's distance to the ground minus ``required`` or, for a link whose
        lowest point can never rise that far above the ground (a UR5's upper arm beside its shoulder axis), minus
        the height it can reach, less 2 mm."""
        worst = min(query, self.sim.obstacle_distance(query)) - required
        if self.ground_height is not None:
            for link, reach in self.ground_reach.items():
                need = min(required, max(0.0, reach - self.ground_height - 0.002))
                worst = min(worst, self.sim.ground_distance(link, query) - need)
        return worst

    def close(self) -> None:
        self.sim.close()


#: link name -> highest lowest point, of the links the ground check counts, per (simulator, URDF, actuated joints,
#: mount): found once per process
_GROUND_LINKS: dict[tuple, dict[str, float]] = {}
#: configurations sampled to see which links' lowest points change height, and the change that counts (m)
GROUND_SAMPLES, GROUND_TOLERANCE = 64, 1e-5


def links_that_can_touch_the_ground(world: SimWorld, robot: URDFRobot, sim: SimulatorParams) -> dict[str, float]:
    """``ground_links`` of the robot, found once per (simulator, robot) in a process."""
    key = (sim.model_dump_json(), robot.urdf_path, tuple(robot.params.joints), repr(robot.params.mount))
    if key not in _GROUND_LINKS:
        _GROUND_LINKS[key] = ground_links(world, robot)
    return _GROUND_LINKS[key]


def ground_links(world: SimWorld, robot: URDFRobot, samples: int = GROUND_SAMPLES, seed: int = 0) -> dict[str, float]:
    """Link name -> the highest its lowest point gets (m, world), of the links whose lowest point (of their
    collision shapes' bounding boxes) changes height by more than GROUND_TOLERANCE over ``samples`` configurations
    drawn uniformly within the joints' limits (a continuous joint over one turn). A link no joint can raise or lower
    (a shoulder that only spins about the vertical) always sits where it sits, however near the ground: checking it
    would refuse every start."""
    lo = np.maximum(robot.lower.numpy(), -np.pi)
    hi = np.minimum(robot.upper.numpy(), np.pi)
    rng = np.random.default_rng(seed)
    qs = lo + (hi - lo) * rng.random((samples, robot.dof))
    lowest: dict[str, list[float]] = {}
    for q in qs:
        world.reset(*robot.simulated_state(q))
        for link, (low, _) in world.link_boxes().items():
            if robot.moves(link):
                lowest.setdefault(link, []).append(float(low[2]))
    return {link: max(zs) for link, zs in lowest.items() if max(zs) - min(zs) > GROUND_TOLERANCE}


def fixed_links_extent(world: SimWorld, robot: URDFRobot) -> float:
    """How far (m) the links no actuated joint moves (the base and what is welded to it) reach horizontally from
    the base's vertical axis: the corners of their collision shapes' bounding boxes. An obstacle nearer than this
    (plus a start's clearance) leaves no start clear of it, whatever the joints do."""
    base = np.array(robot.base_pose()[0][:2])
    extent = 0.0
    for link, (lo, hi) in world.link_boxes().items():
        if robot.moves(link):
            continue
        corners = np.array([[x, y] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])])
        extent = max(extent, float(np.linalg.norm(corners - base, axis=1).max()))
    return extent


class HelperWorlds:
    """The environment's two long-lived worlds, opened on first use: one that checks collisions (start sampling,
    kinematic rollouts) and one that renders (figures). Rollouts in torque mode have worlds of their own."""

    def __init__(self, robot: URDFRobot, gravity: float, sim: SimulatorParams):
        self.robot, self.gravity, self.sim = robot, gravity, sim
        self._checker: TaskWorld | None = None
        self._renderer: TaskWorld | None = None

    def checker(self) -> TaskWorld:
        if self._checker is None:
            self._checker = TaskWorld(self.robot, WorldSettings(gravity=self.gravity), self.sim)
        return self._checker

    def renderer(self) -> TaskWorld:
        if self._renderer is None:
            self._renderer = TaskWorld(self.robot, WorldSettings(gravity=self.gravity, pictures=True), self.sim)
        return self._renderer

    def discard_checker(self) -> None:
        """Forget the collision world after a simulator error: a broken world is not reused."""
        if self._checker is not None:
            self._checker.close()
        self._checker = None

    def close(self) -> None:
        for s in (self._checker, self._renderer):
            if s is not None:
                s.close()
        self._checker = self._renderer = None
