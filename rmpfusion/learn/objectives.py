"""Training objectives, registered in ``OBJECTIVES`` by the name ``train.objective`` gives them.

An objective compares the learner's q̈ with the expert's two ways: as the minibatch loss training minimises,
and as a sum that ``dataset_loss`` accumulates chunk by chunk, so a whole dataset's loss (batch-loss on the
test set, the validation curve) is the same quantity training minimises, with memory bounded.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import TYPE_CHECKING

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from .. import registry
from ..registry import OBJECTIVES

if TYPE_CHECKING:
    from ..envs.demonstrations import Dataset


class Objective(ABC):
    """A loss between predicted and expert accelerations, both (B, d)."""

    class Params(registry.Params):  # registry.Params: this class takes its base's name
        pass

    def __init__(self, params: Params | None = None):
        self.params = params if params is not None else self.Params()

    @abstractmethod
    def __call__(self, pred: Tensor, target: Tensor) -> Tensor:
        """The minibatch loss (a differentiable scalar): the mean over samples and coordinates."""

    @abstractmethod
    def total(self, pred: Tensor, target: Tensor) -> Tensor:
        """The same loss summed over samples and coordinates (a scalar): ``dataset_loss`` divides the sum over
        all chunks by the number of entries."""


@OBJECTIVES.register("mse")
class MSE(Objective):
    """Mean over samples and coordinates of (q̈_learner − q̈_expert)²: the paper's loss and batch-loss."""

    def __call__(self, pred: Tensor, target: Tensor) -> Tensor:
        return F.mse_loss(pred, target)

    def total(self, pred: Tensor, target: Tensor) -> Tensor:
        return ((pred - target) ** 2).sum()


def make_objective(name: str) -> Objective:
    """The registered objective ``name`` with its default parameters (``RegistryError`` naming the registered
    ones if there is none)."""
    entry = OBJECTIVES.get(name)
    return entry.obj(entry.validate({}))


def module_device(model: nn.Module) -> torch.device:
    """Where a model's parameters (or buffers) are: the CPU for one that has none."""
    return next((t.device for t in (*model.parameters(), *model.buffers())), torch.device("cpu"))


@torch.no_grad()
def dataset_loss(model: nn.Module, data: Dataset, objective: Objective | str = "mse", chunk: int = 4096) -> float:
    """``objective`` of ``model`` against the expert over a whole dataset, in chunks (sent to the model's device)
    to bound memory."""
    objective = make_objective(objective) if isinstance(objective, str) else objective
    total, n, device = 0.0, len(data), module_device(model)
    for s in range(0, n, chunk):
        idx = torch.arange(s, min(n, s + chunk), device=data.q.device)
        q, qd, aux, qdd = (_to(t, device) for t in data.select(idx))
        total += float(objective.total(model(q, qd, aux), qdd))
    return total / (n * data.qdd.shape[1])


def _to(t, device: torch.device):
    return {k: v.to(device) for k, v in t.items()} if isinstance(t, dict) else t.to(device)
