"""Stage 2, fit: every learner built from its own seed and trained by the run's training method (``train.method``,
a ``TRAIN_METHODS`` entry: behavior cloning on the train split, DAgger, APG, a policy gradient, a plugin's).

Checkpoints go to ``checkpoints/<learner>/`` (resumed on a rerun, also after SIGKILL); the trained learner is
written to ``final.pt`` in the same checksummed format. ``require_trained`` turns the stage into loading only:
what ``rmpfusion-evaluate`` does with the checkpoints ``rmpfusion-train`` left.
"""

from __future__ import annotations

import contextlib
import time
from dataclasses import dataclass

import torch

from ..learn.checkpoints import latest_checkpoint, load_checkpoint, save_checkpoint
from ..learn.learner import Learner
from ..learn.loop import TrainResult
from ..learn.method import MethodContext, TrainingMethod
from ..registry import TRAIN_METHODS
from .collect import Splits
from .config import RecordedDataConfig
from .construct import build_learners
from .experiment import COMPILING, Experiment


class NotTrainedError(RuntimeError):
    """A stage that evaluates found no fully trained checkpoint for some learner."""


@dataclass
class Fitted:
    """One trained learner: the model (in its training dtype), its training record and how long it took."""

    model: Learner
    result: TrainResult
    seconds: float


def learners(exp: Experiment) -> dict[str, Learner]:
    """Every learner of the run, each drawn from its own seed (so stage commands rebuild the same ones)."""

    @contextlib.contextmanager
    def seeded(name: str):
        with torch.random.fork_rng():
            torch.manual_seed(exp.learner_seed(name))
            yield

    built = build_learners(exp.run, exp.env.aux_dims(), seeded)
    for name, model in built.items():
        model.to(exp.device)  # drawn on the CPU (the same initial weights on every device), then moved
        exp.say.say(f"learner {name}: {exp.run.learners[name].type}, {model.num_parameters()} parameters")
    return built


def _require_trained(exp: Experiment) -> None:
    missing = []
    for name in exp.run.learners:
        ck = latest_checkpoint(exp.dir / "checkpoints" / name)
        if ck is None or int(load_checkpoint(ck)["iteration"]) < exp.run.train.iterations:
            missing.append(name)
    if missing:
        raise NotTrainedError(
            f"no fully trained checkpoints for {missing} in {exp.dir / 'checkpoints'}; run "
            f"rmpfusion-train with the same overrides and hydra.run.dir={exp.dir} first"
        )


def method(exp: Experiment) -> TrainingMethod:
    """The run's training method, built from its validated ``train`` block."""
    return TRAIN_METHODS.get(exp.run.train.method).obj(exp.run.train)


def context(exp: Experiment, name: str, splits: Splits) -> MethodContext:
    """What a training method may use for learner ``name``: the splits, the environment, the expert, the
    demonstrations' recording grid, its checkpoint directory, progress and logging."""
    # the expert's demonstrations on their grid, or None for recorded ones: no expert, and lengths of their own
    grid = None if isinstance(exp.run.data, RecordedDataConfig) else exp.run.data
    return MethodContext(
        data=dict(splits.data),
        seed=exp.learner_seed(name) + 1,
        env=exp.env,
        expert=None if grid is None else exp.expert,
        interval=None if grid is None else grid.interval,
        points=None if grid is None else grid.points,
        checkpoint_dir=exp.dir / "checkpoints" / name,
        run_config=exp.config,
        progress=exp.say.bar(f"train {name}"),
        say=exp.say.say,
        log=(lambda m: exp.log_scalars(name, m)) if exp.log is not None else None,
    )


def fit_one(exp: Experiment, name: str, model: Learner, splits: Splits) -> Fitted:
    """Train one learner by the run's method (resuming from its checkpoints) and write ``final.pt``."""
    t0 = time.time()
    if exp.run.train.compile:
        model.compile()
        exp.say.say(COMPILING.format(what=f"learner {name} for training"))
    ckdir = exp.dir / "checkpoints" / name
    if (ck := latest_checkpoint(ckdir)) is not None:
        exp.say.say(f"learner {name}: resuming from {ck}")
    tr = method(exp).train(model, context(exp, name, splits))
    save_checkpoint(
        {
            "model": model.state_dict(),
            "learner": exp.run.learners[name].model_dump(),
            "config": exp.config,
            "iteration": exp.run.train.iterations,
        },
        ckdir / "final.pt",
    )
    return Fitted(model, tr, time.time() - t0)


def fit(exp: Experiment, splits: Splits, require_trained: bool = False) -> dict[str, Fitted]:
    """Every learner trained (config order), or with ``require_trained`` only loaded from finished checkpoints."""
    if require_trained:
        _require_trained(exp)
    built = learners(exp)
    return {name: fit_one(exp, name, built[name], splits) for name in exp.run.learners}
