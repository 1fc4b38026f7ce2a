"""Whether a policy's rollouts diverged: what stops a run whose expert diverges (its demonstrations would teach
nothing) and what flags a learner that does.

Two tests, each with its tolerance stated here:

- growth: a trajectory whose state leaves ``GROWTH_LIMIT`` × (1 + |q₀| + |q̇₀|) (the largest coordinate, in the
  units of the configuration space) was not steered anywhere: an integrator blowing up, or a gain the step cannot
  resolve. A working policy moves the state by a few times its start, never by a hundred.
- Lyapunov, only where Theorem 2 applies (a tree of GDS leaves and positive weights among obstacles that stay
  put): V_r never rises along the closed loop, so a rise above ``V_RISE_LIMIT`` of max(|V_r|) over a trajectory
  (integration error of a sound step is orders of magnitude below that) says the rollout is not the closed loop
  the theorem describes.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

#: A trajectory diverged when its state's largest coordinate passes this many times 1 + that of its start.
GROWTH_LIMIT = 100.0
#: Where Theorem 2 applies, a trajectory diverged when V_r rises by more than this fraction of max |V_r|.
V_RISE_LIMIT = 0.1


@dataclass
class Divergence:
    """The diverged trajectories of a batch and why: ``samples`` (batch indices), ``reason`` (one line)."""

    samples: list[int]
    total: int
    reason: str

    def as_dict(self) -> dict:
        return {
            "trajectories": len(self.samples),
            "of": self.total,
            "samples": self.samples[:20],
            "reason": self.reason,
            "growth_limit": GROWTH_LIMIT,
            "v_rise_limit": V_RISE_LIMIT,
        }


def _growth(q: Tensor, qd: Tensor) -> Tensor:
    """(B,) the largest |coordinate| of each trajectory over its start's 1 + |q₀| + |q̇₀| (finite records only)."""
    size = torch.cat([q, qd], -1).abs().nan_to_num(nan=0.0, posinf=0.0).amax(-1)  # (T, B)
    return size.amax(0) / (1.0 + size[0])


def _v_rise(V: Tensor) -> Tensor:
    """(B,) the largest rise of V_r above an earlier record, relative to max |V_r| (finite records only)."""
    V = V.double()
    finite = V.isfinite()
    low = torch.where(finite, V, torch.full_like(V, float("inf"))).cummin(0).values
    rise = torch.where(finite, V - low, torch.zeros_like(V)).amax(0)
    scale = torch.where(finite, V.abs(), torch.zeros_like(V)).amax(0)
    return rise / (scale + 1e-12)


def divergence(q: Tensor, qd: Tensor, V: Tensor | None = None, theorem2_applies: bool = False) -> Divergence | None:
    """The trajectories of (T, B, d) records ``q``, ``qd`` (and ``V`` (T, B) where Theorem 2 applies) that diverged,
    or None when none did."""
    growth = _growth(q, qd)
    bad = growth > GROWTH_LIMIT
    parts = []
    if bool(bad.any()):
        parts.append(f"the state grew to {float(growth.max()):.3g} × (1 + its start) (tolerance {GROWTH_LIMIT:g} ×)")
    if V is not None and theorem2_applies:
        rise = _v_rise(V)
        rose = rise > V_RISE_LIMIT
        if bool(rose.any()):
            parts.append(
                f"V_r rose by {float(rise.max()):.3g} of its largest value where Theorem 2 says it never "
                f"rises (tolerance {V_RISE_LIMIT:g})"
            )
        bad |= rose
    if not parts:
        return None
    samples = bad.nonzero().flatten().tolist()
    return Divergence(samples, int(bad.numel()), "; ".join(parts))


def divergence_of_records(q: Tensor, qd: Tensor, traj_id: Tensor, t: Tensor) -> Divergence | None:
    """The growth test on flat records (a dataset: ``q``, ``qd`` (N, d), the trajectory and time of each row): the
    trajectories (``traj_id`` values) that diverged, or None."""
    ids, inv = traj_id.unique(return_inverse=True)
    size = torch.cat([q, qd], -1).abs().nan_to_num(nan=0.0, posinf=0.0).amax(-1).double()
    first_t = torch.full((len(ids),), float("inf"), dtype=t.dtype).scatter_reduce(0, inv, t, "amin")
    start = torch.zeros(len(ids), dtype=size.dtype).scatter_reduce(
        0, inv, torch.where(t == first_t[inv], size, torch.zeros_like(size)), "amax"
    )
    largest = torch.zeros(len(ids), dtype=size.dtype).scatter_reduce(0, inv, size, "amax")
    growth = largest / (1.0 + start)
    bad = growth > GROWTH_LIMIT
    if not bool(bad.any()):
        return None
    return Divergence(
        ids[bad].tolist(),
        len(ids),
        f"the state grew to {float(growth.max()):.3g} × (1 + its start) (tolerance {GROWTH_LIMIT:g} ×)",
    )
