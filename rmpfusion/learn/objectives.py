"""Training objectives, registered in ``OBJECTIVES`` by the name ``train.objective`` gives them.

An objective compares the learner's q̈ with the expert's (or the recorded) two ways: as the minibatch loss training minimises,
and as a sum that ``dataset_loss`` accumulates chunk by chunk, so a whole dataset's loss (batch-loss on the
test set, the validation curve) is the same quantity training minimises, with memory bounded.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import TYPE_CHECKING, ClassVar, Literal

import torch
import torch.nn.functional as F
from pydantic import Field
from torch import Tensor, nn

from .. import registry
from ..registry import OBJECTIVES

if TYPE_CHECKING:
    from ..envs.demonstrations import Dataset


class Objective(ABC):
    """A loss between predicted and expert accelerations, both (B, d). An objective whose ``sample_weights`` gives
    weights is also called with each sample's weight (B,); one without them is called with the two alone."""

    class Params(registry.Params):  # registry.Params: this class takes its base's name
        pass

    #: the objective a run trained on this one reports its batch-loss and validation loss in (None: this one);
    #: an objective fitted to the training set's statistics reports the paper's MSE, comparable across runs
    reports_as: ClassVar[str | None] = None

    def __init__(self, params: Params | None = None):
        self.params = params if params is not None else self.Params()

    def fit(self, data: Dataset) -> None:
        """Read what the objective needs of the training set (its spread, ...) before training; none by default."""

    def sample_weights(self, data: Dataset) -> Tensor | None:
        """(N,) the weight of each sample of ``data`` (mean 1), or None: every sample counts the same."""
        return None

    @abstractmethod
    def __call__(self, pred: Tensor, target: Tensor, weight: Tensor | None = None) -> Tensor:
        """The minibatch loss (a differentiable scalar): the mean over samples and coordinates."""

    @abstractmethod
    def total(self, pred: Tensor, target: Tensor, weight: Tensor | None = None) -> Tensor:
        """The same loss summed over samples and coordinates (a scalar): ``dataset_loss`` divides the sum over
        all chunks by the number of entries."""


@OBJECTIVES.register("mse")
class MSE(Objective):
    """Mean over samples and coordinates of (q̈_learner − q̈_expert)²: the paper's loss and batch-loss."""

    def __call__(self, pred: Tensor, target: Tensor, weight: Tensor | None = None) -> Tensor:
        if weight is None:
            return F.mse_loss(pred, target)
        return (weight[:, None] * (pred - target) ** 2).mean()

    def total(self, pred: Tensor, target: Tensor, weight: Tensor | None = None) -> Tensor:
        square = (pred - target) ** 2
        return square.sum() if weight is None else (weight[:, None] * square).sum()


@OBJECTIVES.register("normalised_mse")
class NormalisedMSE(MSE):
    """The paper's squared error with each coordinate divided by its spread over the training set and, with
    ``weighting: path_length``, each sample weighted by its speed relative to its demonstration's mean speed.

    Why: recorded demonstrations mix coordinates of different scales (a wrist joint's accelerations are a tenth of
    the shoulder's), and a person starts and stops slowly, so the samples of the start-up and of the slow approach to
    the goal outnumber those of the motion itself; weighting by speed counts every stretch of path the same however
    slowly it was drawn. The weights are floored at ``floor`` (a sample at rest still counts a little) and scaled
    to mean 1 over the dataset. Runs trained on it report the paper's MSE."""

    class Params(registry.Params):
        weighting: Literal["uniform", "path_length"] = Field(
            "path_length", description="uniform: every sample the same; path_length: weighted by relative speed"
        )
        floor: float = Field(0.1, ge=0, le=1, description="the least weight, relative to the mean speed")

    reports_as = "mse"

    def __init__(self, params: NormalisedMSE.Params | None = None):
        self.settings = params if params is not None else NormalisedMSE.Params()
        super().__init__(self.settings)  # type: ignore[arg-type]  # a registry Params model of its own
        self.scale: Tensor | None = None

    def fit(self, data: Dataset) -> None:
        spread = data.qdd.std(0)
        self.scale = torch.where(spread > 1e-12, spread, torch.ones_like(spread))

    def sample_weights(self, data: Dataset) -> Tensor | None:
        if self.settings.weighting == "uniform":
            return None
        speed = data.qd.norm(dim=-1)
        ids, inverse = torch.unique(data.traj_id, return_inverse=True)
        sums = torch.zeros(len(ids), dtype=speed.dtype, device=speed.device).index_add_(0, inverse, speed)
        mean = sums / torch.bincount(inverse, minlength=len(ids)).to(speed)
        w = (speed / mean[inverse].clamp(min=1e-12)).clamp(min=self.settings.floor)
        return w / w.mean()

    def _scaled(self, pred: Tensor, target: Tensor) -> tuple[Tensor, Tensor]:
        if self.scale is None:
            raise RuntimeError("normalised_mse reads the training set's spread: call fit(train) before using it")
        return pred / self.scale, target / self.scale

    def __call__(self, pred: Tensor, target: Tensor, weight: Tensor | None = None) -> Tensor:
        return super().__call__(*self._scaled(pred, target), weight)

    def total(self, pred: Tensor, target: Tensor, weight: Tensor | None = None) -> Tensor:
        return super().total(*self._scaled(pred, target), weight)


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
    weights = objective.sample_weights(data)
    for s in range(0, n, chunk):
        idx = torch.arange(s, min(n, s + chunk), device=data.q.device)
        q, qd, aux, qdd = (_to(t, device) for t in data.select(idx))
        pred = model(q, qd, aux)
        # an objective without sample weights is called with two arguments, as a plugin's may be written
        total += float(objective.total(pred, qdd) if weights is None else objective.total(pred, qdd, weights[idx]))
    return total / (n * data.qdd.shape[1])


def _to(t, device: torch.device):
    return {k: v.to(device) for k, v in t.items()} if isinstance(t, dict) else t.to(device)
