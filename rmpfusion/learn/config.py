"""The training block of a run config: optimiser, schedule, batches, snapshots, checkpoints."""
from __future__ import annotations

from typing import Any, Literal, Mapping

from pydantic import BaseModel, ConfigDict, Field


class _Frozen(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class TrainConfig(_Frozen):
    optimizer: Literal["rmsprop", "adam", "sgd"] = "rmsprop"
    lr: float = Field(1e-3, gt=0)
    lr_schedule: Literal["constant", "cosine"] = Field("constant",
                                                       description="cosine: anneal lr to lr·lr_final_fraction")
    lr_final_fraction: float = Field(0.01, ge=0, le=1, description="the final step size as a fraction of lr (cosine "
                                                                   "schedule): 0.01 ends at lr/100")
    batch_size: int = Field(200, gt=0)
    iterations: int = Field(20000, ge=0)
    snapshots: list[int] = Field(default_factory=lambda: [0, 1000, 5000, 20000],
                                 description="iterations at which the learner is kept and evaluated")
    checkpoint_every: int = Field(1000, gt=0)
    log_every: int = Field(100, gt=0)
    dtype: Literal["float32", "float64"] = "float64"
    grad_clip: float | None = Field(None, gt=0)
    compile: bool = Field(False, description="train learner trees through torch.compile: a one-off compile "
                                             "(seconds), then about twice as fast per step (tools/bench.py)")


#: keys renamed since configs were first stored in checkpoints and run directories: {block: {old: new}}
RENAMED_KEYS: dict[str, dict[str, str]] = {"train": {"lr_final": "lr_final_fraction"}}


def _renamed(block: Mapping[str, Any], names: Mapping[str, str]) -> dict[str, Any]:
    out = dict(block)
    for old, new in names.items():
        if old in out:
            value = out.pop(old)
            out.setdefault(new, value)  # a block that holds both names keeps the new one
    return out


def upgrade_train_config(train: Mapping[str, Any]) -> dict[str, Any]:
    """A stored ``train`` block (a checkpoint's ``train_config``) with renamed keys under their current names
    (``RENAMED_KEYS``), so files written before a rename still resume."""
    return _renamed(train, RENAMED_KEYS["train"])


