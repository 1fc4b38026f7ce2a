"""A score-function policy gradient (``train: {method: pg}``; REINFORCE, Williams 1992) for simulators that cannot
be differentiated (pybullet): no expert, no demonstrations, only rollouts and their task cost.

The exploring policy is a Gaussian around the tree's acceleration, held for one control period: every
``decision_interval`` seconds it draws a_d ~ N(μ_θ(s_d), σ²I) at the state s_d, with μ_θ the learner's q̈, and the
environment integrates the constant acceleration a_d until the next decision (a zero-order hold, as a controller
at that rate). A decision's cost is the task cost (``learn/task_cost.py``) of its interval. With the cost-to-go
G_d = Σ_{k ≥ d} c_k and a baseline b_d that does not depend on the episode's own actions,

    ∇_θ E[Σ_d c_d] = E[Σ_d (G_d − b_d) ∇_θ log N(a_d; μ_θ(s_d), σ²I)],

estimated by the mean over ``episodes`` episodes per step; ``leave_one_out`` uses the mean cost-to-go of the other
episodes of the step as b_d. The estimator is unbiased; ``tests/test_methods.py`` holds it to the exact gradient
of a tiny problem computed by quadrature.

The mean policy μ_θ, the tree itself, is what is evaluated and deployed; the Lyapunov monitor of the evaluation
runs on it (the Gaussian exploration is no GDS: Theorem 2 covers the mean, not the draws). Held out: the cost of
the mean policy under the same decisions (σ = 0) from the validation split's starts.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, Literal

import torch
from pydantic import Field, model_validator
from torch import Tensor, nn

from ...envs.protocol import Env
from ...registry import TRAIN_METHODS
from ..config import TrainParams
from ..loop import Steps, optimizer_step
from ..method import MethodContext, TrainingMethod
from ..task_cost import TaskCost, rollout_costs, total
from .apg import on_grid


class PGParams(TrainParams):
    """Episodes per step, the decisions' period and exploration, the task cost."""

    method: Literal["pg"] = Field("pg", description="the TRAIN_METHODS entry these settings are for")
    episodes: int = Field(
        16,
        ge=2,
        description="episodes per step, from training initial states drawn uniformly "
        "(≥ 2: the baseline of one is the others' mean)",
    )
    horizon: float = Field(3.0, gt=0, description="seconds each episode lasts")
    decision_interval: float = Field(0.1, gt=0, description="seconds each drawn acceleration is held")
    sigma: float = Field(
        1.0, gt=0, description="standard deviation of the Gaussian around the tree's q̈ (the unit of q̈)"
    )
    baseline: Literal["leave_one_out", "none"] = Field(
        "leave_one_out", description="b_d: the other episodes' mean cost-to-go, or none (0)"
    )
    cost: TaskCost = TaskCost()

    @model_validator(mode="after")
    def _whole_decisions(self):
        n = round(self.horizon / self.decision_interval)
        if n < 1 or abs(n * self.decision_interval - self.horizon) > 1e-9 * self.horizon:
            raise ValueError(
                f"horizon must be a whole number of decision intervals; given horizon={self.horizon}, "
                f"decision_interval={self.decision_interval}"
            )
        return self

    @property
    def decisions(self) -> int:
        return round(self.horizon / self.decision_interval)

    def describe(self) -> str:
        return (
            f"{super().describe()}; {self.episodes} episodes of {self.horizon}s per step, decisions every "
            f"{self.decision_interval}s, σ={self.sigma}"
        )


@dataclass
class Episode:
    """A batch of B episodes of D decisions: where each decision was taken, what was drawn, what it cost."""

    q: Tensor  # (D, B, d) states at the decisions
    qd: Tensor  # (D, B, d)
    aux: dict[str, Tensor]  # (B, k)
    actions: Tensor  # (D, B, d) the drawn accelerations
    costs: Tensor  # (D, B) the task cost of each decision's interval
    live: Tensor  # (D, B) bool: the episode was still running (no simulator error) when it decided
    terms: dict[str, float]  # the mean over episodes of each term's sum over the horizon


def run_episodes(
    env: Env,
    mean: Callable[..., Tensor],
    q: Tensor,
    qd: Tensor,
    aux: Mapping[str, Tensor],
    params: PGParams,
    sigma: float,
    gen: torch.Generator | None,
) -> Episode:
    """Roll out the Gaussian policy (σ = ``sigma``; 0 for the mean policy) for ``params.decisions`` decisions.

    An episode that the simulator ends early (a recorded error, a non-finite state) stops deciding: its state is
    frozen at its last finite one, its later costs are 0 and its later decisions are left out of the gradient."""
    p, aux = params, dict(aux)
    live = torch.ones(q.shape[0], dtype=torch.bool)
    out: dict[str, list] = {"q": [], "qd": [], "a": [], "c": [], "live": []}
    terms: dict[str, Tensor] = {}
    for d in range(p.decisions):
        with torch.no_grad():
            mu = mean(q, qd, aux)
        a = mu + sigma * torch.randn(mu.shape, generator=gen, dtype=mu.dtype) if sigma > 0 else mu
        ro = env.rollout(_holding(a), q, qd, aux, horizon=p.decision_interval, record_every=p.decision_interval)
        parts = rollout_costs(p.cost, ro, final=d == p.decisions - 1)
        ended = (
            torch.tensor([e is not None for e in ro.error], dtype=torch.bool) if ro.error else torch.zeros_like(live)
        )
        ok = live & ~ended & ro.q[-1].isfinite().all(-1) & ro.qd[-1].isfinite().all(-1)
        cost = torch.where(ok, total(parts)[0], torch.zeros(()))
        for k, v in parts.items():
            terms[k] = terms.get(k, 0.0) + torch.where(ok, v[0], torch.zeros(()))
        for key, value in (("q", q), ("qd", qd), ("a", a), ("c", cost), ("live", live)):
            out[key].append(value)
        q = torch.where(ok[:, None], ro.q[-1], q).detach()
        qd = torch.where(ok[:, None], ro.qd[-1], torch.zeros_like(qd)).detach()
        live = ok
    stack = {k: torch.stack(v) for k, v in out.items()}
    return Episode(
        q=stack["q"],
        qd=stack["qd"],
        aux=aux,
        actions=stack["a"],
        costs=stack["c"],
        live=stack["live"],
        terms={k: float(v.mean()) for k, v in terms.items()},
    )


def _holding(a: Tensor) -> Callable[..., Tensor]:
    """The policy that answers ``a`` whatever the state: one decision, held for its interval."""
    return lambda *_: a


def cost_to_go(costs: Tensor) -> Tensor:
    """G_d = Σ_{k ≥ d} c_k along the decisions (dim 0)."""
    return costs.flip(0).cumsum(0).flip(0)


def surrogate(model: nn.Module, ep: Episode, sigma: float, baseline: str) -> Tensor:
    """A scalar whose gradient is the score-function estimate of ∇_θ E[Σ_d c_d] (the mean over the episodes):
    Σ_d (G_d − b_d)·log N(a_d; μ_θ(s_d), σ²I), with μ_θ evaluated at every decision's state in one batch."""
    D, B, dim = ep.actions.shape
    aux = {k: v.repeat(D, *([1] * (v.dim() - 1))) for k, v in ep.aux.items()}  # decision-major, as the reshape
    mu = model(ep.q.reshape(D * B, dim), ep.qd.reshape(D * B, dim), aux).reshape(D, B, dim)
    log_prob = -0.5 * ((ep.actions - mu) ** 2).sum(-1) / sigma**2  # (D, B), up to a constant
    G = cost_to_go(ep.costs)
    b = (G.sum(1, keepdim=True) - G) / (B - 1) if baseline == "leave_one_out" else torch.zeros_like(G)
    advantage = ((G - b) * ep.live).detach()
    return (advantage * log_prob).sum(0).mean()


class PGSteps(Steps):
    """One step: ``episodes`` episodes of the Gaussian policy from training starts, the score-function estimate
    of the cost's gradient, one optimiser step."""

    measure = "cost"

    def __init__(self, model: nn.Module, params: PGParams, ctx: MethodContext, opt, gen: torch.Generator):
        ctx.need("pg", env=ctx.env)
        assert ctx.env is not None, "need refuses a context without one"
        self.env = ctx.env
        self.model, self.params, self.ctx, self.opt, self.gen = model, params, ctx, opt, gen
        self.starts = ctx.train.initial_states()
        self.val_starts = ctx.val.initial_states() if ctx.val is not None else None
        self.last_val: dict[str, float] = {}

    def _mean(self, q: Tensor, qd: Tensor, aux) -> Tensor:
        return self.model(q, qd, aux)

    def step(self, it: int) -> float:
        q0, qd0, aux = self.starts
        idx = torch.randint(q0.shape[0], (self.params.episodes,), generator=self.gen)
        ep = run_episodes(
            self.env,
            self._mean,
            q0[idx],
            qd0[idx],
            {k: v[idx] for k, v in aux.items()},
            self.params,
            self.params.sigma,
            self.gen,
        )
        self.opt.zero_grad(set_to_none=True)
        surrogate(self.model, ep, self.params.sigma, self.params.baseline).backward()
        optimizer_step(self.model, self.opt, self.params)
        return float(ep.costs.sum(0).mean())

    def held_out(self) -> dict[str, float]:
        if self.val_starts is None:
            return {}
        ep = run_episodes(self.env, self._mean, *self.val_starts, self.params, 0.0, None)
        self.last_val = {**ep.terms, "total": float(ep.costs.sum(0).mean())}
        return {"val": self.last_val["total"]}

    def info(self) -> dict[str, Any]:
        return {"expert_queries": 0, "validation_cost_terms": self.last_val}


@TRAIN_METHODS.register("pg")
class PolicyGradient(TrainingMethod[PGParams]):
    """REINFORCE with a Gaussian around the tree's acceleration, for simulators without gradients."""

    Params = PGParams

    @classmethod
    def requirements(cls, params: PGParams, env: Env, train_trajectories: int) -> list[tuple[str, str]]:
        return on_grid({"horizon": params.horizon}, params.decision_interval, env.dt, "decision_interval")

    def steps(self, model, ctx, opt, gen) -> Steps:
        return PGSteps(model, self.params, ctx, opt, gen)
