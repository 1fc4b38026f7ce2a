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

    def describe(self) -> str:
        batch = "full batch" if self.batch_size is None else f"batch={self.batch_size}"
        return f"{super().describe()}; the first-order field fitted to recorded velocities ({self.loss}, {batch})"


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

    def step(self, it: int) -> float:
        p, N = self.params, len(self.rows)
        rows = self.rows
        if p.batch_size is not None and p.batch_size < N:
            rows = rows[torch.randint(N, (p.batch_size,), generator=self.gen).to(rows.device)]
        self.opt.zero_grad(set_to_none=True)
        loss = field_loss(self.model, self.data, rows, self.speed, p.loss, p.speed_floor)
        loss.backward()
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
        return {"expert_queries": 0, "training_points": len(self.rows), "speed_unit": self.speed}


@TRAIN_METHODS.register("field")
class FieldFit(TrainingMethod[FieldParams]):
    """The learner's first-order field fitted to recorded velocities (the first-order learners' training; for a
    tree, its overdamped field)."""

    Params = FieldParams
    from_recordings = True

    def steps(self, model, ctx, opt, gen) -> Steps:
        return FieldSteps(model, self.params, ctx, opt, gen)
