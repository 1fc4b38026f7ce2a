"""Environments; importing this package registers them in ``rmpfusion.registry.ENVS``."""
from .particle2d import Particle2D, Rollout  # noqa: F401
