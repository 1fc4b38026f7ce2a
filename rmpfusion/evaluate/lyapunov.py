"""Checks of Theorem 2 on recorded rollouts: V_r(t) must not increase (dV/dt = −q̇ᵀ B q̇ ≤ 0).

Integration is inexact, so "does not increase" needs a tolerance. The rule used throughout, for
consecutive records V_t, V_{t+1} of one trajectory:

    V_{t+1} − V_t ≤ atol + rtol · max(|V_t|, |V_{t+1}|)

i.e. an increase is forgiven only when it is below ``rtol`` relative to the size of V itself (plus a tiny
absolute floor for V ≈ 0 at the goal). A non-finite V always counts as a violation.
"""

from __future__ import annotations

from torch import Tensor


def _increase(V: Tensor) -> tuple[Tensor, Tensor]:
    if V.dim() != 2:
        raise ValueError(f"V must be (T, B), got shape {tuple(V.shape)}")
    dV = V[1:] - V[:-1]
    scale = V[1:].abs().maximum(V[:-1].abs())
    return dV, scale


def lyapunov_monotone(V: Tensor, rtol: float = 1e-6, atol: float = 1e-9) -> Tensor:
    """(B,) bool: True when the trajectory's V never rises by more than ``atol + rtol·|V|`` between records."""
    dV, scale = _increase(V)
    ok = (dV <= atol + rtol * scale) | (dV <= 0)
    ok &= V[1:].isfinite() & V[:-1].isfinite()
    return ok.all(0)


def max_relative_increase(V: Tensor, atol: float = 1e-9) -> Tensor:
    """(B,) worst increase between consecutive records, relative to ``max(|V|) + atol``; ≤ 0 when monotone.

    The number to report when ``lyapunov_monotone`` fails: it says by how much (inf for non-finite V).
    """
    dV, scale = _increase(V)
    rel = dV / (scale + atol)
    rel = rel.nan_to_num(nan=float("inf"))
    return rel.max(0).values if rel.shape[0] else V.new_zeros(V.shape[1])


def energy_rate_residual(times: Tensor, V: Tensor, dissipation: Tensor) -> Tensor:
    """(T−2, B) residual dV/dt + q̇ᵀBq̇ at interior records, dV/dt by central differences.

    Theorem 2 says it is zero; on a smooth rollout it is O(record_every²), so a residual that does not shrink
    with the record interval points at a wrong curvature term (e.g. a missing ½ in Ξ_G) or a wrong h_i.
    ``dissipation`` is ``Rollout.dissipation``.
    """
    if V.shape != dissipation.shape or times.shape[0] != V.shape[0]:
        raise ValueError("times (T,), V (T, B) and dissipation (T, B) must agree")
    dt = (times[2:] - times[:-2])[:, None]
    dVdt = (V[2:] - V[:-2]) / dt
    return dVdt + dissipation[1:-1]
