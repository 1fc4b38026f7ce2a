"""Behavior cloning on a dataset, as a function: ``train(model, data, cfg, seed, ...)``, the method ``bc`` of
``TRAIN_METHODS`` without the rest of a pipeline. The loop it runs (checkpoints, signals, resume) is
``learn/loop.py`` (``TrainResult``, ``learning_rate``: re-exported here); the checkpoint format and its readers are
``learn/checkpoints.py``."""

from __future__ import annotations

import os
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from torch import nn

from ..envs.demonstrations import Dataset
from .config import TrainConfig
from .loop import TrainResult, learning_rate
from .method import MethodContext
from .methods.bc import BehaviorCloning

__all__ = ["TrainConfig", "TrainResult", "learning_rate", "train"]


def train(
    model: nn.Module,
    data: Dataset,
    cfg: TrainConfig,
    seed: int,
    test_data: Dataset | None = None,
    val_data: Dataset | None = None,
    checkpoint_dir: str | os.PathLike | None = None,
    run_config: Mapping[str, Any] | None = None,
    progress: Callable[[int, int], Any] | None = None,
    log: Callable[[dict[str, float]], Any] | None = None,
    keep_checkpoints: int = 2,
) -> TrainResult:
    """Train ``model`` in place by behavior cloning for ``cfg.iterations`` minibatch steps, resuming from
    ``checkpoint_dir`` if it holds one.

    ``log`` receives ``{"iteration", "train_loss"[, "val_loss", "test_loss"]}`` every ``cfg.log_every`` steps
    (the validation loss is the one to choose settings by; the test loss is only reported);
    ``progress(done, total)`` is called after every step.
    """
    splits = {
        "train": data,
        **({"val": val_data} if val_data is not None else {}),
        **({"test": test_data} if test_data is not None else {}),
    }
    ctx = MethodContext(
        data=splits,
        seed=seed,
        checkpoint_dir=Path(checkpoint_dir) if checkpoint_dir else None,
        run_config=run_config,
        progress=progress,
        log=log,
        keep_checkpoints=keep_checkpoints,
    )
    return BehaviorCloning(cfg).train(model, ctx)
