"""Trajectory matching (``train: {method: match}``): roll the learner out from each training demonstration's start,
with the demonstration's initial velocity and aux state, and minimise the soft-DTW alignment cost
(``learn/alignment.py``) between the rollout's path and the demonstration's, back-propagated through the
differentiable rollouts APG uses (``DifferentiableRollouts``: the 2-D particle, the plane, and the manipulator in
kinematic mode, whose collisions are checked after the fact and enter no gradient).

Behavior cloning fits accelerations at the demonstrated states only; a rollout leaves those states as soon as it
errs, and the errors add up. Matching whole rollouts trains on the states the policy itself visits. Recorded
demonstrations differ in speed (a human draws the same letter faster or slower), so the rollout is not compared
with the demonstration sample for sample at the same time: soft-DTW aligns the two paths monotonically, and the
loss measures their shapes, with time entering only through the order of the records.

The alignment, stated: both paths are sampled every ``record_every`` seconds (the demonstration by linear
interpolation of its records, the rollout at its records); every rollout lasts ``horizon_factor`` times the longest
demonstration of the split, so a policy that is slower than its demonstration is still compared over the whole
path, and one that arrives early pairs its rest at the goal with the demonstration's end. Each coordinate is divided
by its spread over the training demonstrations (``scaled_square_distances``), and a pair's cost is averaged over
the alignment's length (the sum of the two paths' record counts), so the loss reads as a squared distance per record
in units of that spread.
"""

from __future__ import annotations

import math
from typing import Any, Literal, Protocol, runtime_checkable

import numpy as np
import torch
from pydantic import Field, field_validator
from torch import Tensor, nn

from ...envs.demonstrations import Dataset
from ...envs.protocol import DifferentiableRollouts, Env
from ...registry import TRAIN_METHODS
from ..alignment import scaled_square_distances, soft_dtw
from ..config import BCParams, TrainParams, registered_objective
from ..learner import Learner
from ..loop import Steps, optimizer_step
from ..method import MethodContext, TrainingMethod
from .apg import gradient_refusal, not_differentiable, on_grid
from .bc import MinibatchSteps
from .field import FieldParams, FieldSteps


@runtime_checkable
class RolledOutEnv(Env, DifferentiableRollouts, Protocol):
    """An environment whose rollouts keep the autograd graph, on any integration step: what matching rolls out in
    (``Match.requirements`` refuses the others). Its task geometry need not be differentiable: the loss reads the
    recorded configurations only."""

    def with_step(self, dt: float) -> RolledOutEnv: ...


class MatchParams(TrainParams):
    """Demonstrations per step, the records the paths are compared at, the alignment's smoothing, and how many
    behavior-cloning iterations come first."""

    method: Literal["match"] = Field("match", description="the TRAIN_METHODS entry these settings are for")
    batch_size: int = Field(
        8, ge=1, description="demonstrations rolled out per step, drawn uniformly (capped at the training split's)"
    )
    record_every: float = Field(0.1, gt=0, description="seconds between the records the two paths are compared at")
    horizon_factor: float = Field(
        1.5, ge=1.0, description="every rollout lasts this many times the longest training demonstration"
    )
    dt: float | None = Field(
        None,
        gt=0,
        description="integration step of the training rollouts (null: the environment's); evaluation keeps the "
        "environment's own",
    )
    gamma: float = Field(
        0.01,
        gt=0,
        description="soft-DTW smoothing, in the units of the scaled squared distance (→ 0: hard DTW, not smooth)",
    )
    spread_floor: float = Field(
        0.1,
        ge=0,
        le=1,
        description="each coordinate's distance is scaled by its spread over the training demonstrations, floored "
        "at this fraction of the largest: a coordinate that barely moves (a joint the recordings hold still, whose "
        "spread is its noise) is weighed as one that moves this much, not 1/spread² times the others",
    )

    pretrain_iterations: int = Field(
        0,
        ge=0,
        description="the first this many iterations fit the demonstrations' states (``pretrain``: cheap, and a "
        "start near the demonstrations), the rest trajectory matching",
    )
    pretrain: Literal["bc", "field"] = Field(
        "bc",
        description="what those iterations fit: bc, the recorded accelerations (behavior cloning); field, the "
        "learner's first-order field to the recorded velocities (train.method=field, full batch)",
    )
    pretrain_objective: str = Field("normalised_mse", description="the OBJECTIVES entry of bc's iterations")
    pretrain_batch_size: int = Field(256, ge=1, description="samples per behavior-cloning iteration")

    @field_validator("pretrain_objective")
    @classmethod
    def _objective_registered(cls, name: str) -> str:
        return registered_objective(name)

    def describe(self) -> str:
        return (
            f"{super().describe()}; {self.batch_size} demonstrations per step, soft-DTW (gamma={self.gamma}, "
            f"spreads floored at {self.spread_floor:g} of the largest) "
            f"every {self.record_every}s over {self.horizon_factor}x the longest demonstration"
            f"{f', integrated at dt={self.dt}' if self.dt else ''}"
            f"{f', after {self.pretrain_iterations} iterations of {self.pretrain}' if self.pretrain_iterations else ''}"
        )

    def cloning(self) -> BCParams:
        """The settings of the behavior-cloning iterations: this block's optimiser, schedule and clipping."""
        shared = self.model_dump(include=set(TrainParams.model_fields))
        return BCParams(**shared, objective=self.pretrain_objective, batch_size=self.pretrain_batch_size)

    def field_fit(self) -> FieldParams:
        """The settings of the field-fitting iterations: this block's optimiser, schedule and clipping, every
        training point at each step."""
        return FieldParams(**self.model_dump(include=set(TrainParams.model_fields)))

    def pretraining(self, model: nn.Module, ctx: MethodContext, opt, gen: torch.Generator) -> Steps | None:
        """The steps of the first ``pretrain_iterations`` (None without any)."""
        if not self.pretrain_iterations:
            return None
        if self.pretrain == "field":
            assert isinstance(model, Learner), "the field fit needs a learner's first-order field"
            return FieldSteps(model, self.field_fit(), ctx, opt, gen)
        return MinibatchSteps(model, self.cloning(), ctx, opt, gen)


class DemonstrationPaths:
    """A split's demonstrations as the matching loss reads them: each one's start (q0, q̇0, aux) and its path on
    the record grid, padded to the longest with ``lengths`` saying how many records are its own."""

    def __init__(self, ds: Dataset, record_every: float):
        starts, paths = [], []
        for tid in ds.traj_id.unique():
            rows = torch.nonzero(ds.traj_id == tid).squeeze(1)
            rows = rows[torch.argsort(ds.t[rows])]
            starts.append(int(rows[0]))
            paths.append(on_records(ds.t[rows], ds.q[rows], record_every))
        first = torch.as_tensor(starts)
        self.q0, self.qd0 = ds.q[first], ds.qd[first]
        self.aux = {k: v[first] for k, v in ds.aux.items()}
        self.lengths = torch.as_tensor([len(p) for p in paths])
        longest = int(self.lengths.max())
        pad = lambda p: torch.cat([p, p[-1:].expand(longest - len(p), -1)])
        self.paths = torch.stack([pad(p) for p in paths])  # (n, N, d)
        self.duration = (longest - 1) * record_every

    def __len__(self) -> int:
        return self.q0.shape[0]

    def spread(self, floor: float) -> Tensor:
        """(d,) the standard deviation of each coordinate over every record of every demonstration, at least
        ``floor`` times the largest one (where nothing moves, every coordinate counts as 1)."""
        own = torch.cat([p[:n] for p, n in zip(self.paths, self.lengths)])
        s = own.std(0)
        least = torch.maximum(floor * s.max(), s.new_tensor(1e-12))
        return torch.where(s.max() > 1e-12, torch.maximum(s, least), torch.ones_like(s))


def on_records(t: Tensor, q: Tensor, record_every: float) -> Tensor:
    """(R, d) positions of a demonstration (records q (T, d) at times t (T,)) at 0, record_every, ... ≤ its
    duration, by linear interpolation (demonstrations come on any grid; the rollouts record on this one)."""
    times = (t - t[0]).detach().cpu().numpy()
    end = float(times[-1])
    grid = np.arange(0.0, end + 1e-9 * max(1.0, end), record_every)
    values = q.detach().cpu().numpy()
    out = np.stack([np.interp(grid, times, values[:, k]) for k in range(values.shape[1])], axis=1)
    return torch.as_tensor(out, dtype=q.dtype, device=q.device)


class MatchingCost:
    """The mean over demonstrations of the per-record soft-DTW cost between each one's rollout and its path."""

    def __init__(self, env: RolledOutEnv, params: MatchParams, scale: Tensor, duration: float):
        self.env = env.with_step(params.dt) if params.dt is not None else env
        self.params, self.scale = params, scale
        every = params.record_every
        self.horizon = math.ceil(params.horizon_factor * duration / every - 1e-9) * every

    def __call__(self, policy, demos: DemonstrationPaths, idx: Tensor, backward: bool) -> float:
        p = self.params
        aux = {k: v[idx] for k, v in demos.aux.items()}
        ro = self.env.rollout(
            policy,
            demos.q0[idx],
            demos.qd0[idx],
            aux,
            horizon=self.horizon,
            record_every=p.record_every,
            enable_grad=backward,
        )
        rollout = ro.q.transpose(0, 1)  # (B, M, d)
        paths, lengths = demos.paths[idx], demos.lengths[idx].to(rollout.device)
        cost = scaled_square_distances(paths.to(rollout), rollout, self.scale.to(rollout))
        per_record = soft_dtw(cost, lengths, p.gamma) / (lengths + rollout.shape[1])
        loss = per_record.mean()
        if backward:
            loss.backward()
        return float(loss.detach())


class MatchSteps(Steps):
    """One step: rollouts from ``batch_size`` training demonstrations' starts, their matching cost
    back-propagated, one optimiser step. Held out: the cost of every validation demonstration."""

    measure = "cost"

    def __init__(self, model: nn.Module, params: MatchParams, ctx: MethodContext, opt, gen: torch.Generator):
        ctx.need("match", env=ctx.env)
        assert isinstance(ctx.env, RolledOutEnv), "Match.requirements refuses an environment without gradients"
        self.model, self.params, self.ctx, self.opt, self.gen = model, params, ctx, opt, gen
        self.train = DemonstrationPaths(ctx.train, params.record_every)
        self.val = DemonstrationPaths(ctx.val, params.record_every) if ctx.val is not None else None
        longest = max(self.train.duration, self.val.duration) if self.val is not None else self.train.duration
        self.cost = MatchingCost(ctx.env, params, self.train.spread(params.spread_floor), longest)
        self.cloning = params.pretraining(model, ctx, opt, gen)
        if params.batch_size > len(self.train):
            ctx.tell(
                f"train.batch_size={params.batch_size} is more than the {len(self.train)} training demonstrations: "
                f"every step rolls out {len(self.train)}"
            )

    def step(self, it: int) -> float:
        if self.cloning is not None and it < self.params.pretrain_iterations:
            return self.cloning.step(it)
        n = len(self.train)
        idx = torch.randint(n, (min(self.params.batch_size, n),), generator=self.gen)
        self.opt.zero_grad(set_to_none=True)
        value = self.cost(self.model, self.train, idx, backward=True)
        optimizer_step(self.model, self.opt, self.params)
        return value

    def held_out(self) -> dict[str, float]:
        if self.val is None:
            return {}
        with torch.no_grad():
            return {"val": self.cost(self.model, self.val, torch.arange(len(self.val)), backward=False)}

    def info(self) -> dict[str, Any]:
        return {"expert_queries": 0, "rollout_horizon_s": self.cost.horizon}


@TRAIN_METHODS.register("match")
class Match(TrainingMethod[MatchParams]):
    """Trajectory matching: soft-DTW between rollouts and demonstrations, through differentiable rollouts."""

    Params = MatchParams
    from_recordings = True

    @classmethod
    def requirements(cls, params: MatchParams, env: Env, train_trajectories: int) -> list[tuple[str, str]]:
        why = gradient_refusal(env)
        if why is not None:
            instead = "use method bc, or an environment such as plane, particle2d or the manipulator in kinematic mode"
            return [not_differentiable("match", env, why, instead)]
        return on_grid(
            {},
            params.record_every,
            params.dt or env.dt,
            step="the training step train.dt" if params.dt else "the environment's step",
        )

    def steps(self, model, ctx, opt, gen) -> Steps:
        return MatchSteps(model, self.params, ctx, opt, gen)
