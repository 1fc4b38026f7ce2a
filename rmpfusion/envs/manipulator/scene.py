"""The pybullet side of the manipulator environment: one world (the robot on a fixed base, the scene's obstacles,
a ground plane, a goal marker) and its closest-point clearance, which defines collision in both rollout modes.

Obstacles are built from a sample's aux state (``scenes/aux.py``), the same numbers the tree reads, so what the
tree avoids and what pybullet collides with are one geometry. pybullet is imported on first use, so the
environment (and the package) imports without it.
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Mapping

import numpy as np
from torch import Tensor

from ...robots import URDFRobot
from ...scenes import Scene

_COLOUR = [0.8, 0.2, 0.2, 1]


def _pb():
    import pybullet

    return pybullet


def _quaternion_z_to(axis: np.ndarray) -> list[float]:
    """The rotation taking z to the unit ``axis``, as pybullet's (x, y, z, w)."""
    z = np.array([0.0, 0.0, 1.0])
    c = float(np.dot(z, axis))
    if c < -1 + 1e-12:
        return [1.0, 0.0, 0.0, 0.0]
    v = np.cross(z, axis)
    q = np.array([v[0], v[1], v[2], 1.0 + c])
    return (q / np.linalg.norm(q)).tolist()


def _quaternion_of(R: np.ndarray) -> list[float]:
    """A rotation matrix as pybullet's (x, y, z, w) quaternion (Shepperd's method)."""
    w = math.sqrt(max(0.0, 1.0 + R[0, 0] + R[1, 1] + R[2, 2])) / 2
    x = math.copysign(math.sqrt(max(0.0, 1.0 + R[0, 0] - R[1, 1] - R[2, 2])) / 2, R[2, 1] - R[1, 2])
    y = math.copysign(math.sqrt(max(0.0, 1.0 - R[0, 0] + R[1, 1] - R[2, 2])) / 2, R[0, 2] - R[2, 0])
    z = math.copysign(math.sqrt(max(0.0, 1.0 - R[0, 0] - R[1, 1] + R[2, 2])) / 2, R[1, 0] - R[0, 1])
    return [x, y, z, w]


def sample_aux(aux: Mapping[str, Tensor], b: int) -> dict[str, np.ndarray]:
    """Sample ``b``'s aux state as numpy vectors."""
    return {k: v[b].detach().cpu().numpy().reshape(-1) for k, v in aux.items()}


class _Scene:
    """One pybullet world: the robot on a fixed base at the origin, obstacles, a ground plane and a goal marker."""

    def __init__(self, robot: URDFRobot, gui: bool = False, gravity: float = -9.81):
        p = _pb()
        self.p = p
        self.cid = p.connect(p.GUI if gui else p.DIRECT)
        if self.cid < 0:
            raise RuntimeError("pybullet: could not connect (a GUI may already be open)")
        self.robot, self.arm, self.held = robot.load_into(p, self.cid)
        self.held_drive = robot.held_targets()
        self.ground_reach = self._links_that_can_touch_the_ground(robot)
        self.moving_links = list(self.ground_reach)
        for j in range(-1, p.getNumJoints(self.robot, physicsClientId=self.cid)):
            # pybullet's default link damping is not in its inverse dynamics; remove it so the
            # computed-torque loop realises the commanded acceleration exactly
            p.changeDynamics(
                self.robot, j, linearDamping=0.0, angularDamping=0.0, jointDamping=0.0, physicsClientId=self.cid
            )
        p.setGravity(0, 0, gravity, physicsClientId=self.cid)
        self.joints = self.arm + self.held
        p.setJointMotorControlArray(
            self.robot, self.joints, p.VELOCITY_CONTROL, forces=[0.0] * len(self.joints), physicsClientId=self.cid
        )
        self.obstacles: list[int] = []
        self.ground: int | None = None
        self.goal_marker: int | None = None

    def _links_that_can_touch_the_ground(self, robot: URDFRobot) -> dict[int, float]:
        """pybullet index -> highest lowest point (m) of the links whose lowest point changes height over the joints'
        range: the ones the ground check counts (found once per robot, ``ground_links``)."""
        key = (robot.urdf_path, tuple(robot.params.joints), repr(robot.params.mount))
        if key not in _GROUND_LINKS:
            _GROUND_LINKS[key] = ground_links(self, robot)
        return _GROUND_LINKS[key]

    def _shape(self, kind: str, a: Mapping[str, np.ndarray], k: int, visual: bool) -> tuple[int, int, list[float]]:
        p, cid, pre = self.p, self.cid, f"obstacle{k}_"
        r = float(a[pre + "radius"][0])
        if kind == "sphere":
            args, orient = {"radius": r}, [0.0, 0.0, 0.0, 1.0]
            shape = p.GEOM_SPHERE
        elif kind == "box":
            args, orient = (
                {"halfExtents": a[pre + "half_extents"].tolist()},
                _quaternion_of(a[pre + "rotation"].reshape(3, 3)),
            )
            shape = p.GEOM_BOX
        else:
            half = float(a[pre + ("half_height" if kind == "cylinder" else "half_length")][0])
            args, orient = {"radius": r, "height": 2 * half}, _quaternion_z_to(a[pre + "axis"])
            shape = p.GEOM_CYLINDER if kind == "cylinder" else p.GEOM_CAPSULE
        col = p.createCollisionShape(shape, physicsClientId=cid, **args)
        vis_args = {("length" if key == "height" else key): v for key, v in args.items()}
        vis = p.createVisualShape(shape, rgbaColor=_COLOUR, physicsClientId=cid, **vis_args) if visual else -1
        return col, vis, orient

    def set_env(self, scene: Scene, a: Mapping[str, np.ndarray], visual: bool = False) -> None:
        """Build sample ``a``'s obstacles (its aux as numpy, ``sample_aux``), the ground plane, and a goal marker."""
        p, cid = self.p, self.cid
        for b in self.obstacles + ([self.ground] if self.ground is not None else []):
            p.removeBody(b, physicsClientId=cid)
        self.obstacles, self.ground = [], None
        for k, o in enumerate(scene.obstacles, start=1):
            col, vis, orient = self._shape(o.type, a, k, visual)
            centre = a[f"obstacle{k}_center"].tolist()
            self.obstacles.append(p.createMultiBody(0.0, col, vis, centre, orient, physicsClientId=cid))
        if scene.ground is not None:
            col = p.createCollisionShape(p.GEOM_PLANE, physicsClientId=cid)
            vis = (
                p.createVisualShape(p.GEOM_PLANE, rgbaColor=[0.85, 0.85, 0.8, 1], physicsClientId=cid) if visual else -1
            )
            self.ground = p.createMultiBody(0.0, col, vis, [0.0, 0.0, scene.ground.height], physicsClientId=cid)
        if visual and "goal" in a:
            if self.goal_marker is None:
                vis = p.createVisualShape(p.GEOM_SPHERE, radius=0.03, rgbaColor=[1.0, 0.6, 0.0, 1], physicsClientId=cid)
                self.goal_marker = p.createMultiBody(0.0, -1, vis, [0, 0, 0], physicsClientId=cid)
            p.resetBasePositionAndOrientation(self.goal_marker, a["goal"].tolist(), [0, 0, 0, 1], physicsClientId=cid)

    def move_obstacles(self, scene: Scene, a: Mapping[str, np.ndarray]) -> None:
        """Put the moving obstacles where sample ``a`` (aux at the current time) has them."""
        for k, (o, body) in enumerate(zip(scene.obstacles, self.obstacles), start=1):
            if o.moving:
                _, orient = self.p.getBasePositionAndOrientation(body, physicsClientId=self.cid)
                self.p.resetBasePositionAndOrientation(
                    body, a[f"obstacle{k}_center"].tolist(), orient, physicsClientId=self.cid
                )

    def add_floor(self) -> None:
        """pybullet_data's checkered plane at z = 0 (renders only: the robot's base sits on it)."""
        import os

        import pybullet_data

        self.p.loadURDF(os.path.join(pybullet_data.getDataPath(), "plane.urdf"), physicsClientId=self.cid)

    def reset(self, q: np.ndarray, qd: np.ndarray | None = None) -> None:
        """The actuated joints at (q, q̇); the held ones where they follow (mimic joints) or stay (``held_targets``)."""
        qd = np.zeros(len(self.arm)) if qd is None else qd
        for i, j in enumerate(self.arm):
            self.p.resetJointState(self.robot, j, float(q[i]), float(qd[i]), physicsClientId=self.cid)
        index, gain, bias = self.held_drive
        q, qd = np.asarray(q, dtype=float), np.asarray(qd, dtype=float)
        for h, j in enumerate(self.held):
            value = gain[h] * q[index[h]] + bias[h] if len(q) else bias[h]
            rate = gain[h] * qd[index[h]] if len(qd) else 0.0
            self.p.resetJointState(self.robot, j, float(value), float(rate), physicsClientId=self.cid)

    def state(self) -> tuple[np.ndarray, np.ndarray]:
        """(q, q̇) of every simulated joint: the actuated ones, then the held ones."""
        js = self.p.getJointStates(self.robot, self.joints, physicsClientId=self.cid)
        return np.array([s[0] for s in js]), np.array([s[1] for s in js])

    def clearance(self, query: float) -> float:
        """Smallest robot–obstacle distance (the ground counts for the links the joints move), or ``query``
        when nothing is closer than that."""
        p, cid, best = self.p, self.cid, query
        for ob in self.obstacles:
            for pt in p.getClosestPoints(self.robot, ob, query, physicsClientId=cid):
                best = min(best, pt[8])
        if self.ground is not None:
            for link in self.moving_links:
                for pt in p.getClosestPoints(self.robot, self.ground, query, linkIndexA=link, physicsClientId=cid):
                    best = min(best, pt[8])
        return best

    def start_margin(self, required: float, query: float) -> float:
        """How far the robot is from being a fit start (≥ 0: it is): its distance to every obstacle minus
        ``required``, and each ground-checked link's distance to the ground minus ``required`` or, for a link whose
        lowest point can never rise that far above the ground (a UR5's upper arm beside its shoulder axis), minus
        the height it can reach, less 2 mm."""
        p, cid, worst = self.p, self.cid, query - required
        for ob in self.obstacles:
            for pt in p.getClosestPoints(self.robot, ob, query, physicsClientId=cid):
                worst = min(worst, pt[8] - required)
        if self.ground is not None:
            height = p.getBasePositionAndOrientation(self.ground, physicsClientId=cid)[0][2]
            for link, reach in self.ground_reach.items():
                need = min(required, max(0.0, reach - height - 0.002))
                for pt in p.getClosestPoints(self.robot, self.ground, query, linkIndexA=link, physicsClientId=cid):
                    worst = min(worst, pt[8] - need)
        return worst

    def close(self) -> None:
        with contextlib.suppress(Exception):  # already gone
            self.p.disconnect(physicsClientId=self.cid)


#: pybullet link index -> highest lowest point, of the links the ground check counts, per (URDF, actuated joints,
#: mount): found once per process
_GROUND_LINKS: dict[tuple, dict[int, float]] = {}
#: configurations sampled to see which links' lowest points change height, and the change that counts (m)
GROUND_SAMPLES, GROUND_TOLERANCE = 64, 1e-5


def ground_links(world: _Scene, robot: URDFRobot, samples: int = GROUND_SAMPLES, seed: int = 0) -> dict[int, float]:
    """pybullet index -> the highest its lowest point gets (m, world), of the links whose lowest point (of their
    collision shapes' bounding boxes) changes height by more than GROUND_TOLERANCE over ``samples`` configurations
    drawn uniformly within the joints' limits (a continuous joint over one turn). A link no joint can raise or lower
    (a shoulder that only spins about the vertical) always sits where it sits, however near the ground: checking it
    would refuse every start."""
    p, cid = world.p, world.cid
    lo = np.maximum(robot.lower.numpy(), -np.pi)
    hi = np.minimum(robot.upper.numpy(), np.pi)
    rng = np.random.default_rng(seed)
    qs = lo + (hi - lo) * rng.random((samples, robot.dof))
    links = [
        i
        for i in range(p.getNumJoints(world.robot, physicsClientId=cid))
        if robot.moves(p.getJointInfo(world.robot, i, physicsClientId=cid)[12].decode())
    ]
    lowest = np.empty((samples, len(links)))
    for s, q in enumerate(qs):
        world.reset(q)
        for c, i in enumerate(links):
            lowest[s, c] = p.getAABB(world.robot, i, physicsClientId=cid)[0][2]
    if not links:
        return {}
    varies = lowest.max(0) - lowest.min(0) > GROUND_TOLERANCE
    return {i: float(top) for i, v, top in zip(links, varies, lowest.max(0)) if v}


class HelperWorlds:
    """The environment's two long-lived worlds, opened on first use: one that checks collisions (start sampling,
    kinematic rollouts) and one that renders (figures). Rollouts in torque mode have worlds of their own."""

    def __init__(self, robot: URDFRobot, gravity: float):
        self.robot, self.gravity = robot, gravity
        self._checker: _Scene | None = None
        self._renderer: _Scene | None = None

    def checker(self) -> _Scene:
        if self._checker is None:
            self._checker = _Scene(self.robot, gui=False, gravity=self.gravity)
        return self._checker

    def renderer(self) -> _Scene:
        if self._renderer is None:
            self._renderer = _Scene(self.robot, gui=False, gravity=self.gravity)
            self._renderer.add_floor()
        return self._renderer

    def discard_checker(self) -> None:
        """Forget the collision world after a pybullet error: a broken world is not reused."""
        self._checker = None

    def close(self) -> None:
        for s in (self._checker, self._renderer):
            if s is not None:
                s.close()
        self._checker = self._renderer = None


def fixed_links_extent(world: _Scene, robot: URDFRobot) -> float:
    """How far (m) the links no actuated joint moves (the base and what is welded to it) reach horizontally from
    the base's vertical axis: the corners of their collision shapes' bounding boxes. An obstacle nearer than this
    (plus a start's clearance) leaves no start clear of it, whatever the joints do."""
    p, cid = world.p, world.cid
    base = np.array(robot.base_pose()[0][:2])
    names = {
        i: p.getJointInfo(world.robot, i, physicsClientId=cid)[12].decode()
        for i in range(p.getNumJoints(world.robot, physicsClientId=cid))
    }
    fixed = [-1] + [i for i, link in names.items() if not robot.moves(link)]
    extent = 0.0
    for i in fixed:
        lo, hi = (np.array(v[:2]) for v in p.getAABB(world.robot, i, physicsClientId=cid))
        corners = np.array([[x, y] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])])
        extent = max(extent, float(np.linalg.norm(corners - base, axis=1).max()))
    return extent
