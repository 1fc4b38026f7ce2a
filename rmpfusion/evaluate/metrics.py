"""Evaluation of a learner against its expert (paper §4.1 "Results"): batch-loss on the expert's test data,
online-loss on the learner's own rollouts (exposes covariate shift), success, collisions and the Lyapunov monitor.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable, Mapping

import torch
from torch import Tensor, nn

from .lyapunov import lyapunov_monotone


def _policy_of(learner: Any) -> Callable:
    """The callable whose output a rollout records: a TreeOutput (so V_r is monitored) for trees and learner-rmp."""
    from ..core.tree import RMPTree

    return learner if isinstance(learner, RMPTree) else getattr(learner, "policy", learner)


@torch.no_grad()
def batch_loss(learner: nn.Module, data, chunk: int = 4096) -> float:
    """MSE of learner vs expert q̈ over the whole dataset (same reduction as the training loss)."""
    n = len(data)
    total = 0.0
    for s in range(0, n, chunk):
        idx = torch.arange(s, min(n, s + chunk))
        q, qd, aux, qdd = data.select(idx)
        total += float(((learner(q, qd, aux) - qdd) ** 2).sum())
    return total / (n * data.qdd.shape[1])


@dataclass
class OnlineResult:
    loss: float
    rollout: Any  # envs.Rollout of the learner
    expert_qdd: Tensor  # (T, B, d): the expert's action at the learner's states every ``interval``


@torch.no_grad()
def online_loss(learner: nn.Module, expert: Callable, env, q0: Tensor, qd0: Tensor, aux: Mapping[str, Tensor],
                horizon: float, interval: float, record_every: float | None = None,
                progress: Callable | None = None) -> OnlineResult:
    """Roll the learner out from (q0, qd0); every ``interval`` seconds compare its q̈ with the expert's q̈ at that same state.

    ``record_every`` (a divisor of ``interval``) records the rollout more finely for figures and the Lyapunov
    monitor at no extra policy evaluations; the loss still uses only the ``interval`` records.
    """
    fine = record_every or interval
    stride = int(round(interval / fine))
    if stride < 1 or abs(stride * fine - interval) > 1e-9 * max(1.0, interval):
        raise ValueError(f"record_every={record_every} must divide interval={interval}")
    ro = env.rollout(_policy_of(learner), q0, qd0, aux, horizon=horizon, record_every=fine, progress=progress)
    qs, qds, qdds = ro.q[::stride], ro.qd[::stride], ro.qdd[::stride]
    T, B, d = qs.shape
    rep = {k: v.repeat(T, *([1] * (v.dim() - 1))) for k, v in aux.items()}  # time-major flat, matches reshape below
    out = expert(qs.reshape(T * B, d), qds.reshape(T * B, d), rep)
    eq = (out if isinstance(out, Tensor) else out.qdd).reshape(T, B, d)
    err = (qdds - eq) ** 2
    loss = float(err.mean())
    if not math.isfinite(loss):
        loss = float("inf")
    return OnlineResult(loss=loss, rollout=ro, expert_qdd=eq)


def rollout_rates(ro, rtol: float = 1e-6, atol: float = 1e-9, with_lyapunov: bool = True) -> dict[str, float]:
    """success / collision rates of a rollout, and the fraction of trajectories whose V_r never rises (if recorded)."""
    out = {"success": float(ro.success.double().mean()), "collision": float(ro.collided.double().mean())}
    if with_lyapunov and ro.V is not None:
        out["lyapunov_monotone_fraction"] = float(lyapunov_monotone(ro.V, rtol=rtol, atol=atol).double().mean())
    return out


def evaluate_learner(learner: nn.Module, expert: Callable, env, test_data, horizon: float, interval: float,
                     rtol: float = 1e-6, atol: float = 1e-9, record_every: float | None = None,
                     progress: Callable | None = None
                     ) -> tuple[dict[str, float], OnlineResult]:
    """All metrics of one learner as a flat dict of floats, plus the online rollout (for figures).

    ``lyapunov_monotone_fraction`` is present only for learners with a Lyapunov function (learner-rmp).
    """
    was_training = learner.training
    learner.eval()
    q0, qd0, aux = test_data.initial_states()
    online = online_loss(learner, expert, env, q0, qd0, aux, horizon, interval, record_every, progress)
    m = {"batch_loss": batch_loss(learner, test_data), "online_loss": online.loss}
    m.update(rollout_rates(online.rollout, rtol, atol, with_lyapunov=bool(getattr(learner, "has_lyapunov", False))))
    learner.train(was_training)
    return m, online
