"""Evaluation of a learner against its expert (paper §4.1 "Results"): batch-loss on the expert's test data,
online-loss on the learner's own rollouts (exposes covariate shift), success, collisions and the Lyapunov monitor.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, Protocol, TypeVar

import torch
from torch import Tensor

from ..envs.protocol import HasRatioMetrics, HasTaskMetrics, TimeVaryingAux
from ..envs.rollout import Rollout
from .lyapunov import lyapunov_monotone, max_relative_increase


class RolloutLearner(Protocol):
    """What ``evaluate_learner`` needs of a learner (an ``rmpfusion.learn.Learner``; this layer does not import
    that one): its ``policy`` to roll out, and the module's training mode to switch off meanwhile."""

    training: bool

    def policy(self, q: Tensor, qd: Tensor, aux: Mapping[str, Tensor] | None = None) -> object: ...

    def eval(self) -> object: ...

    def train(self, mode: bool = True) -> object: ...


LearnerT = TypeVar("LearnerT", bound=RolloutLearner)


@dataclass
class OnlineResult:
    """The online loss three ways: the paper's mean over every record, the median over trajectories of each
    trajectory's mean, and the mean over the records before each trajectory's first collision. A learner that
    drives into an obstacle meets the expert's barrier there (enormous accelerations), so the paper's mean mixes
    "collides" with "drifts"; the other two separate them."""

    loss: float
    rollout: Rollout  # of the learner
    expert_qdd: Tensor  # (T, B, d): the expert's action at the learner's states every ``interval``
    median: float = float("nan")
    before_collision: float = float("nan")

    def metrics(self) -> dict[str, float]:
        return {
            "online_loss": self.loss,
            "online_loss_median": self.median,
            "online_loss_before_collision": self.before_collision,
        }


@torch.no_grad()
def online_loss(
    policy: Callable,
    expert: Callable,
    env,
    q0: Tensor,
    qd0: Tensor,
    aux: Mapping[str, Tensor],
    horizon: float,
    interval: float,
    record_every: float | None = None,
    progress: Callable | None = None,
) -> OnlineResult:
    """Roll ``policy`` out from (q0, qd0); every ``interval`` seconds compare its q̈ with the expert's q̈ at that same state.

    ``policy`` is rolled out as given: a tree, or a learner's ``policy``, answers with a TreeOutput, whose V_r the
    rollout records; any other (q, q̇, aux) -> q̈ callable is rolled out without it.

    ``record_every`` (a divisor of ``interval``) records the rollout more finely for figures and the Lyapunov
    monitor at no extra policy evaluations; the loss still uses only the ``interval`` records.
    """
    fine = record_every or interval
    stride = round(interval / fine)
    if stride < 1 or abs(stride * fine - interval) > 1e-9 * max(1.0, interval):
        raise ValueError(f"record_every={record_every} must divide interval={interval}")
    ro = env.rollout(policy, q0, qd0, aux, horizon=horizon, record_every=fine, progress=progress)
    qs, qds, qdds = ro.q[::stride], ro.qd[::stride], ro.qdd[::stride]
    T, B, d = qs.shape
    rep = {k: v.repeat(T, *([1] * (v.dim() - 1))) for k, v in aux.items()}  # time-major flat, matches reshape below
    if ro.moving and isinstance(env, TimeVaryingAux):  # the expert sees the obstacles where the learner met them
        rep = env.aux_at(rep, ro.times[::stride].repeat_interleave(B))
    # the expert is asked only at finite records. A sample that ended early (recorded error) is scored on its records
    # before the failure (rollout_rates counts the failure); any other non-finite record makes the loss inf (diverged)
    finite = (qs.isfinite() & qds.isfinite() & qdds.isfinite()).all(-1)
    valid = torch.ones(T, B, dtype=torch.bool)
    ended = _ended(ro)
    if ended:
        valid[:, ended] = finite[:, ended]
    flat = finite.reshape(T * B)
    eq = torch.full((T * B, d), float("nan"), dtype=qdds.dtype)
    if bool(flat.any()):
        out = expert(qs.reshape(T * B, d)[flat], qds.reshape(T * B, d)[flat], {k: v[flat] for k, v in rep.items()})
        eq[flat] = out if isinstance(out, Tensor) else out.qdd
    eq = eq.reshape(T, B, d)
    err = ((qdds - eq) ** 2).mean(-1)  # (T, B): squared error per record, averaged over coordinates
    before = valid & (ro.times[::stride][:, None] < ro.first_collision_time[None, :])
    per_traj = torch.stack([_finite_mean(err[:, b][valid[:, b]]) for b in range(B)]) if B else err.new_zeros(0)
    return OnlineResult(
        loss=_finite_mean(err[valid]).item(),
        rollout=ro,
        expert_qdd=eq,
        median=float(per_traj.median()) if B else float("inf"),
        before_collision=_finite_mean(err[before]).item(),
    )


def _finite_mean(x: Tensor) -> Tensor:
    """The mean, or inf when it is empty or not finite (a diverged learner)."""
    m = x.mean() if x.numel() else x.new_tensor(float("inf"))
    return m if bool(m.isfinite()) else x.new_tensor(float("inf"))


def _ended(ro: Rollout) -> list[int]:
    """Samples whose rollout ended early with a recorded reason (``ro.error``, e.g. Franka: pybullet or non-finite)."""
    return [b for b, e in enumerate(ro.error) if e is not None]


def rollout_rates(ro: Rollout, rtol: float = 1e-6, atol: float = 1e-9, with_lyapunov: bool = True) -> dict[str, float]:
    """success / collision rates of a rollout, and the fraction of trajectories whose V_r never rises (if recorded).

    Rollouts that record errors also give ``failed``: the fraction of samples that ended early (they never
    count as successes). Their V_r is judged on the records before the failure. Theorem 2 does not cover a
    rollout whose obstacles move (docs/math.md §8): its fraction is reported as
    ``lyapunov_monotone_fraction_moving``, what was observed, never as the check of the theorem.
    """
    out = {"success": float(ro.success.double().mean()), "collision": float(ro.collided.double().mean())}
    ended = _ended(ro)
    if ro.error:
        out["failed"] = len(ended) / len(ro.error)
    if with_lyapunov and ro.V is not None:
        V = ro.V
        if ended:  # hold an ended sample's last finite V: its NaN records say it stopped, not that V rose
            V = V.clone()
            for b in ended:
                fin = V[:, b].isfinite().nonzero().flatten()
                if fin.numel() and int(fin[-1]) + 1 < V.shape[0] and bool(V[: int(fin[-1]) + 1, b].isfinite().all()):
                    V[int(fin[-1]) + 1 :, b] = V[int(fin[-1]), b]
        key = "lyapunov_monotone_fraction_moving" if ro.moving else "lyapunov_monotone_fraction"
        out[key] = float(lyapunov_monotone(V, rtol=rtol, atol=atol).double().mean())
    return out


def evaluate_learner(
    learner: LearnerT,
    expert: Callable,
    env,
    test_data,
    horizon: float,
    interval: float,
    rtol: float = 1e-6,
    atol: float = 1e-9,
    record_every: float | None = None,
    progress: Callable | None = None,
    *,
    loss: Callable[[LearnerT, Any], float],
) -> tuple[dict[str, float], OnlineResult]:
    """All metrics of one learner (a ``rmpfusion.learn.Learner``) as a flat dict of floats, plus the online
    rollout (for figures).

    ``loss(learner, dataset)`` is the batch-loss: the learning layer's dataset loss under the run's training
    objective, handed in so this layer does not depend on that one. The learner's ``policy`` is what is rolled
    out, so ``lyapunov_monotone_fraction`` is present only for learners whose policy is a tree (learner-rmp).
    """
    was_training = learner.training
    learner.eval()
    q0, qd0, aux = test_data.initial_states()
    online = online_loss(learner.policy, expert, env, q0, qd0, aux, horizon, interval, record_every, progress)
    m = {"batch_loss": loss(learner, test_data), **online.metrics()}
    m.update(rollout_rates(online.rollout, rtol, atol))
    learner.train(was_training)
    return m, online


# ---------------------------------------------------------------------------------------------- task metrics
# Environments may define per-trajectory task metrics (``HasTaskMetrics``: ``env.task_metrics(rollout) -> {name:
# (B,)}``) and name those compared with the expert as ratios (``HasRatioMetrics``: ``env.ratio_metrics``), as the
# Franka experiment does (paper Fig. 5b).


def _stats(x: Tensor) -> dict[str, float | int]:
    """mean, std (sample, n−1), min, max over the finite entries, and their count n."""
    x = x.detach().double().flatten()
    x = x[x.isfinite()]
    n = int(x.numel())
    if n == 0:
        return {"mean": float("nan"), "std": float("nan"), "min": float("nan"), "max": float("nan"), "n": 0}
    return {
        "mean": float(x.mean()),
        "std": float(x.std()) if n > 1 else 0.0,
        "min": float(x.min()),
        "max": float(x.max()),
        "n": n,
    }


def summarize(per_trajectory: Mapping[str, Tensor]) -> dict[str, dict[str, float | int]]:
    """``{name: {mean, std, min, max, n}}`` of per-trajectory metrics (non-finite entries left out and not counted)."""
    return {k: _stats(v) for k, v in per_trajectory.items()}


def ratios_to_expert(learner: Mapping[str, Tensor], expert: Mapping[str, Tensor], keys) -> dict[str, dict]:
    """Per trajectory learner/expert for each of ``keys`` (both on the same initial state), then mean ± std over
    trajectories: the paper's Fig. 5b statistic, 1 = the expert. Pairs with a non-finite value or a zero expert
    value are left out; ``n`` says how many remain."""
    out = {}
    for k in keys:
        num, den = learner[k].detach().double(), expert[k].detach().double()
        r = torch.where(den != 0, num / den, torch.full_like(num, float("nan")))
        out[k] = _stats(r)
    return out


@dataclass
class StageResult:
    """One policy evaluated on the test initial states: the expert, or a learner at a training snapshot."""

    label: str
    rollout: Rollout
    per_trajectory: dict[str, Tensor]
    summary: dict[str, dict]
    ratios: dict[str, dict] | None = None
    learner: str | None = None
    iteration: int | None = None
    lyapunov: dict[str, float] | None = None


def task_stage(
    label: str,
    rollout: Rollout,
    env: HasTaskMetrics,
    expert: StageResult | None = None,
    rtol: float = 1e-6,
    atol: float = 1e-9,
    learner: str | None = None,
    iteration: int | None = None,
) -> StageResult:
    """The env's task metrics of ``rollout`` summarised, the ratios to ``expert`` if given, and the Lyapunov
    monitor per trajectory (fraction monotone, worst relative increase) when the rollout recorded V_r, with
    ``theorem2_applies`` false when obstacles moved (then the fraction is what was observed, not a check)."""

    per = {k: v.detach() for k, v in env.task_metrics(rollout).items()}
    ratios = None
    if expert is not None:
        keys = env.ratio_metrics if isinstance(env, HasRatioMetrics) else ()
        ratios = ratios_to_expert(per, expert.per_trajectory, keys)
    lyap = None
    if rollout.V is not None:
        mono = lyapunov_monotone(rollout.V, rtol=rtol, atol=atol)
        per["lyapunov_monotone"] = mono.double()
        lyap = {
            "monotone_fraction": float(mono.double().mean()),
            "max_relative_increase": float(max_relative_increase(rollout.V, atol=atol).max()),
            "theorem2_applies": not rollout.moving,
        }
    return StageResult(
        label=label,
        rollout=rollout,
        per_trajectory=per,
        summary=summarize(per),
        ratios=ratios,
        learner=learner,
        iteration=iteration,
        lyapunov=lyap,
    )
