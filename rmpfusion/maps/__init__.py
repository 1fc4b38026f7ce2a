"""Task maps registered by name: the coordinate changes on the edges of a tree."""

from . import (
    basic,
    distances,
    joint_scaling,
    kinematics,
    learned,
    moving_goal,
    orientation,
    self_collision,  # noqa: F401
    shapes,
)  # (registration side effects)
from .basic import Compose, Identity, JointLimit, Linear, Offset, Select, build_map  # noqa: F401
from .distances import BoxDistance, CylinderDistance, SphereDistance  # noqa: F401
from .joint_scaling import VelocityScaledJoints  # noqa: F401
from .kinematics import Chain, ForwardKinematics  # noqa: F401
from .learned import Diffeomorphism, Normalize  # noqa: F401
from .moving_goal import MovingOffset  # noqa: F401
from .orientation import LinkAxis, LinkOrientation  # noqa: F401
from .self_collision import LinkSphereDistance, non_adjacent_link_pairs  # noqa: F401
from .shapes import BoxObstacle, CapsuleObstacle, CylinderObstacle, PlaneDistance, SphereObstacle  # noqa: F401
