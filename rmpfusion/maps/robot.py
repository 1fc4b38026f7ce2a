"""Which robot a joint-space task map reads: the ``robot:`` / ``urdf:`` / ``joints:`` keys, and the Chain they name.

The maps of the robot leaves (``link_axis``, ``link_orientation``, ``link_sphere_distance``,
``velocity_scaled_joints``) take their robot exactly as ``forward_kinematics`` does: ``robot: panda`` (pybullet's
Panda URDF with panda_joint1..7 actuated), or ``urdf: <path>`` with every movable joint actuated, and ``joints:``
to choose the actuated joints and their order. Nothing here is specific to one robot but the ``panda`` shortcut.
"""
from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field, model_validator

from ..registry import Params
from .kinematics import Chain
from .urdf import PANDA_ARM_JOINTS, load_panda_urdf_path, parse_urdf

#: A point or direction in a link frame.
Vector3 = Annotated[list[float], Field(min_length=3, max_length=3)]


class RobotParams(Params):
    """The robot of a map: ``robot: panda`` or ``urdf: <path>`` (not both), and optionally the actuated ``joints``."""

    robot: Literal["panda"] | None = "panda"
    urdf: str | None = None
    joints: list[str] | None = None

    @model_validator(mode="after")
    def _one_source(self):
        if self.urdf is not None and self.robot is not None and "robot" in self.model_fields_set:
            raise ValueError("give either 'robot' or 'urdf', not both")
        if self.urdf is None and self.robot is None:
            raise ValueError("give 'robot' (panda) or 'urdf' (a path to a URDF file)")
        return self

    def source(self) -> str:
        """How error messages name the robot."""
        return f"robot '{self.robot}'" if self.urdf is None else f"URDF '{self.urdf}'"


def robot_chain(p: RobotParams, in_dim: int, what: str) -> Chain:
    """The kinematic chain ``p`` names, checked to be the parent space (one coordinate per actuated joint)."""
    if p.urdf is not None:
        path, default_joints = p.urdf, None
    else:
        path, default_joints = load_panda_urdf_path(), list(PANDA_ARM_JOINTS)
    chain = Chain(parse_urdf(path), p.joints if p.joints is not None else default_joints)
    if in_dim != chain.dof:
        raise ValueError(f"{what}: the parent space has dimension {in_dim} but {p.source()} has {chain.dof} actuated "
                         f"joints ({', '.join(chain.actuated)}); the parent must be the joint space")
    return chain


def path_joints(chain: Chain, link: str) -> tuple[list[int], list[bool]]:
    """The actuated joints from the root to ``link``, root first: (their coordinates in q, whether each is revolute).

    The same joints, in the same order, as the world axes ``Chain.path_frames`` returns for ``link``.
    """
    q_index, revolute = [], []
    for joint in chain.model.path_to(link):
        if joint.name in chain.actuated:
            q_index.append(chain.actuated.index(joint.name))
            revolute.append(joint.type != "prismatic")
    return q_index, revolute


def rigid_body_of(chain: Chain) -> dict[str, int]:
    """Link -> the rigid body it belongs to (numbered from the root's, 0): links joined by fixed joints or by
    movable joints that are not actuated (frozen by the chain) move as one body."""
    body = {chain.model.root: 0}
    count = 1
    for joint in chain.model.joints:  # parents before children
        if joint.name in chain.actuated:
            body[joint.child] = count
            count += 1
        else:
            body[joint.child] = body[joint.parent]
    return body
