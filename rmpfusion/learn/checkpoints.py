"""The checkpoint format of every training method: one torch file per kept iteration, written atomically with a
format tag and a content checksum, refused loudly (naming the file and the fix) when missing, damaged, tampered
with or made for another model."""

from __future__ import annotations

import hashlib
import os
import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import torch
from torch import nn

from ..files import atomic_torch_save, read_torch_file

CHECKPOINT_NAME = re.compile(r"^ckpt-(\d+)\.pt$")
CHECKPOINT_FORMAT = "rmpfusion-checkpoint/1"


class CheckpointError(RuntimeError):
    """A checkpoint file that cannot be used: missing, damaged, tampered with, or made for another model."""


def latest_checkpoint(directory: str | os.PathLike) -> Path | None:
    d = Path(directory)
    if not d.is_dir():
        return None
    found = [(int(m.group(1)), p) for p in d.iterdir() if (m := CHECKPOINT_NAME.match(p.name))]
    return max(found)[1] if found else None


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
    h = hashlib.sha256()
    _digest({k: v for k, v in payload.items() if k != "sha256"}, h)
    return h.hexdigest()


def save_checkpoint(payload: Mapping[str, Any], path: str | os.PathLike) -> None:
    """Write a checkpoint atomically with its format tag and content checksum."""
    payload = {**payload, "format": CHECKPOINT_FORMAT}
    atomic_torch_save({**payload, "sha256": checkpoint_checksum(payload)}, path)


def _model_mismatch(path: Path, model: nn.Module, state: Mapping[str, Any], fix: str) -> None:
    want = {k: tuple(v.shape) for k, v in model.state_dict().items()}
    have = {k: tuple(v.shape) for k, v in state.get("model", {}).items()}
    if want != have:
        diff = sorted(set(want) ^ set(have)) + sorted(k for k in set(want) & set(have) if want[k] != have[k])
        shown = ", ".join(f"{k}: file {have.get(k)} vs model {want.get(k)}" for k in diff[:5])
        raise CheckpointError(
            f"checkpoint file {path} holds the weights of a different model ({shown}"
            f"{', …' if len(diff) > 5 else ''}); it was made by another configuration of this "
            f"learner: use the run directory that made it, or {fix}"
        )


def load_checkpoint(path: str | os.PathLike, model: nn.Module | None = None) -> dict[str, Any]:
    """Read a checkpoint written by ``save_checkpoint``; refuse (CheckpointError naming the file and the fix) one
    that is missing, unreadable, truncated, fails its checksum, or (given ``model``) holds another model's weights."""
    path = Path(path)
    fix = (
        f"delete {path} (training then resumes from the previous checkpoint in {path.parent} if there is one, "
        "else starts over)"
    )
    state = read_torch_file(
        path,
        "checkpoint",
        fix,
        CheckpointError,
        CHECKPOINT_FORMAT,
        missing="run rmpfusion-train first (it writes checkpoints/<learner>/ in the run directory)",
    )
    stored = state.get("sha256")
    actual = checkpoint_checksum(state)
    if stored != actual:
        raise CheckpointError(
            f"checkpoint file {path} fails its checksum (stored {str(stored)[:12]}…, content "
            f"{actual[:12]}…): it was modified or damaged; {fix}"
        )
    _non_finite_weights(path, state)
    if model is not None:
        _model_mismatch(path, model, state, fix)
    return state


def _non_finite_weights(path: Path, state: Mapping[str, Any]) -> None:
    """Refuse weights with NaN or inf: whatever is built from them (a rollout, an export) only computes noise."""
    bad = [
        (k, int((~v.isfinite()).sum()), v.numel())
        for k, v in (state.get("model") or {}).items()
        if isinstance(v, torch.Tensor) and v.is_floating_point() and not bool(v.isfinite().all())
    ]
    if bad:
        shown = ", ".join(f"{k}: {n} of {total} entries" for k, n, total in bad[:3])
        raise CheckpointError(
            f"checkpoint file {path} holds non-finite weights ({shown}{', …' if len(bad) > 3 else ''}): "
            f"the training that wrote it diverged; use an earlier checkpoint in {path.parent}, or "
            "train again with a lower train.lr"
        )
