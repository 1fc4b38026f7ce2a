"""Robots as the environment and the tree generator use them, and the ``robot:`` block that selects one.

A robot block is ``{type: <kind>, ...}`` like every other registry-typed block (``type`` defaults to ``urdf``, the
built-in kind: a fixed-base arm described by a URDF and ``RobotDescription``). A plugin adds a kind by registering
a class with ``rmpfusion.registry.ROBOTS`` whose ``Params`` subclasses ``RobotDescription`` (so every consumer
finds the fields it reads) and whose constructor takes those params. A robot carries no simulator code: simulators
load its resolved URDF (``urdf_path``) at its mount (``base_pose``), ``rmpfusion/sims/``.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping
from typing import Annotated, Any

import numpy as np
import torch
from pydantic import BeforeValidator, SerializeAsAny
from pydantic_core import PydanticCustomError
from torch import Tensor

from ..maps.kinematics import Chain, mount_matrix
from ..registry import ROBOTS, validate_kind
from .description import RobotDescription
from .packages import resolved_urdf


@ROBOTS.register("urdf")
class URDFRobot:
    """A fixed-base arm from its URDF: kinematics of the actuated joints, limits, end effector, control points."""

    Params = RobotDescription

    def __init__(self, params: RobotDescription):
        self.params = params
        self.name = params.name
        mount = None if params.mount is None else mount_matrix(params.mount.xyz, params.mount.rpy)
        self.chain = Chain(params.model(), params.joints, mount)
        limits = params.joint_limits()
        self.lower = torch.tensor([lim[0] for lim in limits], dtype=torch.float64)
        self.upper = torch.tensor([lim[1] for lim in limits], dtype=torch.float64)
        self.velocity_limit = torch.tensor([lim[2] for lim in limits], dtype=torch.float64)
        self.ee_offset = torch.tensor(params.end_effector.offset, dtype=torch.float64)

    @property
    def dof(self) -> int:
        return len(self.params.joints)

    @functools.cached_property
    def urdf_path(self) -> str:
        """The URDF simulators load: a copy with every mesh an absolute path (``robots/packages.py``), found once
        per robot (a torque-mode rollout opens a world per sample)."""
        return resolved_urdf(self.params.urdf, self.params.packages)

    def ee_position(self, q: Tensor) -> Tensor:
        """(B, 3) world position of the end-effector point."""
        link = self.params.end_effector.link
        R, p = self.chain.forward_kinematics(q, [link])[link]
        return p + (R @ self.ee_offset.to(q).unsqueeze(-1)).squeeze(-1)

    def sphere_centres(self, q: Tensor) -> Tensor:
        """(B, C, 3) world centres of the robot's control spheres at configurations ``q`` (B, dof), in the order of
        ``params.control_points``."""
        cps = self.params.control_points
        poses = self.chain.forward_kinematics(q, sorted({cp.link for cp in cps}))
        return torch.stack(
            [
                poses[cp.link][1]
                + (poses[cp.link][0] @ torch.tensor(cp.offset, dtype=q.dtype).unsqueeze(-1)).squeeze(-1)
                for cp in cps
            ],
            1,
        )

    def moves(self, link: str) -> bool:
        """Whether some actuated joint moves ``link`` (links fixed to the base cannot reach an obstacle's side)."""
        return any(
            j.name in self.params.joints or j.name in self.chain.followers for j in self.params.model().path_to(link)
        )

    def held_joints(self) -> list[str]:
        """Movable joints that are not actuated: those that follow an actuated joint (URDF <mimic>), and the others
        (fingers), which simulators hold at 0 (or at their mimic offset), as the kinematics does."""
        return [j for j in self.params.model().movable_joint_names() if j not in self.params.joints]

    def held_targets(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Where simulators hold the held joints, as (configuration index (0 when none), gain, bias) arrays: joint
        h's target is gain_h · q[index_h] + bias_h (gain 0 for a joint no actuated joint drives), so a mimic joint
        follows its leader and the others stay where the kinematics freezes them. Found once per robot (a torque-mode
        step reads them)."""
        return self._held_drive

    def held_state(self, q: np.ndarray, qd: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(positions, velocities) of the held joints at the actuated (q, q̇): mimic joints at gain·q + bias of their
        leader, the others at their bias."""
        index, gain, bias = self._held_drive
        if not len(q):
            return bias.astype(float), np.zeros(len(bias))
        return gain * q[index] + bias, gain * qd[index]

    def simulated_state(self, q: np.ndarray, qd: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(positions, velocities) of every joint a simulator moves, actuated then held (``held_state``), at the
        actuated (q, q̇) (q̇ = 0 when not given): the order of ``rmpfusion.sims.SimWorld.reset``."""
        q = np.asarray(q, dtype=float)
        qd = np.zeros(len(q)) if qd is None else np.asarray(qd, dtype=float)
        held, held_v = self.held_state(q, qd)
        return np.concatenate([q, held]), np.concatenate([qd, held_v])

    @functools.cached_property
    def _held_drive(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        index, gain, bias = [], [], []
        chain = self.chain
        for name in self.held_joints():
            k = [j.name for j in chain.model.joints].index(name)
            index.append(max(chain._qidx[k], 0))
            gain.append(chain._gain[k])
            bias.append(chain._bias[k])
        return np.array(index, dtype=int), np.array(gain), np.array(bias)

    def base_pose(self) -> tuple[list[float], list[float]]:
        """(position, quaternion x y z w) of the base in the world: the ``mount``."""
        if self.params.mount is None:
            return [0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]
        r, p_, y = self.params.mount.rpy
        cr, sr, cp, sp, cy, sy = (
            math.cos(r / 2),
            math.sin(r / 2),
            math.cos(p_ / 2),
            math.sin(p_ / 2),
            math.cos(y / 2),
            math.sin(y / 2),
        )
        quaternion = [
            sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy,
            cr * cp * cy + sr * sp * sy,
        ]
        return list(self.params.mount.xyz), quaternion


def _robot_block(value: Any) -> Any:
    """Validate a robot block by its kind's own model (``type`` defaults to the URDF kind)."""
    if isinstance(value, RobotDescription) or not isinstance(value, Mapping):
        return (
            value
            if isinstance(value, RobotDescription)
            else _refuse(f"a robot is a mapping (conf/robot/), given {value!r}")
        )
    return validate_kind(ROBOTS, value, "urdf", "robot")


def _refuse(message: str):
    raise PydanticCustomError("robot", "{message}", {"message": message})


#: A field holding a robot block, validated by the kind it names.
RobotField = Annotated[SerializeAsAny[RobotDescription], BeforeValidator(_robot_block)]


def build_robot(params: RobotDescription) -> URDFRobot:
    """The robot object of a validated robot block."""
    return ROBOTS.get(params.type).obj(params)
