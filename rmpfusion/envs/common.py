"""What every environment shares: closed-loop integrators, sampling by seed, rejection sampling of starts."""
from __future__ import annotations

from typing import Any, Callable, Mapping

import torch
from torch import Tensor


def qdd_of(out: Any) -> Tensor:
    """The acceleration of a policy's answer: a tensor, or a TreeOutput."""
    return out if isinstance(out, Tensor) else out.qdd


def semi_implicit_euler(accel, q, qd, dt, a=None):
    """Symplectic Euler: velocity first, then position with the new velocity (first order, no energy drift)."""
    if a is None:
        a = accel(q, qd)
    qd = qd + dt * a
    return q + dt * qd, qd


def rk4(accel, q, qd, dt, a=None):
    """Classical RK4 on the first-order system (q, q̇); ``a`` reuses an acceleration already evaluated at (q, q̇)."""
    k1v = accel(q, qd) if a is None else a
    k1x = qd
    k2x = qd + 0.5 * dt * k1v
    k2v = accel(q + 0.5 * dt * k1x, k2x)
    k3x = qd + 0.5 * dt * k2v
    k3v = accel(q + 0.5 * dt * k2x, k3x)
    k4x = qd + dt * k3v
    k4v = accel(q + dt * k3x, k4x)
    return (q + dt / 6 * (k1x + 2 * k2x + 2 * k3x + k4x),
            qd + dt / 6 * (k1v + 2 * k2v + 2 * k3v + k4v))


def redraw_until_ok(draw: Callable[[], tuple[Tensor, ...]], ok: Callable[[tuple[Tensor, ...], Mapping[str, Tensor]], Tensor],
                    aux: Mapping[str, Tensor], max_tries: int, failure: Callable[[int], str]) -> tuple[Tensor, ...]:
    """Rejection sampling of a batch: redraw every rejected sample until ``ok`` accepts it.

    ``ok`` is only asked about the samples still rejected (with their aux rows), so expensive checks
    (pybullet clearance) run on few samples; ``failure(n_left)`` is the error after ``max_tries`` rounds.
    """
    vals = draw()
    bad = ~ok(vals, aux)
    tries = 1
    while bool(bad.any()):
        if tries >= max_tries:
            raise RuntimeError(failure(int(bad.sum())))
        new = draw()
        idx = bad.nonzero().flatten()
        good = ok(tuple(v[idx] for v in new), {k: v[idx] for k, v in aux.items()})
        take = torch.zeros_like(bad)
        take[idx[good]] = True
        vals = tuple(torch.where(take.view(-1, *[1] * (v.dim() - 1)), nv, v) for v, nv in zip(vals, new))
        bad &= ~take
        tries += 1
    return vals


class SeededSampling:
    """Mixin: environments and initial states in one call, from a seed or a generator."""

    def sample(self, n_envs: int, n_per_env: int, seed: int | None = None,
               generator: torch.Generator | None = None) -> tuple[Tensor, Tensor, dict[str, Tensor]]:
        if generator is None and seed is not None:
            generator = torch.Generator().manual_seed(seed)
        return self.sample_initial_states(self.sample_envs(n_envs, generator), n_per_env, generator)
