"""The training block of a run config: objective and optimiser (by their registered names), schedule, batches,
snapshots, checkpoints."""
from __future__ import annotations

from typing import Any, Literal, Mapping

from pydantic import BaseModel, ConfigDict, Field, field_validator
from pydantic_core import PydanticCustomError

from ..registry import OBJECTIVES, OPTIMIZERS, Registry
from . import objectives, optimizers  # noqa: F401  (the built-in names are registered before any is checked)


class _Frozen(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


def _registered(registry: Registry, name: str) -> str:
    if name not in registry:
        raise PydanticCustomError("registry_name", "{message}", {"message": registry.unknown_message(name)})
    return name


class TrainConfig(_Frozen):
    optimizer: str = Field("rmsprop", description="a name registered in OPTIMIZERS: rmsprop, adam, sgd or a plugin's")
    objective: str = Field("mse", description="a name registered in OBJECTIVES: mse or a plugin's")
    lr: float = Field(1e-3, gt=0)
    lr_schedule: Literal["constant", "cosine"] = Field("constant",
                                                       description="cosine: anneal lr to lr·lr_final_fraction")
    lr_final_fraction: float = Field(0.01, ge=0, le=1, description="the final step size as a fraction of lr (cosine "
                                                                   "schedule): 0.01 ends at lr/100")
    batch_size: int = Field(200, gt=0, description="training points per step, drawn uniformly with replacement; "
                                                 "above the number of training points a step draws that many "
                                                 "instead, still uniformly (so not an error)")
    iterations: int = Field(20000, ge=0)
    snapshots: list[int] = Field(default_factory=lambda: [0, 1000, 5000, 20000],
                                 description="iterations at which the learner is kept and evaluated")
    checkpoint_every: int = Field(1000, gt=0)
    log_every: int = Field(100, gt=0)
    dtype: Literal["float32", "float64"] = "float64"
    grad_clip: float | None = Field(None, gt=0)
    compile: bool = Field(False, description="train learner trees through torch.compile: a one-off compile "
                                             "(seconds), then about twice as fast per step (tools/bench.py)")

    @field_validator("optimizer")
    @classmethod
    def _optimizer_registered(cls, name: str) -> str:
        return _registered(OPTIMIZERS, name)

    @field_validator("objective")
    @classmethod
    def _objective_registered(cls, name: str) -> str:
        return _registered(OBJECTIVES, name)


#: keys renamed since configs were first stored in checkpoints and run directories: {block: {old: new}}
RENAMED_KEYS: dict[str, dict[str, str]] = {"train": {"lr_final": "lr_final_fraction"}}


def _renamed(block: Mapping[str, Any], names: Mapping[str, str]) -> dict[str, Any]:
    out = dict(block)
    for old, new in names.items():
        if old in out:
            value = out.pop(old)
            out.setdefault(new, value)  # a block that holds both names keeps the new one
    return out


#: keys added since configs were first stored, with the value that reproduces a file stored without them
ADDED_KEYS: dict[str, dict[str, Any]] = {"train": {"objective": "mse"}}


def upgrade_train_config(train: Mapping[str, Any]) -> dict[str, Any]:
    """A stored ``train`` block (a checkpoint's ``train_config``, a run config's ``train``) with renamed keys
    under their current names (``RENAMED_KEYS``) and keys added since at the values it was made with
    (``ADDED_KEYS``), so files written before either change still resume."""
    out = _renamed(train, RENAMED_KEYS["train"])
    for key, value in ADDED_KEYS["train"].items():
        out.setdefault(key, value)
    return out


