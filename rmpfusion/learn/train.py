"""Behavior cloning: minimise the MSE between learner and expert accelerations (paper §3.4, §4.1).

Everything random comes from one torch.Generator seeded by the run seed, and checkpoints carry it with the
model and optimizer, so a run resumed from a checkpoint ends at exactly the weights of an uninterrupted one.
"""
from __future__ import annotations

import copy
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping

import torch
import torch.nn.functional as F
from torch import nn

from ..config.schema import TrainConfig
from ..files import atomic_torch_save
from .demonstrations import Dataset

_DTYPES = {"float32": torch.float32, "float64": torch.float64}
#: TrainConfig fields that change the optimisation path; a checkpoint made with other values is not resumed.
_PATH_KEYS = ("optimizer", "lr", "batch_size", "dtype", "grad_clip")


@dataclass
class TrainResult:
    snapshots: dict[int, dict[str, torch.Tensor]]  # iteration -> state_dict copy (0 = before training)
    curve: list[tuple[int, float]]  # (iteration, minibatch train loss)
    test_curve: list[tuple[int, float]] = field(default_factory=list)  # (iteration, test batch-loss)
    resumed_from: int | None = None


def make_optimizer(params, cfg: TrainConfig) -> torch.optim.Optimizer:
    if cfg.optimizer == "rmsprop":
        return torch.optim.RMSprop(params, lr=cfg.lr)
    if cfg.optimizer == "adam":
        return torch.optim.Adam(params, lr=cfg.lr)
    return torch.optim.SGD(params, lr=cfg.lr)


def mse(model: nn.Module, q, qd, aux, qdd) -> torch.Tensor:
    """Mean over samples and coordinates of (q̈_learner − q̈_expert)²: the paper's loss and batch-loss."""
    return F.mse_loss(model(q, qd, aux), qdd)


@torch.no_grad()
def dataset_loss(model: nn.Module, data: Dataset, chunk: int = 4096) -> float:
    """MSE over a whole dataset, in chunks to bound memory."""
    total, n = 0.0, len(data)
    for s in range(0, n, chunk):
        idx = torch.arange(s, min(n, s + chunk))
        q, qd, aux, qdd = data.select(idx)
        total += float(((model(q, qd, aux) - qdd) ** 2).sum())
    return total / (n * data.qdd.shape[1])


def _state_copy(model: nn.Module) -> dict[str, torch.Tensor]:
    return {k: v.detach().clone() for k, v in model.state_dict().items()}


_CKPT = re.compile(r"^ckpt-(\d+)\.pt$")


def latest_checkpoint(directory: str | os.PathLike) -> Path | None:
    d = Path(directory)
    if not d.is_dir():
        return None
    found = [(int(m.group(1)), p) for p in d.iterdir() if (m := _CKPT.match(p.name))]
    return max(found)[1] if found else None


def train(model: nn.Module, data: Dataset, cfg: TrainConfig, seed: int, test_data: Dataset | None = None,
          checkpoint_dir: str | os.PathLike | None = None, run_config: Mapping[str, Any] | None = None,
          progress: Callable[[int, int], Any] | None = None,
          log: Callable[[dict[str, float]], Any] | None = None, keep_checkpoints: int = 2) -> TrainResult:
    """Train ``model`` in place for ``cfg.iterations`` minibatch steps, resuming from ``checkpoint_dir`` if it holds one.

    ``log`` receives ``{"iteration", "train_loss"[, "test_loss"]}`` every ``cfg.log_every`` steps;
    ``progress(done, total)`` is called after every step.
    """
    dtype = _DTYPES[cfg.dtype]
    model.to(dtype)
    data = data.to(dtype)
    test_data = test_data.to(dtype) if test_data is not None else None
    opt = make_optimizer(model.parameters(), cfg)
    gen = torch.Generator().manual_seed(int(seed))
    snaps_at = sorted(set(cfg.snapshots))
    res = TrainResult(snapshots={}, curve=[])
    start = 0
    ckdir = Path(checkpoint_dir) if checkpoint_dir is not None else None
    if ckdir is not None and (ck := latest_checkpoint(ckdir)) is not None:
        state = torch.load(ck, map_location="cpu", weights_only=True)
        old = state["train_config"]
        bad = [k for k in _PATH_KEYS if old.get(k) != getattr(cfg, k)]
        if bad:
            raise RuntimeError(f"checkpoint {ck} was made with different training settings "
                               f"({', '.join(f'{k}: {old.get(k)!r} vs {getattr(cfg, k)!r}' for k in bad)}); "
                               f"delete {ckdir} to start over")
        model.load_state_dict(state["model"])
        opt.load_state_dict(state["optimizer"])
        gen.set_state(state["rng"])
        start = int(state["iteration"])
        res = TrainResult(snapshots={int(k): v for k, v in state["snapshots"].items()},
                          curve=[tuple(c) for c in state["curve"]], test_curve=[tuple(c) for c in state["test_curve"]],
                          resumed_from=start)
    if start > cfg.iterations:
        raise RuntimeError(f"checkpoint in {ckdir} is at iteration {start}, beyond iterations={cfg.iterations}")

    def checkpoint(it: int) -> None:
        if ckdir is None:
            return
        ckdir.mkdir(parents=True, exist_ok=True)
        atomic_torch_save({"model": model.state_dict(), "optimizer": opt.state_dict(), "rng": gen.get_state(),
                      "iteration": it, "snapshots": res.snapshots, "curve": res.curve, "test_curve": res.test_curve,
                      "train_config": cfg.model_dump(), "config": dict(run_config or {})}, ckdir / f"ckpt-{it:08d}.pt")
        olds = sorted((int(m.group(1)), p) for p in ckdir.iterdir() if (m := _CKPT.match(p.name)))
        for _, p in olds[:-keep_checkpoints]:
            p.unlink(missing_ok=True)

    if start == 0 and 0 in snaps_at:
        res.snapshots[0] = _state_copy(model)
    if start == 0 and test_data is not None:
        model.eval()
        res.test_curve.append((0, dataset_loss(model, test_data)))
    N = len(data)
    model.train()
    for it in range(start, cfg.iterations):
        idx = torch.randint(N, (min(cfg.batch_size, N),), generator=gen)
        q, qd, aux, qdd = data.select(idx)
        opt.zero_grad(set_to_none=True)
        loss = mse(model, q, qd, aux, qdd)
        loss.backward()
        if cfg.grad_clip is not None:
            nn.utils.clip_grad_norm_(model.parameters(), cfg.grad_clip)
        opt.step()
        done = it + 1
        lv = float(loss.detach())
        res.curve.append((done, lv))
        if done % cfg.log_every == 0 or done == cfg.iterations:
            metrics = {"iteration": float(done), "train_loss": lv}
            if test_data is not None:
                tl = dataset_loss(model, test_data)
                res.test_curve.append((done, tl))
                metrics["test_loss"] = tl
            if log is not None:
                log(metrics)
        if done in snaps_at:
            res.snapshots[done] = _state_copy(model)
        if done % cfg.checkpoint_every == 0 or done == cfg.iterations:
            checkpoint(done)
        if progress is not None:
            progress(done, cfg.iterations)
    model.eval()
    return res


def load_snapshot(model: nn.Module, state: Mapping[str, torch.Tensor]) -> nn.Module:
    """A copy of ``model`` holding a snapshot's weights (the original is left as it is)."""
    m = copy.deepcopy(model)
    m.load_state_dict(dict(state))
    return m
