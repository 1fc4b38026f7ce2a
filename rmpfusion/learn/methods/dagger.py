"""DAgger (``train: {method: dagger}``; Ross, Gordon & Bagnell, AISTATS 2011): behavior cloning whose data grows
with the states the learner itself visits, labelled by the expert.

Round 0 trains on ``initial_trajectories`` of the expert's demonstrations (β_0 = 1: the expert's own states).
Round r = 1 … ``rounds`` starts at iteration ⌊r·iterations/(rounds+1)⌋: the policy π_r = β_r·π* + (1 − β_r)·π̂ is
rolled out from ``trajectories_per_round`` training initial states for as long as a demonstration, the expert is
asked for its q̈ at every state recorded ``data.interval`` apart (one label each, as a demonstration's points),
those labels join the data, and minibatch training goes on over all of it. The learner keeps its weights from
round to round (no restart), and the step-size schedule spans all ``iterations``.

The β-mixture: Ross et al. pick the expert's action with probability β at every step. Here the policies act on a
continuous-time system through an integrator evaluating them several times a step, so the mixture acts on the
accelerations, q̈ = β·q̈* + (1 − β)·q̈_learner: the limit of choosing per step as the step shrinks. β = 0 (the
``indicator`` schedule for every round after the first, which Ross et al. found best in practice) rolls out the
learner alone. While β > 0 the expert also acts during the rollouts; those calls are counted apart from the labels
(``expert_calls_in_rollouts``), so a comparison "at equal expert queries" can say which it equalises.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, Literal

import torch
from pydantic import Field, model_validator
from torch import Tensor, nn

from ...envs.demonstrations import Dataset
from ...envs.faults import IsolatingPolicy
from ...envs.protocol import Env
from ...registry import TRAIN_METHODS
from ..config import BCParams
from ..loop import Steps
from ..method import MethodContext, TrainingMethod
from .bc import MinibatchSteps


class DAggerParams(BCParams):
    """DAgger's rounds and β-mixture beside behavior cloning's minibatch settings."""

    method: Literal["dagger"] = Field(  # type: ignore[assignment]  # its own name in place of BCParams' "bc"
        "dagger", description="the TRAIN_METHODS entry these settings are for"
    )
    rounds: int = Field(5, ge=1, description="aggregation rounds after round 0 (the demonstrations)")
    initial_trajectories: int | None = Field(
        None,
        ge=1,
        description="demonstrations round 0 trains on, drawn at random from the training split "
        "(null: all); the rest of the expert's labels come from the rounds",
    )
    trajectories_per_round: int = Field(
        100,
        ge=1,
        description="rollouts per round, each from a training initial "
        "state; every one is labelled at data.points records",
    )
    beta_schedule: Literal["indicator", "exponential", "constant"] = Field(
        "indicator",
        description="β_r of round r ≥ 1: indicator 0 (the learner alone), exponential beta^r, constant beta",
    )
    beta: float = Field(0.5, ge=0, le=1, description="the exponential schedule's base, or the constant β")

    ITERATIONS_SHAPE_THE_PATH = True  # the rounds start at fractions of `iterations`

    @model_validator(mode="after")
    def _beta_used(self):
        if self.beta_schedule == "indicator" and "beta" in self.model_fields_set:
            raise ValueError(
                f"beta is not used by beta_schedule=indicator (β = 0 after round 0); use "
                f"beta_schedule=exponential or constant, or leave beta out; given beta={self.beta}"
            )
        return self

    def beta_at(self, r: int) -> float:
        """β of round ``r`` (round 0 is the expert's demonstrations: 1)."""
        if r == 0:
            return 1.0
        return {"indicator": 0.0, "exponential": self.beta**r, "constant": self.beta}[self.beta_schedule]

    def round_start(self, r: int) -> int:
        """The iteration at which round ``r`` aggregates its data."""
        return (r * self.iterations) // (self.rounds + 1)

    def describe(self) -> str:
        return (
            f"{super().describe()}; {self.rounds} rounds x {self.trajectories_per_round} rollouts, "
            f"β {self.beta_schedule}{'' if self.beta_schedule == 'indicator' else f' {self.beta}'}"
        )


class _Counted:
    """A policy that counts the states it is asked about."""

    def __init__(self, policy):
        self.policy, self.calls = policy, 0

    def __call__(self, q: Tensor, qd: Tensor, aux: Mapping[str, Tensor]) -> Tensor:
        self.calls += q.shape[0]
        out = self.policy(q, qd, aux)
        return out if isinstance(out, Tensor) else out.qdd


def _mixture(learner: nn.Module, expert: _Counted, beta: float):
    """q̈ = β·q̈* + (1 − β)·q̈_learner; the learner alone at β = 0 (the expert is not asked)."""
    if beta == 0.0:
        return lambda q, qd, aux: learner(q, qd, aux)
    return lambda q, qd, aux: beta * expert(q, qd, aux) + (1.0 - beta) * learner(q, qd, aux)


class DAggerSteps(MinibatchSteps):
    """Behavior cloning's minibatch steps on data that grows at the start of every round."""

    params: DAggerParams

    def __init__(self, model: nn.Module, params: DAggerParams, ctx: MethodContext, opt, gen: torch.Generator):
        super().__init__(model, params, ctx, opt, gen)
        ctx.need("dagger", env=ctx.env, expert=ctx.expert, interval=ctx.interval, points=ctx.points)
        first = ctx.train.t == ctx.train.t.min()
        self.starts = (
            ctx.train.q[first],
            ctx.train.qd[first],
            {k: v[first] for k, v in ctx.train.aux.items()},
            ctx.train.env_id[first],
        )
        self.data = _initial(ctx.train, params.initial_trajectories, ctx.seed)
        self.rounds: list[dict[str, Any]] = [
            {
                "round": 0,
                "beta": 1.0,
                "iteration": 0,
                "labels": len(self.data),
                "expert_calls_in_rollouts": 0,
                "training_points": len(self.data),
            }
        ]

    def step(self, it: int) -> float:
        r = len(self.rounds)
        if r <= self.params.rounds and it >= self.params.round_start(r):
            self._aggregate(r, it)
        return super().step(it)

    def _aggregate(self, r: int, it: int) -> None:
        """Round ``r``: roll out the β-mixture, label its records by the expert, add them to the data."""
        p, ctx = self.params, self.ctx
        env, points, interval = ctx.env, ctx.points, ctx.interval
        assert env is not None and points is not None and interval is not None, "need() refused a context without them"
        beta = p.beta_at(r)
        n = self.starts[0].shape[0]
        k = p.trajectories_per_round
        idx = torch.randperm(n, generator=self.gen)[:k] if k <= n else torch.randint(n, (k,), generator=self.gen)
        q0, qd0, env_id = self.starts[0][idx], self.starts[1][idx], self.starts[3][idx]
        aux = {a: v[idx] for a, v in self.starts[2].items()}
        acting = _Counted(ctx.expert)
        with torch.no_grad():
            ro = env.rollout(
                _mixture(self.model, acting, beta),
                q0,
                qd0,
                aux,
                horizon=(points - 1) * interval,
                record_every=interval,
            )
        new = _labelled(ro, aux, env_id, ctx.expert, first_id=int(self.data.traj_id.max()) + 1)
        self.data = Dataset.concat([self.data, new])
        record = {
            "round": r,
            "beta": beta,
            "iteration": it,
            "labels": len(new),
            "expert_calls_in_rollouts": acting.calls,
            "training_points": len(self.data),
            "learner_collision_rate": float(ro.collided.double().mean()),
            "learner_success_rate": float(ro.success.double().mean()),
        }
        self.rounds.append(record)
        ctx.tell(
            f"dagger round {r}/{p.rounds} at iteration {it}: β={beta:.3g}, {k} rollouts "
            f"({100 * record['learner_collision_rate']:.0f} % collided), {len(new)} expert labels, "
            f"{len(self.data)} training points"
        )

    def state(self) -> dict[str, Any]:
        return {"data": self.data.tensors(), "rounds": self.rounds}

    def load_state(self, state: Mapping[str, Any]) -> None:
        if state:
            self.data = Dataset.from_tensors(state["data"])
            self.rounds = [dict(r) for r in state["rounds"]]

    def info(self) -> dict[str, Any]:
        """Expert labels (round 0's demonstrations and every round's), and the expert's calls while acting in
        β-mixtures, counted apart."""
        labels = [r["labels"] for r in self.rounds]
        return {
            "expert_queries": sum(labels),
            "expert_queries_per_round": labels,
            "expert_calls_in_rollouts": sum(r["expert_calls_in_rollouts"] for r in self.rounds),
            "training_points": len(self.data),
            "rounds": self.rounds,
        }


def _initial(train: Dataset, n: int | None, seed: int) -> Dataset:
    """Round 0's data: ``n`` demonstrations drawn at random (from their own generator, so the draw is the same
    whatever the training generator does), or all of them."""
    ids = train.traj_id.unique()
    if n is None:
        return train
    if n > ids.numel():
        raise ValueError(
            f"train.initial_trajectories={n} but the training split has {ids.numel()} demonstrations; "
            "lower it, or collect more (data.train_envs, data.train_trajectories)"
        )
    pick = torch.randperm(ids.numel(), generator=torch.Generator().manual_seed(int(seed) + 7919))[:n]
    return train.trajectories(ids[pick.sort().values])


def _labelled(ro, aux: Mapping[str, Tensor], env_id: Tensor, expert, first_id: int) -> Dataset:
    """The expert's q̈ at every finite record of the rollout (a sample the expert cannot evaluate is left out):
    a dataset laid out like demonstrations, trajectory-major."""
    T, B, _ = ro.q.shape
    flat = lambda x: x.transpose(0, 1).reshape(B * T, *x.shape[2:])
    q, qd = flat(ro.q), flat(ro.qd)
    rep = {k: v.repeat_interleave(T, dim=0) for k, v in aux.items()}
    with torch.no_grad():
        qdd = torch.full_like(q, float("nan"))
        finite = q.isfinite().all(-1) & qd.isfinite().all(-1)
        if bool(finite.any()):
            out = IsolatingPolicy(expert)(q[finite], qd[finite], {k: v[finite] for k, v in rep.items()})
            qdd[finite] = out if isinstance(out, Tensor) else out.qdd
    keep = qdd.isfinite().all(-1)
    traj = first_id + torch.arange(B).repeat_interleave(T)
    return Dataset(
        q=q[keep],
        qd=qd[keep],
        aux={k: v[keep] for k, v in rep.items()},
        qdd=qdd[keep].detach(),
        env_id=env_id.repeat_interleave(T)[keep],
        traj_id=traj[keep],
        t=ro.times.repeat(B)[keep].to(q),
        collided=ro.collided.clone(),
        success=ro.success.clone(),
    )


@TRAIN_METHODS.register("dagger")
class DAgger(TrainingMethod[DAggerParams]):
    """DAgger: behavior cloning on data aggregated from the learner's own rollouts, labelled by the expert."""

    Params = DAggerParams

    @classmethod
    def requirements(cls, params: DAggerParams, env: Env, train_trajectories: int) -> list[tuple[str, str]]:
        if params.initial_trajectories is not None and params.initial_trajectories > train_trajectories:
            return [
                (
                    "train.initial_trajectories",
                    (
                        f"round 0 would draw {params.initial_trajectories} demonstrations but the training split "
                        f"has {train_trajectories} (data.train_envs × data.train_trajectories); lower it or collect "
                        "more (a smoke run on data=tiny: train=dagger_smoke)"
                    ),
                )
            ]
        return []

    def steps(self, model, ctx, opt, gen) -> Steps:
        return DAggerSteps(model, self.params, ctx, opt, gen)
