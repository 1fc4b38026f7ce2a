"""Leaf RMP types registered by name: GDS leaves and exact ports of RMPflow's reference leaves."""

from . import (  # noqa: F401  (importing the modules registers their leaf RMPs)
    gds_leaves,
    moving_goal,
    orientation,
    rmpflow,
    velocity_limit,
)
from .gds_leaves import CollisionAvoidance, Damper, GoalAttractor, IdentityMetric, JointLimitBarrier
from .moving_goal import MovingGoalAttractor
from .orientation import OrientationAttractor
from .rmpflow import RMPflowCollisionAvoidance, RMPflowDamper, RMPflowGoalAttractor
from .velocity_limit import VelocityLimit

__all__ = [
    "CollisionAvoidance",
    "Damper",
    "GoalAttractor",
    "IdentityMetric",
    "JointLimitBarrier",
    "MovingGoalAttractor",
    "OrientationAttractor",
    "RMPflowCollisionAvoidance",
    "RMPflowDamper",
    "RMPflowGoalAttractor",
    "VelocityLimit",
]
