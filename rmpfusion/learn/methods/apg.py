"""Analytic policy gradients through the simulator (``train: {method: apg}``): no expert, no demonstrations. The
2-D particle is simulated in torch, so a rollout of the learner's tree is a differentiable function of its weights
(and learnable leaf parameters); the task cost (``learn/task_cost.py``) of a batch of rollouts from training
initial states is back-propagated through the integrator into them.

The training rollouts may run on a coarser integration step than the environment's (``dt``): the gradient of a
20-s rollout costs 5× less at 0.05 s than at 0.01 s, and the evaluation of the optimised tree still runs on the
experiment's own step, where the Lyapunov monitor and the task metrics are accurate. The optimiser may then find
weights whose dynamics are too fast for the coarse step (on 2d2level at 0.05 s it did, from step 15 on: the coarse
rollouts blew up while the same trees were stable at the fine step), so the shipped preset trains on the
environment's own step.

Truncated back-propagation: the horizon is cut into windows of ``truncation`` seconds; each window's cost is
back-propagated within the window (the gradients of all windows add up) and the next window starts from the
detached end state. Memory is bounded by one window and exploding products of long Jacobian chains are cut, at
the price of ignoring how a window's actions change the later windows' cost.
"""

from __future__ import annotations

from typing import Any, Literal, Protocol, runtime_checkable

import torch
from pydantic import Field, model_validator
from torch import Tensor, nn

from ...envs.common import time_grid
from ...envs.protocol import DifferentiableRollouts, DifferentiableTask, Env
from ...registry import TRAIN_METHODS
from ..config import TrainParams
from ..loop import Steps, optimizer_step
from ..method import MethodContext, TrainingMethod
from ..task_cost import TaskCost, interval_costs, record_clearance, total


class APGParams(TrainParams):
    """Rollouts per step, their length and truncation, and the task cost."""

    method: Literal["apg"] = Field("apg", description="the TRAIN_METHODS entry these settings are for")
    batch_size: int = Field(16, ge=1, description="rollouts per step, from training initial states drawn uniformly")
    horizon: float = Field(30.0, gt=0, description="seconds each training rollout lasts")
    truncation: float | None = Field(
        None,
        gt=0,
        description="seconds per back-propagated window (null: the whole "
        "horizon); the horizon must be a multiple of it",
    )
    record_every: float = Field(0.1, gt=0, description="seconds between the records the cost is integrated over")
    dt: float | None = Field(
        None,
        gt=0,
        description="integration step of the training rollouts (null: the "
        "environment's); evaluation keeps the environment's own",
    )
    cost: TaskCost = TaskCost()

    @model_validator(mode="after")
    def _windows(self):
        w = self.truncation or self.horizon
        n = round(self.horizon / w)
        if n < 1 or abs(n * w - self.horizon) > 1e-9 * self.horizon:
            raise ValueError(
                f"horizon must be a multiple of truncation (whole windows); given horizon={self.horizon}, "
                f"truncation={self.truncation}"
            )
        return self

    @property
    def window(self) -> float:
        return self.truncation or self.horizon

    @property
    def windows(self) -> int:
        return round(self.horizon / self.window)

    def describe(self) -> str:
        return (
            f"{super().describe()}; {self.batch_size} rollouts of {self.horizon}s per step, windows of "
            f"{self.window}s{f', integrated at dt={self.dt}' if self.dt else ''}"
        )


@runtime_checkable
class SimulatedEnv(Env, DifferentiableRollouts, DifferentiableTask, Protocol):
    """An environment whose rollouts and task geometry are differentiable, on any integration step: what APG rolls
    out in (``APG.requirements`` refuses the others)."""

    def with_step(self, dt: float) -> SimulatedEnv: ...


class RolloutCost:
    """The task cost of rollouts of a policy from given starts, window by window; with ``backward`` each window's
    cost is back-propagated as soon as it is known."""

    def __init__(self, env: SimulatedEnv, params: APGParams):
        self.env = env.with_step(params.dt) if params.dt is not None else env
        self.params = params

    def __call__(self, policy, q: Tensor, qd: Tensor, aux: dict[str, Tensor], backward: bool) -> dict[str, float]:
        """The mean over the batch of each term of the cost (and ``total``) of one rollout per start."""
        p = self.params
        sums: dict[str, float] = {}
        for w in range(p.windows):
            ro = self.env.rollout(
                policy, q, qd, aux, horizon=p.window, record_every=p.record_every, enable_grad=backward
            )
            d = self.env.goal_distance(ro.q, aux)
            terms = interval_costs(
                p.cost, ro.times, ro.q, d, record_clearance(self.env.clearance(ro.q, aux)), final=w == p.windows - 1
            )
            cost = total(terms).sum(0)  # (B,)
            if backward:
                cost.mean().backward()
            for k, v in {**terms, "total": None}.items():
                value = cost if v is None else v.sum(0)
                sums[k] = sums.get(k, 0.0) + float(value.detach().mean())
            q, qd = ro.q[-1].detach(), ro.qd[-1].detach()
        return sums


class APGSteps(Steps):
    """One step: rollouts from ``batch_size`` training starts, their cost back-propagated, one optimiser step.
    Held out: the cost of the validation split's starts."""

    measure = "cost"

    def __init__(self, model: nn.Module, params: APGParams, ctx: MethodContext, opt, gen: torch.Generator):
        ctx.need("apg", env=ctx.env)
        assert isinstance(ctx.env, SimulatedEnv), "APG.requirements refuses an environment without gradients"
        self.model, self.params, self.ctx, self.opt, self.gen = model, params, ctx, opt, gen
        self.cost = RolloutCost(ctx.env, params)
        self.starts = ctx.train.initial_states()
        self.val_starts = ctx.val.initial_states() if ctx.val is not None else None
        self.last_val: dict[str, float] = {}

    def _policy(self, q: Tensor, qd: Tensor, aux) -> Tensor:
        return self.model(q, qd, aux)

    def step(self, it: int) -> float:
        q0, qd0, aux = self.starts
        idx = torch.randint(q0.shape[0], (self.params.batch_size,), generator=self.gen)
        self.opt.zero_grad(set_to_none=True)
        sums = self.cost(self._policy, q0[idx], qd0[idx], {k: v[idx] for k, v in aux.items()}, backward=True)
        optimizer_step(self.model, self.opt, self.params)
        return sums["total"]

    def held_out(self) -> dict[str, float]:
        if self.val_starts is None:
            return {}
        with torch.no_grad():
            self.last_val = self.cost(self._policy, *self.val_starts, backward=False)
        return {"val": self.last_val["total"]}

    def info(self) -> dict[str, Any]:
        return {"expert_queries": 0, "validation_cost_terms": self.last_val}


def on_grid(
    lengths: dict[str, float],
    every: float,
    dt: float,
    every_key: str = "record_every",
    step: str = "the environment's step",
) -> list[tuple[str, str]]:
    """Each of ``lengths`` (train.<key> = seconds) a whole number of ``every``, itself a whole number of the
    integration step ``dt``: rollouts record on that grid only, and a window must end on a record."""
    issues = []
    try:
        time_grid(every, every, dt)
    except ValueError:
        issues.append((f"train.{every_key}", f"must be a positive multiple of {step} {dt:.6g} s; given {every}"))
    for key, t in lengths.items():
        n = round(t / every)
        if n < 1 or abs(n * every - t) > 1e-9 * max(1.0, t):
            issues.append(
                (
                    f"train.{key}",
                    f"must be a whole number of train.{every_key} = {every} s (rollouts end on a record); given {t}",
                )
            )
    return issues


def not_differentiable(method: str, env: Env, why: str, instead: str) -> tuple[str, str]:
    """The requirement a method that back-propagates through rollouts states of an environment that cannot:
    ``why`` not, and what to do ``instead``."""
    message = (
        f"{method} back-propagates through rollouts, which the environment '{type(env).__name__}' does not offer "
        f"({why}); {instead}"
    )
    return ("train.method", message)


def gradient_refusal(env: Env) -> str | None:
    """Why rollouts of ``env`` cannot keep the autograd graph (None when they can)."""
    if not isinstance(env, DifferentiableRollouts):
        return "its rollouts are not integrated in torch"
    return env.gradient_refusal()


@TRAIN_METHODS.register("apg")
class APG(TrainingMethod[APGParams]):
    """Policy optimisation by back-propagating a task cost through differentiable rollouts."""

    Params = APGParams

    @classmethod
    def requirements(cls, params: APGParams, env: Env, train_trajectories: int) -> list[tuple[str, str]]:
        why = (
            gradient_refusal(env)
            if isinstance(env, DifferentiableTask)
            else "it is not simulated in torch with a differentiable goal distance and clearance"
        )
        if why is not None:
            return [not_differentiable("apg", env, why, "use method pg, or an environment such as particle2d")]
        return on_grid(
            {"horizon": params.horizon, "truncation": params.window},
            params.record_every,
            params.dt or env.dt,
            step="the training step train.dt" if params.dt else "the environment's step",
        )

    def steps(self, model, ctx, opt, gen) -> Steps:
        return APGSteps(model, self.params, ctx, opt, gen)
