"""Leaf RMP types registered by name: GDS leaves and exact ports of RMPflow's reference leaves."""
from . import gds_leaves, rmpflow  # noqa: F401  (registration side effects)
from .gds_leaves import CollisionAvoidance, Damper, GoalAttractor, IdentityMetric, JointLimitBarrier  # noqa: F401
from .rmpflow import RMPflowCollisionAvoidance, RMPflowDamper, RMPflowGoalAttractor  # noqa: F401
