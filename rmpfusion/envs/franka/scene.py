"""The pybullet side of the Franka environment: one world (the Panda on a fixed base, cylinder obstacles, a goal
marker) and its closest-point clearance, which defines collision in both rollout modes.

pybullet is imported on first use, so the environment (and the package) imports without it.
"""
from __future__ import annotations

import os
from typing import Mapping, Sequence

import numpy as np
from torch import Tensor

from ...maps.urdf import load_panda_urdf_path

ARM_JOINTS = list(range(7))  # pybullet joint indices of panda_joint1..7 in pybullet_data's panda.urdf
FINGER_JOINTS = [9, 10]


def _pb():
    import pybullet

    return pybullet


class _Scene:
    """One pybullet world: the Panda on a fixed base at the origin, cylinder obstacles and a goal marker."""

    def __init__(self, gui: bool = False, gravity: float = -9.81):
        p = _pb()
        self.p = p
        self.cid = p.connect(p.GUI if gui else p.DIRECT)
        if self.cid < 0:
            raise RuntimeError("pybullet: could not connect (a GUI may already be open)")
        self.robot = p.loadURDF(load_panda_urdf_path(), useFixedBase=True, flags=p.URDF_USE_INERTIA_FROM_FILE,
                                physicsClientId=self.cid)
        for j in range(-1, p.getNumJoints(self.robot, physicsClientId=self.cid)):
            # pybullet's default link damping is not in its inverse dynamics; remove it so the
            # computed-torque loop realises the commanded acceleration exactly
            p.changeDynamics(self.robot, j, linearDamping=0.0, angularDamping=0.0, jointDamping=0.0,
                             physicsClientId=self.cid)
        p.setGravity(0, 0, gravity, physicsClientId=self.cid)
        self.joints = ARM_JOINTS + FINGER_JOINTS
        p.setJointMotorControlArray(self.robot, self.joints, p.VELOCITY_CONTROL, forces=[0.0] * len(self.joints),
                                    physicsClientId=self.cid)
        self.obstacles: list[int] = []
        self.goal_marker: int | None = None

    def set_env(self, centers: np.ndarray, radii: np.ndarray, heights: Sequence[float], goal: np.ndarray | None,
                visual: bool = False) -> None:
        p, cid = self.p, self.cid
        for b in self.obstacles:
            p.removeBody(b, physicsClientId=cid)
        self.obstacles = []
        for c, r, h in zip(centers, radii, heights):
            col = p.createCollisionShape(p.GEOM_CYLINDER, radius=float(r), height=float(h), physicsClientId=cid)
            vis = p.createVisualShape(p.GEOM_CYLINDER, radius=float(r), length=float(h), rgbaColor=[0.8, 0.2, 0.2, 1],
                                      physicsClientId=cid) if visual else -1
            self.obstacles.append(p.createMultiBody(0.0, col, vis, [float(v) for v in c], physicsClientId=cid))
        if visual and goal is not None:
            if self.goal_marker is None:
                vis = p.createVisualShape(p.GEOM_SPHERE, radius=0.03, rgbaColor=[1.0, 0.6, 0.0, 1], physicsClientId=cid)
                self.goal_marker = p.createMultiBody(0.0, -1, vis, [0, 0, 0], physicsClientId=cid)
            p.resetBasePositionAndOrientation(self.goal_marker, [float(v) for v in goal], [0, 0, 0, 1],
                                              physicsClientId=cid)

    def add_ground(self) -> None:
        """pybullet_data's checkered plane at z = 0 (renders only: the robot's base sits on it)."""
        import pybullet_data

        self.p.loadURDF(os.path.join(pybullet_data.getDataPath(), "plane.urdf"), physicsClientId=self.cid)

    def reset(self, q: np.ndarray, qd: np.ndarray | None = None) -> None:
        qd = np.zeros(7) if qd is None else qd
        for i, j in enumerate(ARM_JOINTS):
            self.p.resetJointState(self.robot, j, float(q[i]), float(qd[i]), physicsClientId=self.cid)
        for j in FINGER_JOINTS:
            self.p.resetJointState(self.robot, j, 0.0, 0.0, physicsClientId=self.cid)

    def state(self) -> tuple[np.ndarray, np.ndarray]:
        """(q, q̇) of all 9 movable joints (arm then fingers)."""
        js = self.p.getJointStates(self.robot, self.joints, physicsClientId=self.cid)
        return np.array([s[0] for s in js]), np.array([s[1] for s in js])

    def clearance(self, query: float) -> float:
        """Smallest robot–obstacle distance, or ``query`` when nothing is closer than that."""
        best = query
        for ob in self.obstacles:
            for pt in self.p.getClosestPoints(self.robot, ob, query, physicsClientId=self.cid):
                best = min(best, pt[8])
        return best

    def close(self) -> None:
        try:
            self.p.disconnect(physicsClientId=self.cid)
        except Exception:  # noqa: BLE001 - already gone
            pass


def scene_args(aux: Mapping[str, Tensor], b: int, heights: Sequence[float]):
    """(centres (K, 3), radii (K,), heights, goal (3,) or None) of sample ``b`` of an aux dict, for ``set_env``."""
    K = len(heights)
    centers = np.array([aux[f"obstacle{k}_center"][b].tolist() for k in range(1, K + 1)]).reshape(K, 3)
    radii = np.array([float(aux[f"obstacle{k}_radius"][b].reshape(-1)[0]) for k in range(1, K + 1)])
    goal = np.array(aux["goal"][b].tolist()) if "goal" in aux else None
    return centers, radii, list(heights), goal


class HelperWorlds:
    """The environment's two long-lived worlds, opened on first use: one that checks collisions (start sampling,
    kinematic rollouts) and one that renders (figures). Rollouts in torque mode have worlds of their own."""

    def __init__(self, gravity: float):
        self.gravity = gravity
        self._checker: _Scene | None = None
        self._renderer: _Scene | None = None

    def checker(self) -> _Scene:
        if self._checker is None:
            self._checker = _Scene(gui=False, gravity=self.gravity)
        return self._checker

    def renderer(self) -> _Scene:
        if self._renderer is None:
            self._renderer = _Scene(gui=False, gravity=self.gravity)
            self._renderer.add_ground()
        return self._renderer

    def discard_checker(self) -> None:
        """Forget the collision world after a pybullet error: a broken world is not reused."""
        self._checker = None

    def close(self) -> None:
        for s in (self._checker, self._renderer):
            if s is not None:
                s.close()
        self._checker = self._renderer = None
