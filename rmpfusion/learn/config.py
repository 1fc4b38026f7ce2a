"""The training block of a run config: which training method (``method:``, a ``TRAIN_METHODS`` name) and its
settings. Every method's ``Params`` extends ``TrainParams`` (iterations, snapshots, checkpoints, the optimiser and
its schedule); behavior cloning's (``BCParams``, also known as ``TrainConfig``) adds the objective and the batch.

Configs, checkpoints and run directories written before methods existed have no ``method`` key: they are
behavior cloning, and ``upgrade_train_config`` says so (with the other keys renamed or added since).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, ClassVar, Literal

from pydantic import Field, field_validator
from pydantic_core import PydanticCustomError

from ..registry import OBJECTIVES, OPTIMIZERS, Params, Registry
from . import objectives, optimizers  # noqa: F401  (the built-in names are registered before any is checked)

#: The method a training block without ``method`` means: every config written before methods existed.
DEFAULT_METHOD = "bc"


def _registered(registry: Registry, name: str) -> str:
    if name not in registry:
        raise PydanticCustomError("registry_name", "{message}", {"message": registry.unknown_message(name)})
    return name


def registered_objective(name: str) -> str:
    """``name`` if OBJECTIVES has it, else a validation error naming the registered ones."""
    return _registered(OBJECTIVES, name)


class TrainParams(Params):
    """What every training method has: how long it runs, which iterates are kept, how it checkpoints and logs,
    and the optimiser of the learner's parameters with its step-size schedule.

    A method's own model adds its settings and a ``method`` field holding its registered name (``Literal``), so
    that its settings say which method they are for wherever they are stored."""

    optimizer: str = Field("rmsprop", description="a name registered in OPTIMIZERS: rmsprop, adam, sgd or a plugin's")
    lr: float = Field(1e-3, gt=0)
    lr_schedule: Literal["constant", "cosine"] = Field(
        "constant", description="cosine: anneal lr to lr·lr_final_fraction"
    )
    lr_final_fraction: float = Field(
        0.01, ge=0, le=1, description="the final step size as a fraction of lr (cosine schedule): 0.01 ends at lr/100"
    )
    iterations: int = Field(20000, ge=0, description="optimiser steps")
    snapshots: list[int] = Field(
        default_factory=lambda: [0, 1000, 5000, 20000],
        description="iterations at which the learner is kept and evaluated",
    )
    checkpoint_every: int = Field(1000, gt=0)
    log_every: int = Field(100, gt=0, description="iterations between held-out evaluations (curves and logger)")
    dtype: Literal["float32", "float64"] = "float64"
    grad_clip: float | None = Field(None, gt=0)
    compile: bool = Field(
        False,
        description="train learner trees through torch.compile: a one-off compile "
        "(seconds), then about twice as fast per step (tools/bench.py)",
    )

    #: fields that change what a run writes or how fast, never the weights it ends with
    PLUMBING: ClassVar[tuple[str, ...]] = ("snapshots", "checkpoint_every", "log_every", "compile")
    #: whether the training path depends on ``iterations`` itself (rounds placed by it), not only on the schedule
    ITERATIONS_SHAPE_THE_PATH: ClassVar[bool] = False

    @field_validator("optimizer")
    @classmethod
    def _optimizer_registered(cls, name: str) -> str:
        return _registered(OPTIMIZERS, name)

    def path_keys(self) -> tuple[str, ...]:
        """The settings a checkpoint must share with this block to be resumed by it: everything except plumbing,
        and ``iterations`` only when the schedule (or the method's rounds) spans them."""
        spans = self.lr_schedule != "constant" or self.ITERATIONS_SHAPE_THE_PATH
        return tuple(k for k in type(self).model_fields if k not in self.PLUMBING and (k != "iterations" or spans))

    @property
    def batch_loss_objective(self) -> str:
        """The objective (an ``OBJECTIVES`` name) of the reported batch-loss and validation loss against the
        expert: the method's own training objective when it imitates, else the paper's MSE."""
        return "mse"

    def describe(self) -> str:
        """One line for ``rmpfusion-validate``."""
        return f"{self.optimizer} lr={self.lr} iterations={self.iterations} snapshots={self.snapshots}"


class BCParams(TrainParams):
    """Behavior cloning (paper §3.4, §4): the objective between the learner's and the expert's q̈ on minibatches
    of the demonstrations."""

    method: Literal["bc"] = Field("bc", description="the TRAIN_METHODS entry these settings are for")
    objective: str = Field("mse", description="a name registered in OBJECTIVES: mse or a plugin's")
    batch_size: int = Field(
        200,
        gt=0,
        description="training points per step, drawn uniformly with replacement; "
        "above the number of training points a step draws that many "
        "instead, still uniformly (so not an error)",
    )

    @field_validator("objective")
    @classmethod
    def _objective_registered(cls, name: str) -> str:
        return registered_objective(name)

    @property
    def batch_loss_objective(self) -> str:
        return OBJECTIVES.get(self.objective).obj.reports_as or self.objective

    def describe(self) -> str:
        return (
            f"{self.optimizer} lr={self.lr} batch={self.batch_size} iterations={self.iterations} "
            f"snapshots={self.snapshots}"
        )


#: The name the training block had when behavior cloning was the only method.
TrainConfig = BCParams


#: keys renamed since configs were first stored in checkpoints and run directories: {block: {old: new}}
RENAMED_KEYS: dict[str, dict[str, str]] = {"train": {"lr_final": "lr_final_fraction"}}


def _renamed(block: Mapping[str, Any], names: Mapping[str, str]) -> dict[str, Any]:
    out = dict(block)
    for old, new in names.items():
        if old in out:
            value = out.pop(old)
            out.setdefault(new, value)  # a block that holds both names keeps the new one
    return out


#: keys added to a method's block since configs were first stored, by method, with the value that reproduces a file
#: stored without them (a block without ``method`` is behavior cloning's)
ADDED_KEYS: dict[str, dict[str, Any]] = {
    DEFAULT_METHOD: {"method": DEFAULT_METHOD, "objective": "mse"},
    "match": {"spread_floor": 0.0},
}


def upgrade_train_config(train: Mapping[str, Any]) -> dict[str, Any]:
    """A stored ``train`` block (a checkpoint's ``train_config``, a run config's ``train``) as it reads today:
    renamed keys under their current names (``RENAMED_KEYS``), a block without ``method`` (written before
    training methods existed) is behavior cloning, and the keys added to its method since are set to the values it
    was made with (``ADDED_KEYS``)."""
    out = _renamed(train, RENAMED_KEYS["train"])
    for key, value in ADDED_KEYS.get(out.get("method", DEFAULT_METHOD), {}).items():
        out.setdefault(key, value)
    return out
