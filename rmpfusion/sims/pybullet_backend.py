"""pybullet as a simulator backend (``sim: {type: pybullet}``, the default): one physics client per world, the
robot loaded with its URDF's inertias on a fixed base, obstacles as static bodies, distances from pybullet's
closest points, pictures from its headless tiny renderer. pybullet is imported when a world opens."""

from __future__ import annotations

import contextlib
import functools
import math
import os
from collections.abc import Callable, Sequence
from typing import Any, TypeVar

import numpy as np

from ..registry import SIMULATORS
from ..robots import URDFRobot
from .camera import FAR, Camera, linear_depth
from .config import SimulatorParams
from .protocol import BACKGROUND, GOAL_MARKER, GROUND, ROBOT, Images, Obstacle, SimulationError, SimWorld, WorldSettings

_OBSTACLE_COLOUR = [0.8, 0.2, 0.2, 1]
_GROUND_COLOUR = [0.85, 0.85, 0.8, 1]
_GOAL_COLOUR = [1.0, 0.6, 0.0, 1]

F = TypeVar("F", bound=Callable[..., Any])


def _pybullet() -> Any:
    import pybullet  # when a world opens: the package imports without pybullet

    return pybullet


def _engine_errors(method: F) -> F:
    """The method with pybullet's own error raised as ``SimulationError`` (the protocol's)."""

    @functools.wraps(method)
    def wrapped(self: PyBulletWorld, *args: Any, **kwargs: Any) -> Any:
        try:
            return method(self, *args, **kwargs)
        except self.p.error as e:
            raise SimulationError(f"pybullet: {e}") from e

    return wrapped  # type: ignore[return-value]  # same signature as method


def quaternion_of(R: np.ndarray) -> list[float]:
    """A rotation matrix as pybullet's (x, y, z, w) quaternion (Shepperd's method)."""
    w = math.sqrt(max(0.0, 1.0 + R[0, 0] + R[1, 1] + R[2, 2])) / 2
    x = math.copysign(math.sqrt(max(0.0, 1.0 + R[0, 0] - R[1, 1] - R[2, 2])) / 2, R[2, 1] - R[1, 2])
    y = math.copysign(math.sqrt(max(0.0, 1.0 - R[0, 0] + R[1, 1] - R[2, 2])) / 2, R[0, 2] - R[2, 0])
    z = math.copysign(math.sqrt(max(0.0, 1.0 - R[0, 0] - R[1, 1] + R[2, 2])) / 2, R[1, 0] - R[0, 1])
    return [x, y, z, w]


class PyBulletParams(SimulatorParams):
    """pybullet has no settings of its own here: the step, gravity and GUI come from the environment."""


@SIMULATORS.register("pybullet")
class PyBulletWorld(SimWorld):
    """One pybullet physics client (DIRECT, or the GUI when ``settings.gui``)."""

    Params = PyBulletParams
    has_window = True

    def __init__(self, robot: URDFRobot, settings: WorldSettings, params: PyBulletParams | None = None):
        super().__init__(robot, settings, params or PyBulletParams())
        p = self.p = _pybullet()
        self.cid = p.connect(p.GUI if settings.gui else p.DIRECT)
        if self.cid < 0:
            raise SimulationError("pybullet: could not connect (a GUI may already be open)")
        try:
            self._load_robot()
            p.setGravity(0, 0, settings.gravity, physicsClientId=self.cid)
            p.setTimeStep(settings.timestep, physicsClientId=self.cid)
            if settings.pictures:
                import pybullet_data  # pybullet's own data, installed with it

                p.loadURDF(os.path.join(pybullet_data.getDataPath(), "plane.urdf"), physicsClientId=self.cid)
        except p.error as e:
            self.close()
            raise SimulationError(f"pybullet: could not load {robot.urdf_path}: {e}") from e
        self.obstacles: list[int] = []
        self.ground: int | None = None
        self.goal_marker: int | None = None

    @property
    def _visual(self) -> bool:
        return self.settings.pictures or self.settings.gui

    def _load_robot(self) -> None:
        """The robot on a fixed base at its mount; its links' damping removed (pybullet's default damping is not in
        its inverse dynamics: without it, computed torque realises the commanded acceleration exactly); the
        default velocity motors off."""
        p, cid, robot = self.p, self.cid, self.robot
        position, orientation = robot.base_pose()
        self.body = p.loadURDF(
            robot.urdf_path,
            position,
            orientation,
            useFixedBase=True,
            flags=p.URDF_USE_INERTIA_FROM_FILE,
            physicsClientId=cid,
        )
        n = p.getNumJoints(self.body, physicsClientId=cid)
        info = [p.getJointInfo(self.body, i, physicsClientId=cid) for i in range(n)]
        joint_index = {j[1].decode(): j[0] for j in info}
        self.link_index = {j[12].decode(): j[0] for j in info}
        self.link_index[p.getBodyInfo(self.body, physicsClientId=cid)[0].decode()] = -1
        self.joints = [joint_index[j] for j in (*robot.params.joints, *robot.held_joints())]
        for j in range(-1, n):
            p.changeDynamics(self.body, j, linearDamping=0.0, angularDamping=0.0, jointDamping=0.0, physicsClientId=cid)
        p.setJointMotorControlArray(
            self.body, self.joints, p.VELOCITY_CONTROL, forces=[0.0] * len(self.joints), physicsClientId=cid
        )

    # ---------------------------------------------------------------- the scene
    def _shape(self, o: Obstacle) -> tuple[int, int, list[float]]:
        p, cid = self.p, self.cid
        args: dict[str, Any]
        if o.kind == "sphere":
            shape, args = p.GEOM_SPHERE, {"radius": o.radius}
        elif o.kind == "box":
            shape, args = p.GEOM_BOX, {"halfExtents": list(o.half_extents)}
        else:
            shape = p.GEOM_CYLINDER if o.kind == "cylinder" else p.GEOM_CAPSULE
            args = {"radius": o.radius, "height": 2 * o.half_length}
        orientation = [0.0, 0.0, 0.0, 1.0] if o.kind == "sphere" else quaternion_of(o.rotation)
        col = p.createCollisionShape(shape, physicsClientId=cid, **args)
        vis_args = {("length" if key == "height" else key): v for key, v in args.items()}
        vis = (
            p.createVisualShape(shape, rgbaColor=_OBSTACLE_COLOUR, physicsClientId=cid, **vis_args)
            if self._visual
            else -1
        )
        return col, vis, orientation

    @_engine_errors
    def set_obstacles(self, obstacles: Sequence[Obstacle]) -> None:
        p, cid = self.p, self.cid
        for body in self.obstacles:
            p.removeBody(body, physicsClientId=cid)
        self.obstacles = []
        for o in obstacles:
            col, vis, orientation = self._shape(o)
            self.obstacles.append(
                p.createMultiBody(0.0, col, vis, np.asarray(o.center).tolist(), orientation, physicsClientId=cid)
            )

    @_engine_errors
    def move_obstacle(self, slot: int, center: np.ndarray) -> None:
        body = self.obstacles[slot]
        _, orientation = self.p.getBasePositionAndOrientation(body, physicsClientId=self.cid)
        self.p.resetBasePositionAndOrientation(body, np.asarray(center).tolist(), orientation, physicsClientId=self.cid)

    @_engine_errors
    def set_ground(self, height: float | None) -> None:
        p, cid = self.p, self.cid
        if self.ground is not None:
            p.removeBody(self.ground, physicsClientId=cid)
            self.ground = None
        if height is None:
            return
        col = p.createCollisionShape(p.GEOM_PLANE, physicsClientId=cid)
        vis = p.createVisualShape(p.GEOM_PLANE, rgbaColor=_GROUND_COLOUR, physicsClientId=cid) if self._visual else -1
        self.ground = p.createMultiBody(0.0, col, vis, [0.0, 0.0, height], physicsClientId=cid)

    @_engine_errors
    def set_goal_marker(self, position: np.ndarray | None) -> None:
        p, cid = self.p, self.cid
        if position is None or not self._visual:
            if self.goal_marker is not None:
                p.removeBody(self.goal_marker, physicsClientId=cid)
                self.goal_marker = None
            return
        if self.goal_marker is None:
            vis = p.createVisualShape(p.GEOM_SPHERE, radius=0.03, rgbaColor=_GOAL_COLOUR, physicsClientId=cid)
            self.goal_marker = p.createMultiBody(0.0, -1, vis, [0, 0, 0], physicsClientId=cid)
        p.resetBasePositionAndOrientation(
            self.goal_marker, np.asarray(position).tolist(), [0, 0, 0, 1], physicsClientId=cid
        )

    # ---------------------------------------------------------------- the robot
    @_engine_errors
    def reset(self, q: np.ndarray, qd: np.ndarray) -> None:
        for i, j in enumerate(self.joints):
            self.p.resetJointState(self.body, j, float(q[i]), float(qd[i]), physicsClientId=self.cid)

    @_engine_errors
    def state(self) -> tuple[np.ndarray, np.ndarray]:
        js = self.p.getJointStates(self.body, self.joints, physicsClientId=self.cid)
        return np.array([s[0] for s in js]), np.array([s[1] for s in js])

    @_engine_errors
    def inverse_dynamics(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
        tau = self.p.calculateInverseDynamics(
            self.body,
            np.asarray(q).tolist(),
            np.asarray(qd).tolist(),
            np.asarray(qdd).tolist(),
            physicsClientId=self.cid,
        )
        return np.asarray(tau, dtype=float)

    @_engine_errors
    def step(self, torque: np.ndarray) -> None:
        p, cid = self.p, self.cid
        p.setJointMotorControlArray(
            self.body, self.joints, p.TORQUE_CONTROL, forces=np.asarray(torque).tolist(), physicsClientId=cid
        )
        p.stepSimulation(physicsClientId=cid)

    # ---------------------------------------------------------------- geometry
    @_engine_errors
    def obstacle_distance(self, query: float) -> float:
        best = query
        for body in self.obstacles:
            for pt in self.p.getClosestPoints(self.body, body, query, physicsClientId=self.cid):
                best = min(best, pt[8])
        return best

    @_engine_errors
    def ground_distance(self, link: str, query: float) -> float:
        if self.ground is None:
            return query
        best = query
        for pt in self.p.getClosestPoints(
            self.body, self.ground, query, linkIndexA=self.link_index[link], physicsClientId=self.cid
        ):
            best = min(best, pt[8])
        return best

    @_engine_errors
    def link_frames(self) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        p, cid, out = self.p, self.cid, {}
        for name, i in self.link_index.items():
            if i < 0:  # pybullet keeps the base's inertial frame: the link frame is that times the inverse offset
                com, com_orientation = p.getBasePositionAndOrientation(self.body, physicsClientId=cid)
                offset, offset_orientation = p.getDynamicsInfo(self.body, -1, physicsClientId=cid)[3:5]
                inverse = p.invertTransform(offset, offset_orientation)
                position, orientation = p.multiplyTransforms(com, com_orientation, *inverse)
            else:
                position, orientation = p.getLinkState(
                    self.body, i, computeForwardKinematics=True, physicsClientId=cid
                )[4:6]
            R = np.array(p.getMatrixFromQuaternion(orientation), dtype=float).reshape(3, 3)
            out[name] = (np.array(position, dtype=float), R)
        return out

    @_engine_errors
    def link_boxes(self) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        out = {}
        for name, i in self.link_index.items():
            lo, hi = self.p.getAABB(self.body, i, physicsClientId=self.cid)
            out[name] = (np.array(lo), np.array(hi))
        return out

    # ---------------------------------------------------------------- pictures and the end
    @_engine_errors
    def render(self, camera: Camera, width: int, height: int) -> Images:
        p = self.p
        view = camera.view_matrix().T.reshape(-1).tolist()  # pybullet takes OpenGL's column-major matrices
        proj = camera.projection_matrix(width, height).T.reshape(-1).tolist()
        img = p.getCameraImage(width, height, view, proj, renderer=p.ER_TINY_RENDERER, physicsClientId=self.cid)
        rgba = np.asarray(img[2], dtype=np.uint8).reshape(height, width, 4)
        depth = linear_depth(np.asarray(img[3], dtype=float).reshape(height, width))
        depth[depth >= FAR] = np.inf
        return Images(
            np.ascontiguousarray(rgba[..., :3]), depth, self._labels(np.asarray(img[4]).reshape(height, width))
        )

    def _labels(self, bodies: np.ndarray) -> np.ndarray:
        """pybullet's body ids per pixel as the protocol's segmentation labels."""
        labels = np.full(bodies.shape, GROUND, dtype=int)  # anything else drawn is the floor
        labels[bodies < 0] = BACKGROUND
        labels[bodies == self.body] = ROBOT
        for k, body in enumerate(self.obstacles):
            labels[bodies == body] = k + 1
        if self.goal_marker is not None:
            labels[bodies == self.goal_marker] = GOAL_MARKER
        return labels

    def close(self) -> None:
        with contextlib.suppress(Exception):  # already gone
            self.p.disconnect(physicsClientId=self.cid)
