"""Task maps registered by name: the coordinate changes on the edges of a tree."""

from . import (  # noqa: F401  (importing the modules registers their task maps)
    basic,
    distances,
    joint_scaling,
    kinematics,
    learned,
    moving_goal,
    orientation,
    self_collision,
    shapes,
)
from .basic import Compose, Identity, JointLimit, Linear, Offset, Select, build_map
from .distances import BoxDistance, CylinderDistance, SphereDistance
from .joint_scaling import VelocityScaledJoints
from .kinematics import Chain, ForwardKinematics
from .learned import Diffeomorphism, Normalize
from .moving_goal import MovingOffset
from .orientation import LinkAxis, LinkOrientation
from .self_collision import LinkSphereDistance, non_adjacent_link_pairs
from .shapes import BoxObstacle, CapsuleObstacle, CylinderObstacle, PlaneDistance, SphereObstacle

__all__ = [
    "BoxDistance",
    "BoxObstacle",
    "CapsuleObstacle",
    "Chain",
    "Compose",
    "CylinderDistance",
    "CylinderObstacle",
    "Diffeomorphism",
    "ForwardKinematics",
    "Identity",
    "JointLimit",
    "Linear",
    "LinkAxis",
    "LinkOrientation",
    "LinkSphereDistance",
    "MovingOffset",
    "Normalize",
    "Offset",
    "PlaneDistance",
    "Select",
    "SphereDistance",
    "SphereObstacle",
    "VelocityScaledJoints",
    "build_map",
    "non_adjacent_link_pairs",
]
