"""One experiment end to end (paper §4.1) as four stages: collect -> fit -> evaluate -> report.

Each stage is a function of the ``Experiment`` and what the stages before it returned, and writes its
outputs into the run directory (datasets, checkpoints, figures, metrics.json), so the stage commands
(``rmpfusion-collect``, ``-train``, ``-evaluate``) run the same functions one at a time in one directory.

All on CPU, one intra-op thread: the batches are small (2-D states), so extra threads only contend on a
shared machine (a batched 2x2 solve got ~10x slower with 2 busy threads in measurements).
"""

from __future__ import annotations

import os
import time
from contextlib import contextmanager
from pathlib import Path

import torch

from ..files import atomic_write_json
from .collect import Splits, collect
from .config import RunConfig
from .evaluation import ExpertEval, evaluate, evaluate_expert
from .experiment import Experiment, Log, prepare
from .fit import Fitted, fit
from .progress import Progress
from .recorded import RecordedEval, report_recorded
from .report import report


@contextmanager
def _threads(n: int):
    old = torch.get_num_threads()
    torch.set_num_threads(n)
    try:
        yield
    finally:
        torch.set_num_threads(old)


def start(run: RunConfig, run_dir: str | os.PathLike, progress: bool = True, log: Log | None = None) -> Experiment:
    """The experiment's context in ``run_dir`` (created), with its config written to config.json."""
    run_dir = Path(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    atomic_write_json(run_dir / "config.json", run.model_dump())
    return prepare(run, run_dir, Progress(progress), log)


def evaluate_and_report(
    exp: Experiment, splits: Splits, fitted: dict[str, Fitted], started: float, expert: ExpertEval | None = None
) -> dict:
    """Stages 3 and 4 over trained learners: what ``rmpfusion-run`` and ``rmpfusion-evaluate`` end with
    (``expert``: its evaluation when it was done already)."""
    evaluated = evaluate(exp, splits, fitted, expert)
    if isinstance(evaluated, RecordedEval):  # recorded demonstrations: measured against the held-out ones
        return report_recorded(exp, splits, fitted, evaluated, started)
    return report(exp, splits, fitted, *evaluated, started)


def run_experiment(
    run: RunConfig,
    run_dir: str | os.PathLike,
    progress: bool = True,
    log: Log | None = None,
    threads: int = 1,
    require_trained: bool = False,
) -> dict:
    """Run ``run`` in ``run_dir`` and return (and write) its metrics; rerunning reuses data and checkpoints.
    ``require_trained``: evaluate the checkpoints already there instead of training (``rmpfusion-evaluate``)."""
    started = time.time()
    with _threads(threads):
        exp = start(run, run_dir, progress, log)
        splits = collect(exp)  # the expert's rollouts, or the recorded demonstrations split by demonstration
        # before training: an expert that diverges stops the run here (recorded demonstrations have no expert)
        expert = evaluate_expert(exp, splits.test) if splits.demos is None else None
        fitted = fit(exp, splits, require_trained=require_trained)
        return evaluate_and_report(exp, splits, fitted, started, expert)
