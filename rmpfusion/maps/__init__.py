"""Task maps registered by name: the coordinate changes on the edges of a tree."""
from . import basic, distances, kinematics, shapes  # noqa: F401  (registration side effects)
from .basic import Compose, Identity, JointLimit, Linear, Offset, Select, build_map  # noqa: F401
from .distances import BoxDistance, CylinderDistance, SphereDistance  # noqa: F401
from .kinematics import Chain, ForwardKinematics  # noqa: F401
from .shapes import BoxObstacle, CapsuleObstacle, CylinderObstacle, PlaneDistance, SphereObstacle  # noqa: F401
