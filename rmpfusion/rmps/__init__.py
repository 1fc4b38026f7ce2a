"""Leaf RMP types registered by name: GDS leaves and exact ports of RMPflow's reference leaves."""

from . import gds_leaves, moving_goal, orientation, rmpflow, velocity_limit  # noqa: F401  (registration side effects)
from .gds_leaves import CollisionAvoidance, Damper, GoalAttractor, IdentityMetric, JointLimitBarrier  # noqa: F401
from .moving_goal import MovingGoalAttractor  # noqa: F401
from .orientation import OrientationAttractor  # noqa: F401
from .rmpflow import RMPflowCollisionAvoidance, RMPflowDamper, RMPflowGoalAttractor  # noqa: F401
from .velocity_limit import VelocityLimit  # noqa: F401
