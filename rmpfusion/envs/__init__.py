"""Environments; importing this package registers them in ``rmpfusion.registry.ENVS``."""
from .franka import Franka, FrankaRollout  # noqa: F401
from .particle2d import Particle2D, Rollout  # noqa: F401
