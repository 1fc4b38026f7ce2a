"""Fitting a policy's first-order field to recorded velocities (``train: {method: field}``): minimise the error
between the learner's field v(q) (``Learner.first_order_field``) and the demonstrations' velocities q̇ at their
positions.

This is how the stable first-order learners of the LASA literature are trained (SEDS, CLF-DM, Euclideanizing
Flows), and for a tree it is the overdamped field −B_r⁻¹∇Φ_r (``RMPTree.overdamped_field``): through a learned
diffeomorphism ψ onto a latent attractor with damping η, v = −(gain/η)·J_ψ⁻¹∇φ(ψ(x)), the field Euclideanizing flows
fit. Fitting velocities instead of accelerations avoids the noisiest target a recording has (the second derivative of
a filtered path), and the fitted tree still runs as the second-order GDS it is: its velocity relaxes onto the field at
the rate its damping sets, from rest as a demonstration starts, Theorem 2 holds, and leaves the recordings never
constrained (an obstacle's) act beside it.

Errors are divided by the training velocities' mean speed, so the loss reads as a squared (or smooth-L1) relative
error whatever the units; ``batch_size: null`` takes every training point at each step (full batch, the
literature's usual choice for a few thousand points).

The recordings constrain the field only where they pass. Elsewhere a fitted map may stretch space steeply, and its
field then moves many times faster than any demonstration did (measured on LASA's Khamesh: 56 times, over the box of
starts the convergence check uses), which flings a second-order rollout far out and past what a fixed step can
integrate. ``speed_limit`` bounds it where it matters: at points drawn each step over the training positions' box,
enlarged by ``speed_box``, the part of the field's speed above ``speed_limit`` times the fastest recorded one is
penalised.
"""

from __future__ import annotations

from typing import Any, Literal

import torch
from pydantic import Field
from torch import Tensor
from torch.nn import functional as F

from ...envs.demonstrations import Dataset
from ...registry import TRAIN_METHODS
from ..config import TrainParams
from ..learner import Learner
from ..loop import Steps, optimizer_step
from ..method import MethodContext, TrainingMethod


class FieldParams(TrainParams):
    """The loss between field and recorded velocities, and the points per step."""

    method: Literal["field"] = Field("field", description="the TRAIN_METHODS entry these settings are for")
    loss: Literal["mse", "smooth_l1", "relative"] = Field(
        "mse",
        description="mse: the squared error in units of the mean recorded speed; smooth_l1: Huber's (quadratic below "
        "1, linear above), the loss Euclideanizing flows train with; relative: each point's squared error in units of "
        "its own recorded speed (at least speed_floor of the mean), so the slow approach to the goal weighs as much "
        "as the fast middle",
    )
    speed_floor: float = Field(
        0.1, gt=0, le=1, description="loss=relative: the least speed an error is divided by, as a fraction of the mean"
    )
    batch_size: int | None = Field(
        None, ge=1, description="training points per step, drawn uniformly with replacement; null: all of them"
    )
    settle: float = Field(
        0.0,
        ge=0,
        description="seconds after each demonstration's start whose velocities are not fitted: a demonstration "
        "starts at rest, and there its velocity is still building up towards the motion's, as a tree's relaxes onto "
        "its field within a few 1/η",
    )

    speed_limit: float | None = Field(
        None,
        gt=0,
        description="the field's speed over the enlarged box of training positions is penalised above this many "
        "times the fastest recorded speed (null: unbounded; the recordings constrain the field only where they pass)",
    )
    speed_box: float = Field(
        1.0, ge=0, description="speed_limit: the box's sides are 1 + speed_box times the training positions' spread"
    )
    speed_points: int = Field(1024, ge=1, description="speed_limit: points drawn in the box at each step")
    speed_weight: float = Field(1.0, gt=0, description="speed_limit: the penalty's weight beside the fit's loss")

    def describe(self) -> str:
        batch = "full batch" if self.batch_size is None else f"batch={self.batch_size}"
        bound = "" if self.speed_limit is None else f", speed ≤ {self.speed_limit:g}× the fastest recorded"
        return (
            f"{super().describe()}; the first-order field fitted to recorded velocities ({self.loss}, {batch}{bound})"
        )


def field_loss(
    model: Learner, ds: Dataset, rows: Tensor | None, speed: float, loss: str, speed_floor: float = 0.1
) -> Tensor:
    """The error of ``model``'s field against the recorded velocities of ``ds`` at ``rows`` (all when None), in units
    of ``speed`` (``relative``: of each point's own speed, at least ``speed_floor``·``speed``)."""
    q, qd, aux = (ds.q, ds.qd, ds.aux) if rows is None else ds.select(rows)[:3]
    unit = qd.norm(dim=-1, keepdim=True).clamp(min=speed_floor * speed) if loss == "relative" else speed
    err = (model.first_order_field(q, aux) - qd) / unit
    if loss == "smooth_l1":
        return F.smooth_l1_loss(err, torch.zeros_like(err), reduction="sum") / err.shape[0]
    return (err * err).sum(-1).mean()


class SpeedBound:
    """The penalty on the field's speed above ``limit`` times the fastest recorded one, at points drawn uniformly
    in the training positions' box (its sides 1 + ``box`` times their spread), each with the aux of a training
    row drawn with it (its goal, its obstacles)."""

    def __init__(self, ds: Dataset, rows: Tensor, params: FieldParams, gen: torch.Generator):
        assert params.speed_limit is not None, "a speed bound needs train.speed_limit"
        q = ds.q[rows]
        lo, hi = q.min(0).values, q.max(0).values
        pad = 0.5 * params.speed_box * (hi - lo)
        self.lo, self.size = lo - pad, (hi - lo) + 2 * pad
        self.limit = params.speed_limit * float(ds.qd[rows].norm(dim=-1).max().clamp(min=1e-12))
        self.ds, self.rows, self.params, self.gen = ds, rows, params, gen

    def draw(self) -> tuple[Tensor, dict[str, Tensor]]:
        """Points in the box, and the aux of training rows to go with them."""
        n = self.params.speed_points
        u = torch.rand(n, self.lo.shape[0], generator=self.gen, dtype=self.lo.dtype).to(self.lo.device)
        pick = self.rows[torch.randint(len(self.rows), (n,), generator=self.gen).to(self.rows.device)]
        return self.lo + u * self.size, self.ds.select(pick)[2]

    def penalty(self, model: Learner) -> Tensor:
        q, aux = self.draw()
        speed = model.first_order_field(q, aux).norm(dim=-1)
        defined = speed.isfinite()  # the field is undefined where the damping is singular to working precision
        excess = torch.relu(speed[defined] / self.limit - 1)
        return self.params.speed_weight * (excess * excess).sum() / len(speed)


def fitted_rows(ds: Dataset, settle: float) -> Tensor:
    """The rows of ``ds`` whose velocities are fitted: those at least ``settle`` s after their demonstration's
    start."""
    return torch.nonzero(ds.t >= settle).squeeze(1)


class FieldSteps(Steps):
    """One step: the field's loss on a batch of training points (all of them by default), one optimiser step.
    Held out: the same loss on the validation and test points."""

    def __init__(self, model: Learner, params: FieldParams, ctx: MethodContext, opt, gen: torch.Generator):
        if not model.has_first_order_field:
            raise ValueError(
                f"train.method=field fits a first-order field, and the learner {type(model).__name__} has none "
                "(trees and first-order learners have one); use train.method=bc for it"
            )
        self.model, self.params, self.ctx, self.opt, self.gen = model, params, ctx, opt, gen
        self.data: Dataset = ctx.train
        self.rows = fitted_rows(self.data, params.settle)
        if self.rows.numel() == 0:
            raise ValueError(
                f"train.settle={params.settle} s leaves no training point to fit (every demonstration is shorter); "
                "lower it"
            )
        self.speed = float(self.data.qd[self.rows].norm(dim=-1).mean().clamp(min=1e-12))
        self.bound = None if params.speed_limit is None else SpeedBound(self.data, self.rows, params, gen)

    def step(self, it: int) -> float:
        p, N = self.params, len(self.rows)
        rows = self.rows
        if p.batch_size is not None and p.batch_size < N:
            rows = rows[torch.randint(N, (p.batch_size,), generator=self.gen).to(rows.device)]
        self.opt.zero_grad(set_to_none=True)
        loss = field_loss(self.model, self.data, rows, self.speed, p.loss, p.speed_floor)
        total = loss if self.bound is None else loss + self.bound.penalty(self.model)
        total.backward()
        optimizer_step(self.model, self.opt, p)
        return float(loss.detach())

    def held_out(self) -> dict[str, float]:
        out = {}
        for key, ds in (("val", self.ctx.val), ("test", self.ctx.test)):
            if ds is not None:
                with torch.no_grad():
                    rows = fitted_rows(ds, self.params.settle)
                    out[key] = float(
                        field_loss(self.model, ds, rows, self.speed, self.params.loss, self.params.speed_floor)
                    )
        return out

    def info(self) -> dict[str, Any]:
        bound = {} if self.bound is None else {"speed_bound": self.bound.limit}
        return {"expert_queries": 0, "training_points": len(self.rows), "speed_unit": self.speed, **bound}


@TRAIN_METHODS.register("field")
class FieldFit(TrainingMethod[FieldParams]):
    """The learner's first-order field fitted to recorded velocities (the first-order learners' training; for a
    tree, its overdamped field)."""

    Params = FieldParams
    from_recordings = True

    def steps(self, model, ctx, opt, gen) -> Steps:
        return FieldSteps(model, self.params, ctx, opt, gen)
