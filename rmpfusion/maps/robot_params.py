"""Which robot a joint-space task map reads: the ``urdf:`` / ``joints:`` keys, and the Chain they name.

Every map on a robot's joint space (``forward_kinematics``, ``link_axis``, ``link_orientation``,
``link_sphere_distance``, ``velocity_scaled_joints``) takes its robot the same way: ``urdf:`` a file path or
``pkg://<package>/<path>`` inside an installed package, and ``joints:`` the actuated joints in configuration order
(default: every movable joint that mimics none; mimic joints follow their leaders, the others are frozen at 0),
and ``mount:`` where the base sits in the world. A robot description (conf/robot/) names them, and the manipulator
tree writes them into every such map.
"""

from __future__ import annotations

from typing import Annotated

from pydantic import Field, model_validator

from ..registry import Params

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
