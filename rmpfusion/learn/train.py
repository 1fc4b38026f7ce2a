"""Behavior cloning: minimise the objective (the paper's MSE unless ``train.objective`` names another) between
learner and expert accelerations (paper §3.4, §4.1), with the optimiser ``train.optimizer`` names.

Everything random comes from one torch.Generator seeded by the run seed, and checkpoints carry it with the
model and optimizer, so a run resumed from a checkpoint ends at exactly the weights of an uninterrupted one.

Checkpoints are written atomically (a kill mid-write leaves only a temporary that is never read, and is removed
by the next run); SIGTERM (SLURM preemption, ``kill``) and SIGINT (Ctrl-C) during training finish the current
step, write a checkpoint and then stop as the signal would have, so a rerun loses nothing.
"""
from __future__ import annotations

import copy
import math
import os
import re
import signal
import sys
import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping

import torch
from torch import nn

from ..envs.demonstrations import Dataset
from ..envs.common import DTYPES
from ..files import atomic_torch_save, read_torch_file, remove_stale_temporaries
from .config import TrainConfig, upgrade_train_config
from .objectives import Objective, dataset_loss, make_objective, module_device
from .optimizers import make_optimizer

#: TrainConfig fields that change the optimisation path; a checkpoint made with other values is not resumed.
_PATH_KEYS = ("optimizer", "objective", "lr", "lr_schedule", "lr_final_fraction", "batch_size", "dtype", "grad_clip")


@dataclass
class TrainResult:
    snapshots: dict[int, dict[str, torch.Tensor]]  # iteration -> state_dict copy (0 = before training)
    curve: list[tuple[int, float]]  # (iteration, minibatch train loss)
    test_curve: list[tuple[int, float]] = field(default_factory=list)  # (iteration, test batch-loss)
    val_curve: list[tuple[int, float]] = field(default_factory=list)  # (iteration, validation batch-loss)
    resumed_from: int | None = None


def learning_rate(cfg: TrainConfig, it: int) -> float:
    """The step size of step ``it`` (0-based): a function of the iteration alone, so a resumed run follows the
    same schedule. ``cosine`` anneals from ``lr`` to ``lr · lr_final_fraction`` over ``iterations``."""
    if cfg.lr_schedule == "constant" or cfg.iterations <= 1:
        return cfg.lr
    frac = min(it, cfg.iterations - 1) / (cfg.iterations - 1)
    return cfg.lr * (cfg.lr_final_fraction + (1.0 - cfg.lr_final_fraction) * 0.5 * (1.0 + math.cos(math.pi * frac)))


def _state_copy(model: nn.Module) -> dict[str, torch.Tensor]:
    return {k: v.detach().clone() for k, v in model.state_dict().items()}


CHECKPOINT_NAME = re.compile(r"^ckpt-(\d+)\.pt$")


def latest_checkpoint(directory: str | os.PathLike) -> Path | None:
    d = Path(directory)
    if not d.is_dir():
        return None
    found = [(int(m.group(1)), p) for p in d.iterdir() if (m := CHECKPOINT_NAME.match(p.name))]
    return max(found)[1] if found else None


CHECKPOINT_FORMAT = "rmpfusion-checkpoint/1"


class CheckpointError(RuntimeError):
    """A checkpoint file that cannot be used: missing, damaged, tampered with, or made for another model."""


def _digest(obj: Any, h) -> None:
    if isinstance(obj, torch.Tensor):
        t = obj.detach().cpu().contiguous()
        h.update(f"T|{t.dtype}|{tuple(t.shape)}|".encode())
        h.update(t.reshape(-1).view(torch.uint8).numpy().tobytes())
    elif isinstance(obj, Mapping):
        h.update(f"D{len(obj)}|".encode())
        for k in sorted(obj, key=repr):
            _digest(k, h)
            _digest(obj[k], h)
    elif isinstance(obj, (list, tuple)):
        h.update(f"L{len(obj)}|".encode())
        for v in obj:
            _digest(v, h)
    else:
        h.update(f"{type(obj).__name__}:{obj!r}|".encode())


def checkpoint_checksum(payload: Mapping[str, Any]) -> str:
    """sha256 of a checkpoint's content (every tensor's bytes, every number and string; not the ``sha256`` key)."""
    import hashlib

    h = hashlib.sha256()
    _digest({k: v for k, v in payload.items() if k != "sha256"}, h)
    return h.hexdigest()


def save_checkpoint(payload: Mapping[str, Any], path: str | os.PathLike) -> None:
    """Write a checkpoint atomically with its format tag and content checksum."""
    payload = {**payload, "format": CHECKPOINT_FORMAT}
    atomic_torch_save({**payload, "sha256": checkpoint_checksum(payload)}, path)


def load_checkpoint(path: str | os.PathLike, model: nn.Module | None = None) -> dict[str, Any]:
    """Read a checkpoint written by ``save_checkpoint``; refuse (CheckpointError naming the file and the fix) one
    that is missing, unreadable, truncated, fails its checksum, or (given ``model``) holds another model's weights."""
    path = Path(path)
    fix = (f"delete {path} (training then resumes from the previous checkpoint in {path.parent} if there is one, "
           "else starts over)")
    state = read_torch_file(path, "checkpoint", fix, CheckpointError, CHECKPOINT_FORMAT,
                            missing="run rmpfusion-train first (it writes checkpoints/<learner>/ in the run directory)")
    stored = state.get("sha256")
    actual = checkpoint_checksum(state)
    if stored != actual:
        raise CheckpointError(f"checkpoint file {path} fails its checksum (stored {str(stored)[:12]}…, content "
                              f"{actual[:12]}…): it was modified or damaged; {fix}")
    if model is not None:
        want = {k: tuple(v.shape) for k, v in model.state_dict().items()}
        have = {k: tuple(v.shape) for k, v in state.get("model", {}).items()}
        if want != have:
            diff = sorted(set(want) ^ set(have)) + sorted(k for k in set(want) & set(have) if want[k] != have[k])
            shown = ", ".join(f"{k}: file {have.get(k)} vs model {want.get(k)}" for k in diff[:5])
            raise CheckpointError(f"checkpoint file {path} holds the weights of a different model ({shown}"
                                  f"{', …' if len(diff) > 5 else ''}); it was made by another configuration of this "
                                  f"learner: use the run directory that made it, or {fix}")
    return state


class _StopOnSignal:
    """While training, SIGTERM and SIGINT only set a flag; the loop then checkpoints at the end of the current
    step and calls ``stop``, which does what the signal would have done: exit with status 128+signum for a
    default SIGTERM, KeyboardInterrupt for a default SIGINT, or call a handler someone else installed and go on
    training if it returns (submitit's SIGTERM handler does: the job lives on until its requeue). SIGUSR1/2 are
    taken only when a Python handler is installed (submitit's preemption signal requeues the job: the checkpoint
    comes first). A second Ctrl-C stops at once."""

    SIGNALS = (signal.SIGTERM, signal.SIGINT)
    CHAINED = tuple(getattr(signal, n) for n in ("SIGUSR1", "SIGUSR2") if hasattr(signal, n))

    def __init__(self):
        self.signum: int | None = None
        self._old: dict[int, Any] = {}

    def __enter__(self) -> "_StopOnSignal":
        if threading.current_thread() is threading.main_thread():
            for s in self.SIGNALS + self.CHAINED:
                old = signal.getsignal(s)
                if old in (signal.SIG_IGN, None) or (s in self.CHAINED and not callable(old)):
                    continue
                self._old[s] = old
                signal.signal(s, self._handler)
        return self

    def _handler(self, signum, frame) -> None:
        if self.signum == signal.SIGINT and signum == signal.SIGINT:
            raise KeyboardInterrupt
        self.signum = signum

    def __exit__(self, *exc) -> None:
        for s, old in self._old.items():
            signal.signal(s, old)
        self._old = {}

    def stop(self, where: str) -> None:
        signum, self.signum = self.signum, None
        name = signal.Signals(signum).name
        old = self._old.get(signum, signal.SIG_DFL)
        print(f"rmpfusion: {name} received; {where}", file=sys.stderr, flush=True)
        if callable(old) and old is not signal.default_int_handler:
            old(signum, None)  # someone else's handler decides; if it returns, training goes on
            return
        self.__exit__()
        if signum == signal.SIGINT:
            raise KeyboardInterrupt
        raise SystemExit(128 + signum)


@dataclass
class _Session:
    """One call of ``train``: what every step reads and writes."""

    model: nn.Module
    cfg: TrainConfig
    data: Dataset
    test_data: Dataset | None
    val_data: Dataset | None
    opt: torch.optim.Optimizer
    objective: Objective
    gen: torch.Generator
    ckdir: Path | None
    run_config: Mapping[str, Any] | None
    keep_checkpoints: int
    progress: Callable[[int, int], Any] | None
    log: Callable[[dict[str, float]], Any] | None
    snaps_at: list[int] = field(default_factory=list)
    res: TrainResult = field(default_factory=lambda: TrainResult(snapshots={}, curve=[]))
    start: int = 0


def _resume(s: _Session) -> None:
    """Continue from the latest checkpoint in ``s.ckdir``, if any: the model, optimiser, generator and every
    curve so far, so the rest of the run is the one an uninterrupted run would have done."""
    ckdir = s.ckdir
    if ckdir is not None and ckdir.is_dir():
        remove_stale_temporaries(ckdir, recursive=False)
    if ckdir is not None and (ck := latest_checkpoint(ckdir)) is not None:
        state = load_checkpoint(ck, s.model)  # damaged, tampered or foreign files raise, naming the file
        _check_same_path(ck, upgrade_train_config(state["train_config"]), s.cfg)
        s.model.load_state_dict(state["model"])
        s.opt.load_state_dict(state["optimizer"])
        s.gen.set_state(state["rng"])
        s.start = int(state["iteration"])
        s.res = TrainResult(snapshots={int(k): v for k, v in state["snapshots"].items()},
                            curve=[tuple(c) for c in state["curve"]],
                            test_curve=[tuple(c) for c in state["test_curve"]],
                            val_curve=[tuple(c) for c in state.get("val_curve", [])], resumed_from=s.start)
    if s.start > s.cfg.iterations:
        raise RuntimeError(f"checkpoint in {ckdir} is at iteration {s.start}, beyond iterations={s.cfg.iterations}")


def _check_same_path(ck: Path, old: Mapping[str, Any], cfg: TrainConfig) -> None:
    """Refuse a checkpoint made with settings that change the optimisation path (``old``: its upgraded
    ``train_config``; a key it lacks has the default it was made with)."""
    keys = _PATH_KEYS + (("iterations",) if cfg.lr_schedule != "constant" else ())  # the schedule spans them
    bad = [k for k in keys if old.get(k, TrainConfig.model_fields[k].default) != getattr(cfg, k)]
    if bad:
        raise RuntimeError(f"checkpoint {ck} was made with different training settings "
                           f"({', '.join(f'{k}: {old.get(k)!r} vs {getattr(cfg, k)!r}' for k in bad)}); "
                           f"delete {ck.parent} to start over")


def _checkpoint(s: _Session, it: int) -> Path | None:
    """Write the checkpoint of iteration ``it`` (nothing without a checkpoint directory) and keep only the
    newest ``keep_checkpoints``."""
    if s.ckdir is None:
        return None
    s.ckdir.mkdir(parents=True, exist_ok=True)
    path = s.ckdir / f"ckpt-{it:08d}.pt"
    res = s.res
    save_checkpoint({"model": s.model.state_dict(), "optimizer": s.opt.state_dict(), "rng": s.gen.get_state(),
                     "iteration": it, "snapshots": res.snapshots, "curve": res.curve, "test_curve": res.test_curve,
                     "val_curve": res.val_curve, "train_config": s.cfg.model_dump(),
                     "config": dict(s.run_config or {})}, path)
    olds = sorted((int(m.group(1)), p) for p in s.ckdir.iterdir() if (m := CHECKPOINT_NAME.match(p.name)))
    for _, p in olds[:-s.keep_checkpoints]:
        p.unlink(missing_ok=True)
    return path


def _record_start(s: _Session) -> None:
    """Iteration 0 of a fresh run: the untrained snapshot and the first points of the held-out curves."""
    if 0 in s.snaps_at:
        s.res.snapshots[0] = _state_copy(s.model)
    s.model.eval()
    if s.val_data is not None:
        s.res.val_curve.append((0, dataset_loss(s.model, s.val_data, s.objective)))
    if s.test_data is not None:
        s.res.test_curve.append((0, dataset_loss(s.model, s.test_data, s.objective)))


def _step(s: _Session, it: int) -> float:
    """Minibatch step ``it`` (0-based); returns its loss."""
    cfg, opt, N = s.cfg, s.opt, len(s.data)
    idx = torch.randint(N, (min(cfg.batch_size, N),), generator=s.gen).to(s.data.q.device)  # the CPU's draws
    q, qd, aux, qdd = s.data.select(idx)
    if cfg.lr_schedule != "constant":
        for group in opt.param_groups:
            group["lr"] = learning_rate(cfg, it)
    opt.zero_grad(set_to_none=True)
    loss = s.objective(s.model(q, qd, aux), qdd)
    loss.backward()
    if cfg.grad_clip is not None:
        nn.utils.clip_grad_norm_(s.model.parameters(), cfg.grad_clip)
    opt.step()
    return float(loss.detach())


def _log(s: _Session, done: int, lv: float) -> None:
    """The held-out losses after ``done`` steps, appended to their curves and handed to ``s.log``."""
    metrics = {"iteration": float(done), "train_loss": lv}
    if s.val_data is not None:
        vl = dataset_loss(s.model, s.val_data, s.objective)
        s.res.val_curve.append((done, vl))
        metrics["val_loss"] = vl
    if s.test_data is not None:
        tl = dataset_loss(s.model, s.test_data, s.objective)
        s.res.test_curve.append((done, tl))
        metrics["test_loss"] = tl
    if s.log is not None:
        s.log(metrics)


def _after_step(s: _Session, done: int, lv: float, stop: "_StopOnSignal") -> None:
    """Everything due after ``done`` steps: curves and logs, snapshot, checkpoint, progress, and a stop that a
    signal asked for (after a checkpoint, so a rerun resumes here)."""
    cfg = s.cfg
    s.res.curve.append((done, lv))
    if done % cfg.log_every == 0 or done == cfg.iterations:
        _log(s, done, lv)
    if done in s.snaps_at:
        s.res.snapshots[done] = _state_copy(s.model)
    saved = None
    if done % cfg.checkpoint_every == 0 or done == cfg.iterations:
        saved = _checkpoint(s, done)
    if s.progress is not None:
        s.progress(done, cfg.iterations)
    if stop.signum is not None:
        saved = saved or _checkpoint(s, done)
        stop.stop(f"checkpoint at iteration {done}/{cfg.iterations} written to {saved}; run the same command "
                  "again (same run directory) to resume" if saved else
                  f"stopped at iteration {done}/{cfg.iterations} (no checkpoint_dir, nothing saved)")


def train(model: nn.Module, data: Dataset, cfg: TrainConfig, seed: int, test_data: Dataset | None = None,
          val_data: Dataset | None = None, checkpoint_dir: str | os.PathLike | None = None,
          run_config: Mapping[str, Any] | None = None, progress: Callable[[int, int], Any] | None = None,
          log: Callable[[dict[str, float]], Any] | None = None, keep_checkpoints: int = 2) -> TrainResult:
    """Train ``model`` in place for ``cfg.iterations`` minibatch steps, resuming from ``checkpoint_dir`` if it holds one.

    ``log`` receives ``{"iteration", "train_loss"[, "val_loss", "test_loss"]}`` every ``cfg.log_every`` steps
    (the validation loss is the one to choose settings by; the test loss is only reported);
    ``progress(done, total)`` is called after every step. The model trains where it is (``model.to(device)``
    first): the training data goes there once; minibatches are drawn by the CPU generator, so a run draws the same
    minibatches on every device.
    """
    dtype = DTYPES[cfg.dtype]
    model.to(dtype)
    device = module_device(model)
    data = data.to(dtype, device)
    test_data = test_data.to(dtype) if test_data is not None else None
    val_data = val_data.to(dtype) if val_data is not None else None
    s = _Session(model=model, cfg=cfg, data=data, test_data=test_data, val_data=val_data,
                 opt=make_optimizer(model.parameters(), cfg.optimizer, cfg.lr), objective=make_objective(cfg.objective),
                 gen=torch.Generator().manual_seed(int(seed)), snaps_at=sorted(set(cfg.snapshots)),
                 ckdir=Path(checkpoint_dir) if checkpoint_dir is not None else None, run_config=run_config,
                 keep_checkpoints=keep_checkpoints, progress=progress, log=log)
    _resume(s)
    if s.start == 0:
        _record_start(s)
    model.train()
    with _StopOnSignal() as stop:
        for it in range(s.start, cfg.iterations):
            lv = _step(s, it)
            _after_step(s, it + 1, lv, stop)
    model.eval()
    return s.res


def load_snapshot(model: nn.Module, state: Mapping[str, torch.Tensor]) -> nn.Module:
    """A copy of ``model`` holding a snapshot's weights (the original is left as it is)."""
    m = copy.deepcopy(model)
    m.load_state_dict(dict(state))
    return m
