"""A finished recorded-demonstrations run opened again, for the tools that measure it without training: its config
from the final checkpoint (edited where a tool asks), the experiment prepared in a scratch directory (nothing is
written into the run), its learner with the checkpoint's weights, and its splits."""

from __future__ import annotations

import tempfile
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from ..learn.checkpoints import load_checkpoint
from .config import upgrade_run_config
from .experiment import prepare
from .fit import learners
from .progress import Progress
from .recorded import recorded_splits
from .validate import parse_run_config


@dataclass
class FinishedRun:
    exp: Any  # the prepared experiment
    model: Any  # the learner, in float64, with the checkpoint's weights
    demos: dict  # split -> its demonstrations
    every: list  # every demonstration


@contextmanager
def finished_run(
    run_dir: Path,
    learner: str = "rmp",
    edit: Callable[[dict], dict] | None = None,
    new_nodes: tuple[str, ...] = (),
) -> Iterator[FinishedRun]:
    """``run_dir``'s final ``learner``, its config passed through ``edit`` first; parameters of the tree nodes
    ``new_nodes`` (added by the edit) keep their own values, every other one must come from the checkpoint."""
    ckpt = load_checkpoint(run_dir / "checkpoints" / learner / "final.pt")
    config = upgrade_run_config(ckpt["config"])
    run = parse_run_config(edit(config) if edit is not None else config)
    with tempfile.TemporaryDirectory() as scratch:
        exp = prepare(run, Path(scratch), Progress(False))
        model = learners(exp)[learner]
        missing = model.load_state_dict(ckpt["model"], strict=not new_nodes).missing_keys
        foreign = [k for k in missing if not any(n in k for n in new_nodes)]
        if foreign:
            raise ValueError(f"{run_dir}: the checkpoint does not fit the learner, it lacks {foreign[:4]}")
        _, demos, every = recorded_splits(exp)
        yield FinishedRun(exp, model.to(torch.float64), demos, every)
