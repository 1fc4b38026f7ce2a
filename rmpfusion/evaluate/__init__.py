"""Metrics on rollouts: Lyapunov monitoring (Theorem 2), success and collision rates."""

from .certificate import Certificate, certify
from .lyapunov import energy_rate_residual, lyapunov_monotone, max_relative_increase

__all__ = ["Certificate", "certify", "energy_rate_residual", "lyapunov_monotone", "max_relative_increase"]
