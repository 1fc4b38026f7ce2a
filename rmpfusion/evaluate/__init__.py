"""Metrics on rollouts: Lyapunov monitoring (Theorem 2), success and collision rates."""

from .certificate import Certificate, certify  # noqa: F401
from .lyapunov import energy_rate_residual, lyapunov_monotone, max_relative_increase  # noqa: F401
