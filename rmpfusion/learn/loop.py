"""The resumable training loop every training method runs: the method supplies its steps (``Steps``), the loop
owns everything around them (the step-size schedule, held-out curves, snapshots, checkpoints, progress, signals
and resuming), so a new method gets all of it by writing its step.

Everything random comes from one torch.Generator seeded by the run seed, and checkpoints carry it with the model,
the optimiser and the method's own state (DAgger's aggregated data, ...), so a run resumed from a checkpoint ends
at exactly the weights of an uninterrupted one. Checkpoints are written atomically (a kill mid-write leaves only a
temporary that is never read, and is removed by the next run); SIGTERM (SLURM preemption, ``kill``) and SIGINT
(Ctrl-C) finish the current step, write a checkpoint and then stop as the signal would have.
"""

from __future__ import annotations

import copy
import math
from abc import ABC, abstractmethod
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

import torch
from torch import nn

from ..files import remove_stale_temporaries
from .checkpoints import CHECKPOINT_NAME, CheckpointError, latest_checkpoint, load_checkpoint, save_checkpoint
from .config import TrainParams, upgrade_train_config
from .interrupts import StopOnSignal

#: The largest magnitude a trained parameter may reach. No weight network or leaf number of a working tree comes
#: near it (float32 itself overflows at 3.4e38); a parameter beyond it, or a non-finite one, means the optimiser
#: diverged, and every number computed from it afterwards would be noise.
PARAMETER_LIMIT = 1e15


class TrainingDivergedError(FloatingPointError):
    """Training stopped because a parameter became non-finite or passed ``PARAMETER_LIMIT``."""


@dataclass
class TrainResult:
    snapshots: dict[int, dict[str, torch.Tensor]]  # iteration -> state_dict copy (0 = before training)
    curve: list[tuple[int, float]]  # (iteration, the step's training loss or cost)
    test_curve: list[tuple[int, float]] = field(default_factory=list)  # (iteration, test batch-loss)
    val_curve: list[tuple[int, float]] = field(default_factory=list)  # (iteration, validation loss or cost)
    resumed_from: int | None = None
    info: dict[str, Any] = field(default_factory=dict)  # what the method reports (metrics.json "training")
    measure: str = "loss"  # what the curves hold: "loss" against the expert, or the task's "cost"


class Steps(ABC):
    """One training method's iterations, as the loop runs them."""

    #: what the curves hold: "loss" (against the expert's q̈) or "cost" (the task's, no expert)
    measure: str = "loss"

    @abstractmethod
    def step(self, it: int) -> float:
        """Iteration ``it`` (0-based): one optimiser step (``optimizer_step``); returns its loss or cost."""

    def held_out(self) -> dict[str, float]:
        """The current model on held-out data: ``{"val": ..., "test": ...}`` (either may be absent)."""
        return {}

    def state(self) -> dict[str, Any]:
        """What the method must checkpoint beyond the model, the optimiser and the generator."""
        return {}

    def load_state(self, state: Mapping[str, Any]) -> None:
        """Restore what ``state`` returned (resuming)."""

    def info(self) -> dict[str, Any]:
        """What metrics.json reports about the training (expert queries, learned values, ...)."""
        return {}


def learning_rate(cfg: TrainParams, it: int) -> float:
    """The step size of step ``it`` (0-based): a function of the iteration alone, so a resumed run follows the
    same schedule. ``cosine`` anneals from ``lr`` to ``lr · lr_final_fraction`` over ``iterations``."""
    if cfg.lr_schedule == "constant" or cfg.iterations <= 1:
        return cfg.lr
    frac = min(it, cfg.iterations - 1) / (cfg.iterations - 1)
    return cfg.lr * (cfg.lr_final_fraction + (1.0 - cfg.lr_final_fraction) * 0.5 * (1.0 + math.cos(math.pi * frac)))


def optimizer_step(model: nn.Module, opt: torch.optim.Optimizer, cfg: TrainParams) -> None:
    """Apply the gradients accumulated in ``model``: clipped to ``grad_clip`` when set, then one optimiser step."""
    if cfg.grad_clip is not None:
        nn.utils.clip_grad_norm_(model.parameters(), cfg.grad_clip)
    opt.step()


def check_parameters(model: nn.Module, done: int, cfg: TrainParams) -> None:
    """Refuse to go on once a parameter is non-finite or beyond ``PARAMETER_LIMIT`` after ``done`` steps, naming
    the step and the parameter (one synchronisation per step: the names are only looked up on failure)."""
    params = [p for p in model.parameters() if p.numel()]
    if not params:
        return
    largest = torch.stack([p.detach().abs().amax() for p in params]).amax()
    if bool(largest <= PARAMETER_LIMIT):
        return
    name, p = next(
        (n, p)
        for n, p in model.named_parameters()
        if p.numel() and not bool(p.detach().abs().amax() <= PARAMETER_LIMIT)
    )
    bad = p.detach()[~(p.detach().abs() <= PARAMETER_LIMIT)]
    value = float(bad.flatten()[0])
    raise TrainingDivergedError(
        f"training diverged at iteration {done}: parameter {name} holds {value:.3g} ({bad.numel()} of its {p.numel()} "
        f"entries are non-finite or beyond {PARAMETER_LIMIT:.0e}), so nothing it computes means anything; lower "
        f"train.lr (now {cfg.lr:g}) or set train.grad_clip, and run again in a new run directory"
    )


def state_copy(model: nn.Module) -> dict[str, torch.Tensor]:
    return {k: v.detach().clone() for k, v in model.state_dict().items()}


M = TypeVar("M", bound=nn.Module)


def load_snapshot(model: M, state: Mapping[str, torch.Tensor]) -> M:
    """A copy of ``model`` holding a snapshot's weights (the original is left as it is)."""
    m = copy.deepcopy(model)
    m.load_state_dict(dict(state))
    return m


@dataclass
class Loop:
    """One training run: what every iteration reads and writes."""

    model: nn.Module
    cfg: TrainParams
    opt: torch.optim.Optimizer
    gen: torch.Generator
    steps: Steps
    ckdir: Path | None = None
    run_config: Mapping[str, Any] | None = None
    keep_checkpoints: int = 2
    progress: Callable[[int, int], Any] | None = None
    log: Callable[[dict[str, float]], Any] | None = None
    res: TrainResult = field(default_factory=lambda: TrainResult(snapshots={}, curve=[]))
    start: int = 0

    def __post_init__(self) -> None:
        self.res.measure = self.steps.measure
        self.snaps_at = sorted(set(self.cfg.snapshots))


def _resume(s: Loop) -> None:
    """Continue from the latest checkpoint in ``s.ckdir``, if any: the model, optimiser, generator, the method's
    state and every curve so far, so the rest of the run is the one an uninterrupted run would have done."""
    ckdir = s.ckdir
    if ckdir is not None and ckdir.is_dir():
        remove_stale_temporaries(ckdir, recursive=False)
    if ckdir is not None and (ck := latest_checkpoint(ckdir)) is not None:
        state = load_checkpoint(ck, s.model)  # damaged, tampered or foreign files raise, naming the file
        _check_same_path(ck, upgrade_train_config(state["train_config"]), s.cfg)
        s.model.load_state_dict(state["model"])
        s.opt.load_state_dict(state["optimizer"])
        s.gen.set_state(state["rng"])
        s.steps.load_state(state.get("method_state", {}))
        s.start = int(state["iteration"])
        s.res = TrainResult(
            snapshots={int(k): v for k, v in state["snapshots"].items()},
            curve=[tuple(c) for c in state["curve"]],
            test_curve=[tuple(c) for c in state["test_curve"]],
            val_curve=[tuple(c) for c in state.get("val_curve", [])],
            resumed_from=s.start,
            measure=s.steps.measure,
        )
    if s.start > s.cfg.iterations:
        raise RuntimeError(f"checkpoint in {ckdir} is at iteration {s.start}, beyond iterations={s.cfg.iterations}")


def _check_same_path(ck: Path, old: Mapping[str, Any], cfg: TrainParams) -> None:
    """Refuse a checkpoint made with settings that change the optimisation path (``old``: its upgraded
    ``train_config``; a key it lacks has the default it was made with)."""
    fields = type(cfg).model_fields
    bad = [k for k in cfg.path_keys() if _plain(old.get(k, fields[k].default)) != _plain(getattr(cfg, k))]
    if bad:
        raise CheckpointError(
            f"checkpoint {ck} was made with different training settings "
            f"({', '.join(f'{k}: {old.get(k)!r} vs {_plain(getattr(cfg, k))!r}' for k in bad)}); "
            f"delete {ck.parent} to start over"
        )


def _plain(value: Any) -> Any:
    """A setting as the checkpoint stores it (nested settings are models in the config, dicts in the file)."""
    return value.model_dump() if hasattr(value, "model_dump") else value


def _checkpoint(s: Loop, it: int) -> Path | None:
    """Write the checkpoint of iteration ``it`` (nothing without a checkpoint directory) and keep only the
    newest ``keep_checkpoints``."""
    if s.ckdir is None:
        return None
    s.ckdir.mkdir(parents=True, exist_ok=True)
    path = s.ckdir / f"ckpt-{it:08d}.pt"
    res = s.res
    save_checkpoint(
        {
            "model": s.model.state_dict(),
            "optimizer": s.opt.state_dict(),
            "rng": s.gen.get_state(),
            "iteration": it,
            "snapshots": res.snapshots,
            "curve": res.curve,
            "test_curve": res.test_curve,
            "val_curve": res.val_curve,
            "train_config": s.cfg.model_dump(),
            "method_state": s.steps.state(),
            "config": dict(s.run_config or {}),
        },
        path,
    )
    olds = sorted((int(m.group(1)), p) for p in s.ckdir.iterdir() if (m := CHECKPOINT_NAME.match(p.name)))
    for _, p in olds[: -s.keep_checkpoints]:
        p.unlink(missing_ok=True)
    return path


_CURVES = {"val": "val_curve", "test": "test_curve"}


def _held_out(s: Loop, done: int) -> dict[str, float]:
    """The held-out measures after ``done`` steps, appended to their curves."""
    out = {}
    for key, value in s.steps.held_out().items():
        getattr(s.res, _CURVES[key]).append((done, value))
        out[f"{key}_{s.steps.measure}"] = value
    return out


def _record_start(s: Loop) -> None:
    """Iteration 0 of a fresh run: the untrained snapshot and the first points of the held-out curves."""
    if 0 in s.snaps_at:
        s.res.snapshots[0] = state_copy(s.model)
    s.model.eval()
    _held_out(s, 0)


def _after_step(s: Loop, done: int, value: float, stop: StopOnSignal) -> None:
    """Everything due after ``done`` steps: curves and logs, snapshot, checkpoint, progress, and a stop that a
    signal asked for (after a checkpoint, so a rerun resumes here)."""
    cfg = s.cfg
    s.res.curve.append((done, value))
    if done % cfg.log_every == 0 or done == cfg.iterations:
        metrics = {"iteration": float(done), f"train_{s.steps.measure}": value, **_held_out(s, done)}
        if s.log is not None:
            s.log(metrics)
    if done in s.snaps_at:
        s.res.snapshots[done] = state_copy(s.model)
    saved = None
    if done % cfg.checkpoint_every == 0 or done == cfg.iterations:
        saved = _checkpoint(s, done)
    if s.progress is not None:
        s.progress(done, cfg.iterations)
    if stop.signum is not None:
        saved = saved or _checkpoint(s, done)
        stop.stop(
            f"checkpoint at iteration {done}/{cfg.iterations} written to {saved}; run the same command "
            "again (same run directory) to resume"
            if saved
            else f"stopped at iteration {done}/{cfg.iterations} (no checkpoint_dir, nothing saved)"
        )


def run(s: Loop) -> TrainResult:
    """Run ``s.cfg.iterations`` steps of ``s.steps`` on ``s.model`` in place, resuming from ``s.ckdir`` if it
    holds a checkpoint. The step size follows the schedule before every step; ``progress(done, total)`` is
    called after every step, ``log`` every ``log_every`` with the step's measure and the held-out ones."""
    _resume(s)
    if s.start == 0:
        _record_start(s)
    s.model.train()
    with StopOnSignal() as stop:
        for it in range(s.start, s.cfg.iterations):
            if s.cfg.lr_schedule != "constant":
                for group in s.opt.param_groups:
                    group["lr"] = learning_rate(s.cfg, it)
            value = s.steps.step(it)
            check_parameters(s.model, it + 1, s.cfg)
            _after_step(s, it + 1, value, stop)
    s.model.eval()
    s.res.info = s.steps.info()
    return s.res
