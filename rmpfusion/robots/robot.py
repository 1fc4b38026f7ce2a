"""Robots as the environment and the tree generator use them, and the ``robot:`` block that selects one.

A robot block is ``{type: <kind>, ...}`` like every other registry-typed block (``type`` defaults to ``urdf``, the
built-in kind: a fixed-base arm described by a URDF and ``RobotDescription``). A plugin adds a kind by registering
a class with ``rmpfusion.registry.ROBOTS`` whose ``Params`` subclasses ``RobotDescription`` (so every consumer
finds the fields it reads) and whose constructor takes those params; it may override how the robot is loaded into
a simulator (``envs/manipulator/scene.py`` calls ``load_into``).
"""
from __future__ import annotations

from typing import Annotated, Any, Mapping

import torch
from pydantic import BeforeValidator, SerializeAsAny, ValidationError
from pydantic_core import PydanticCustomError
from torch import Tensor

from ..maps.kinematics import Chain
from ..maps.urdf import resolve_urdf_path
from ..registry import ROBOTS, RegistryError
from .description import RobotDescription


@ROBOTS.register("urdf")
class URDFRobot:
    """A fixed-base arm from its URDF: kinematics of the actuated joints, limits, end effector, control points."""

    Params = RobotDescription

    def __init__(self, params: RobotDescription):
        self.params = params
        self.name = params.name
        self.chain = Chain(params.model(), params.joints)
        limits = params.joint_limits()
        self.lower = torch.tensor([lim[0] for lim in limits], dtype=torch.float64)
        self.upper = torch.tensor([lim[1] for lim in limits], dtype=torch.float64)
        self.velocity_limit = torch.tensor([lim[2] for lim in limits], dtype=torch.float64)
        self.ee_offset = torch.tensor(params.end_effector.offset, dtype=torch.float64)

    @property
    def dof(self) -> int:
        return len(self.params.joints)

    @property
    def urdf_path(self) -> str:
        return resolve_urdf_path(self.params.urdf)

    def ee_position(self, q: Tensor) -> Tensor:
        """(B, 3) world position of the end-effector point."""
        link = self.params.end_effector.link
        R, p = self.chain.forward_kinematics(q, [link])[link]
        return p + (R @ self.ee_offset.to(q).unsqueeze(-1)).squeeze(-1)

    def moves(self, link: str) -> bool:
        """Whether some actuated joint moves ``link`` (links fixed to the base cannot reach an obstacle's side)."""
        return any(j.name in self.params.joints for j in self.params.model().path_to(link))

    def held_joints(self) -> list[str]:
        """Movable joints that are not actuated (fingers): simulators hold them at 0, as the kinematics does."""
        return [j for j in self.params.model().movable_joint_names() if j not in self.params.joints]

    def load_into(self, p: Any, cid: int) -> tuple[int, list[int], list[int]]:
        """Load the robot into pybullet world ``cid`` on a fixed base at the origin: (body, pybullet indices of the
        actuated joints in configuration order, indices of the held joints)."""
        body = p.loadURDF(self.urdf_path, useFixedBase=True, flags=p.URDF_USE_INERTIA_FROM_FILE, physicsClientId=cid)
        index = {p.getJointInfo(body, i, physicsClientId=cid)[1].decode(): i
                 for i in range(p.getNumJoints(body, physicsClientId=cid))}
        return body, [index[j] for j in self.params.joints], [index[j] for j in self.held_joints()]


def _robot_block(value: Any) -> Any:
    """Validate a robot block by its kind's own model (``type`` defaults to the URDF kind)."""
    if isinstance(value, RobotDescription) or not isinstance(value, Mapping):
        return value if isinstance(value, RobotDescription) else _refuse(f"a robot is a mapping (conf/robot/), "
                                                                         f"given {value!r}")
    kind = value.get("type", "urdf")
    try:
        entry = ROBOTS.get(kind)
    except RegistryError as e:
        _refuse(f"type: {e}")
    try:
        return entry.params.model_validate({**value, "type": kind})
    except ValidationError as e:
        _refuse("; ".join((f"{'.'.join(map(str, err['loc']))}: " if err["loc"] else "")
                          + err["msg"].removeprefix("Value error, ") for err in e.errors()))


def _refuse(message: str):
    raise PydanticCustomError("robot", "{message}", {"message": message})


#: A field holding a robot block, validated by the kind it names.
RobotField = Annotated[SerializeAsAny[RobotDescription], BeforeValidator(_robot_block)]


def build_robot(params: RobotDescription) -> URDFRobot:
    """The robot object of a validated robot block."""
    return ROBOTS.get(params.type).obj(params)
