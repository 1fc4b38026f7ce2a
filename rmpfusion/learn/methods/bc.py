"""Behavior cloning (``train: {method: bc}``): minimise the objective (the paper's MSE unless ``objective`` names
another) between the learner's and the expert's accelerations on minibatches of the demonstrations (paper §3.4,
§4.1), with the optimiser ``optimizer`` names."""

from __future__ import annotations

from typing import Any

import torch
from torch import nn

from ...envs.demonstrations import Dataset
from ...registry import TRAIN_METHODS
from ..config import BCParams
from ..loop import Steps, optimizer_step
from ..method import MethodContext, TrainingMethod
from ..objectives import dataset_loss, make_objective


class MinibatchSteps(Steps):
    """Minibatch steps of an objective against the expert's q̈ on a dataset, uniformly with replacement; the
    held-out losses on the validation and test sets."""

    def __init__(
        self, model: nn.Module, params: BCParams, ctx: MethodContext, opt: torch.optim.Optimizer, gen: torch.Generator
    ):
        self.model, self.params, self.ctx, self.opt, self.gen = model, params, ctx, opt, gen
        self.objective = make_objective(params.objective)
        self.data: Dataset = ctx.train
        self.objective.fit(self.data)
        self.weights = self.objective.sample_weights(self.data)
        if params.batch_size > len(self.data):
            ctx.tell(
                f"train.batch_size={params.batch_size} is more than the {len(self.data)} training points: every "
                f"step draws {len(self.data)} (capped at the dataset's size)"
            )

    def step(self, it: int) -> float:
        N = len(self.data)
        # drawn by the CPU generator, so a run draws the same minibatches on every device
        idx = torch.randint(N, (min(self.params.batch_size, N),), generator=self.gen).to(self.data.q.device)
        q, qd, aux, qdd = self.data.select(idx)
        self.opt.zero_grad(set_to_none=True)
        pred = self.model(q, qd, aux)
        loss = self.objective(pred, qdd) if self.weights is None else self.objective(pred, qdd, self.weights[idx])
        loss.backward()
        optimizer_step(self.model, self.opt, self.params)
        return float(loss.detach())

    def held_out(self) -> dict[str, float]:
        out = {}
        for key, ds in (("val", self.ctx.val), ("test", self.ctx.test)):
            if ds is not None:
                out[key] = dataset_loss(self.model, ds, self.objective)
        return out

    def info(self) -> dict[str, Any]:
        """The expert queries behind the training data: one per demonstration point."""
        return {"expert_queries": len(self.data), "training_points": len(self.data)}


@TRAIN_METHODS.register("bc")
class BehaviorCloning(TrainingMethod[BCParams]):
    """Behavior cloning from the expert's demonstrations (the paper's method)."""

    Params = BCParams
    from_recordings = True

    def steps(self, model, ctx, opt, gen) -> Steps:
        return MinibatchSteps(model, self.params, ctx, opt, gen)
