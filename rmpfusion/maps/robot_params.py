"""Which robot a joint-space task map reads: the ``urdf:`` / ``joints:`` keys, and the Chain they name.

Every map on a robot's joint space (``forward_kinematics``, ``link_axis``, ``link_orientation``,
``link_sphere_distance``, ``velocity_scaled_joints``) takes its robot the same way: ``urdf:`` a file path or
``pkg://<package>/<path>`` inside an installed package, and ``joints:`` the actuated joints in configuration order
(default: every movable joint that mimics none; mimic joints follow their leaders, the others are frozen at 0),
and ``mount:`` where the base sits in the world. A robot description (conf/robot/) names them, and the manipulator
tree writes them into every such map.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Annotated

from pydantic import Field, model_validator

from ..registry import Params

if TYPE_CHECKING:
    from .kinematics import Chain

#: A point or direction in a link frame.
Vector3 = Annotated[list[float], Field(min_length=3, max_length=3)]


class Mount(Params):
    """Where a robot's base (its URDF's root link) sits in the world: a URDF-style origin."""

    xyz: Vector3 = Field(default_factory=lambda: [0.0, 0.0, 0.0], description="position (m)")
    rpy: Vector3 = Field(default_factory=lambda: [0.0, 0.0, 0.0], description="fixed-axis roll, pitch, yaw (rad)")

    def is_identity(self) -> bool:
        return not any(self.xyz) and not any(self.rpy)


class RobotParams(Params):
    """The robot of a map: its ``urdf``, optionally its actuated ``joints``, and where its base is ``mount``ed."""

    urdf: str = Field(description="the URDF: a file path, or pkg://<package>/<path> inside an installed package")
    joints: list[str] | None = Field(
        None,
        description="the actuated joints in configuration order (default: every movable joint; the others stay at 0)",
    )
    robot: str | None = Field(None, description="retired: a robot is named by its urdf and joints")
    mount: Mount | None = Field(None, description="the base's pose in the world (default: at the origin)")

    @model_validator(mode="before")
    @classmethod
    def _no_robot_names(cls, data):
        robot = data.get("robot") if isinstance(data, dict) else None
        if robot is not None:  # before the other fields: a stored config of old has urdf: null beside it
            raise ValueError(
                f"robot ({robot!r}) was retired: robots are described in conf/robot/<name>.yaml; write "
                f"that file's urdf and joints here instead (urdf: <its urdf>, joints: [<its joints>])"
            )
        return data

    def source(self) -> str:
        """How error messages name the robot."""
        return f"URDF '{self.urdf}'"


def path_joints(chain: Chain, link: str) -> tuple[list[int], list[bool]]:
    """The actuated joints from the root to ``link``, root first: (their coordinates in q, whether each is revolute).

    The same joints, in the same order, as the world axes ``Chain.path_frames`` returns for ``link``.
    """
    q_index, revolute = [], []
    for joint in chain.model.path_to(link):
        if joint.name in chain.followers:
            raise ValueError(
                f"link '{link}' is moved by joint '{joint.name}', which follows another (URDF <mimic>); "
                f"orientation maps do not follow mimic joints: choose a link above it"
            )
        if joint.name in chain.actuated:
            q_index.append(chain.actuated.index(joint.name))
            revolute.append(joint.type != "prismatic")
    return q_index, revolute


def rigid_body_of(chain: Chain) -> dict[str, int]:
    """Link -> the rigid body it belongs to (numbered from the root's, 0): links joined by fixed joints or by
    movable joints that no actuated joint drives (frozen by the chain) move as one body."""
    body = {chain.model.root: 0}
    count = 1
    for joint in chain.model.joints:  # parents before children
        if joint.name in chain.actuated or joint.name in chain.followers:
            body[joint.child] = count
            count += 1
        else:
            body[joint.child] = body[joint.parent]
    return body
