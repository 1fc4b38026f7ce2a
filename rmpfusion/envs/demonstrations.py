"""Demonstrations (paper §4.1 "Data"): the expert is rolled out in random environments and every
``interval`` seconds the visited state, the aux state and the expert's acceleration there are recorded.

Environments produce demonstrations (each may define its own protocol, ``Env.demonstrations``) and learners
only consume them, so the dataset type lives with the environments, below ``learn/``.

Datasets are expensive relative to tests and shared between runs, so they are saved with the seed and
config hash that made them and a content checksum; a stale, truncated or edited file is refused loudly
instead of silently training on the wrong data.
"""

from __future__ import annotations

import hashlib
import json
import os
import warnings
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch
from torch import Tensor

from ..files import atomic_torch_save, load_error_cause, read_torch_file

FORMAT = "rmpfusion-dataset/1"


class DatasetError(RuntimeError):
    """A dataset file that cannot be used: missing, damaged, or made by a different configuration."""


@dataclass
class Dataset:
    """Flat arrays of N = envs × trajectories × points samples, trajectory-major and time-ordered."""

    q: Tensor  # (N, d)
    qd: Tensor  # (N, d)
    aux: dict[str, Tensor]  # name -> (N, k)
    qdd: Tensor  # (N, d) expert acceleration at (q, qd, aux)
    env_id: Tensor  # (N,) long
    traj_id: Tensor  # (N,) long, unique over the whole dataset
    t: Tensor  # (N,) seconds since the trajectory's start
    collided: Tensor = field(default_factory=lambda: torch.zeros(0, dtype=torch.bool))  # (n_traj,) expert collided
    success: Tensor = field(default_factory=lambda: torch.zeros(0, dtype=torch.bool))  # (n_traj,) expert succeeded

    def __len__(self) -> int:
        return self.q.shape[0]

    def tensors(self) -> dict[str, Tensor]:
        out = {
            "q": self.q,
            "qd": self.qd,
            "qdd": self.qdd,
            "env_id": self.env_id,
            "traj_id": self.traj_id,
            "t": self.t,
            "collided": self.collided,
            "success": self.success,
        }
        out.update({f"aux.{k}": v for k, v in self.aux.items()})
        return out

    @classmethod
    def from_tensors(cls, d: Mapping[str, Tensor]) -> Dataset:
        aux = {k[4:]: v for k, v in d.items() if k.startswith("aux.")}
        return cls(
            q=d["q"],
            qd=d["qd"],
            aux=aux,
            qdd=d["qdd"],
            env_id=d["env_id"],
            traj_id=d["traj_id"],
            t=d["t"],
            collided=d["collided"],
            success=d["success"],
        )

    def initial_states(self) -> tuple[Tensor, Tensor, dict[str, Tensor]]:
        """(q0, qd0, aux) of every trajectory, from its t = 0 record: the test initial states of online-loss."""
        first = self.t == self.t.min()
        return self.q[first], self.qd[first], {k: v[first] for k, v in self.aux.items()}

    def trajectories(self, ids: Tensor) -> Dataset:
        """The records of the trajectories ``ids`` (``traj_id`` values), in their order here; their per-trajectory
        flags (``collided``, ``success``, one per trajectory in increasing ``traj_id``) come along."""
        rows = torch.isin(self.traj_id, ids)
        kept = torch.isin(self.traj_id.unique(), ids)
        flag = lambda f: f[kept] if f.numel() == kept.numel() else f
        return Dataset(
            q=self.q[rows],
            qd=self.qd[rows],
            aux={k: v[rows] for k, v in self.aux.items()},
            qdd=self.qdd[rows],
            env_id=self.env_id[rows],
            traj_id=self.traj_id[rows],
            t=self.t[rows],
            collided=flag(self.collided),
            success=flag(self.success),
        )

    @classmethod
    def concat(cls, parts: list[Dataset]) -> Dataset:
        """One dataset of several (in order), as an aggregating learner (DAgger) grows its data."""
        cat = lambda name: torch.cat([getattr(p, name) for p in parts])
        return cls(
            q=cat("q"),
            qd=cat("qd"),
            aux={k: torch.cat([p.aux[k] for p in parts]) for k in parts[0].aux},
            qdd=cat("qdd"),
            env_id=cat("env_id"),
            traj_id=cat("traj_id"),
            t=cat("t"),
            collided=cat("collided"),
            success=cat("success"),
        )

    def select(self, idx: Tensor) -> tuple[Tensor, Tensor, dict[str, Tensor], Tensor]:
        return self.q[idx], self.qd[idx], {k: v[idx] for k, v in self.aux.items()}, self.qdd[idx]

    def to(self, dtype: torch.dtype | None = None, device: torch.device | str | None = None) -> Dataset:
        """The samples in ``dtype`` (floating tensors) and on ``device`` (all of them); None leaves either as it is."""
        f = lambda x: x.to(device=device, dtype=dtype if x.is_floating_point() else None)
        return Dataset(
            q=f(self.q),
            qd=f(self.qd),
            aux={k: f(v) for k, v in self.aux.items()},
            qdd=f(self.qdd),
            env_id=f(self.env_id),
            traj_id=f(self.traj_id),
            t=f(self.t),
            collided=f(self.collided),
            success=f(self.success),
        )

    def checksum(self) -> str:
        """sha256 of the content (names, dtypes, shapes, bytes): independent of how the file was serialised."""
        h = hashlib.sha256()
        for k, v in sorted(self.tensors().items()):
            v = v.detach().contiguous().cpu()
            h.update(f"{k}|{v.dtype}|{tuple(v.shape)}|".encode())
            h.update(v.numpy().tobytes())
        return h.hexdigest()


def collect(
    env,
    expert,
    n_envs: int,
    n_traj: int,
    n_points: int,
    interval: float,
    generator: torch.Generator | None = None,
    progress: Callable[[int, int], Any] | None = None,
) -> Dataset:
    """Run ``expert`` from ``n_traj`` initial states in each of ``n_envs`` fresh environments and record
    ``n_points`` samples ``interval`` seconds apart (the first at t = 0). The label is the expert's q̈ at the
    recorded state, i.e. the very evaluation that drove the rollout there."""
    envs = env.sample_envs(n_envs, generator)
    q0, qd0, aux = env.sample_initial_states(envs, n_traj, generator)
    ro = env.rollout(expert, q0, qd0, aux, horizon=(n_points - 1) * interval, record_every=interval, progress=progress)
    T, B, _ = ro.q.shape
    if T != n_points:
        raise RuntimeError(f"expert rollout recorded {T} points, expected {n_points}")

    # a trajectory the expert could not finish (a recorded error, or any non-finite record) must not become
    # training data: it is left out, with a warning that says which and why; none left is an error
    errors = list(ro.error or [None] * B)
    finite = (ro.q.isfinite() & ro.qd.isfinite() & ro.qdd.isfinite()).all(-1).all(0)
    failed = {b: errors[b] or "non-finite record" for b in range(B) if errors[b] is not None or not bool(finite[b])}
    if len(failed) == B:
        raise RuntimeError(
            f"the expert failed on every one of the {B} trajectories (first: {failed[0]}); "
            "check the expert and the environment before collecting"
        )
    if failed:
        shown = "; ".join(f"trajectory {b}: {r}" for b, r in list(failed.items())[:3])
        warnings.warn(
            f"expert failed on {len(failed)} of {B} trajectories, left out of the dataset ({shown}"
            f"{'; …' if len(failed) > 3 else ''})",
            RuntimeWarning,
            stacklevel=2,
        )
    keep = torch.tensor([b not in failed for b in range(B)])
    rows = keep.repeat_interleave(T)

    def flat(x: Tensor) -> Tensor:  # (T, B, ...) -> (B·T, ...) trajectory-major, failed trajectories left out
        return x.transpose(0, 1).reshape(B * T, *x.shape[2:])[rows].contiguous()

    traj = torch.arange(B).repeat_interleave(T)[rows]
    return Dataset(
        q=flat(ro.q),
        qd=flat(ro.qd),
        qdd=flat(ro.qdd).detach(),
        aux={k: v.repeat_interleave(T, dim=0)[rows].contiguous() for k, v in aux.items()},
        env_id=traj // n_traj,
        traj_id=traj,
        t=ro.times.repeat(B)[rows].contiguous(),
        collided=ro.collided[keep].clone(),
        success=ro.success[keep].clone(),
    )


def _canonical(meta: Mapping[str, Any]) -> dict:
    return json.loads(json.dumps(dict(meta), sort_keys=True, default=str))


def save_dataset(path: str | os.PathLike, ds: Dataset, meta: Mapping[str, Any]) -> str:
    """Write ``ds`` with ``meta`` (seed, config hash, ...) and its checksum; atomic, so a crash leaves either the
    old file or the new one, never half of one. Returns the checksum."""
    path = Path(path)
    for name, v in ds.tensors().items():  # a NaN label or state would silently poison training: refuse it here
        if v.is_floating_point() and not bool(v.isfinite().all()):
            bad = (~v.isfinite()).reshape(v.shape[0], -1).any(-1).nonzero().flatten()
            trajs = sorted(set(ds.traj_id[bad].tolist())) if ds.traj_id.numel() == v.shape[0] else []
            raise DatasetError(
                f"refusing to write dataset {path}: {name} is non-finite in {bad.numel()} rows "
                f"(first rows {bad[:5].tolist()}{f', trajectories {trajs[:5]}' if trajs else ''}); "
                "the expert failed there: drop those records (or fix the expert) before saving"
            )
    path.parent.mkdir(parents=True, exist_ok=True)
    checksum = ds.checksum()
    payload = {
        "format": FORMAT,
        "sha256": checksum,
        "meta": _canonical(meta),
        "tensors": {k: v.detach().cpu() for k, v in ds.tensors().items()},
    }
    atomic_torch_save(payload, path)
    return checksum


def load_dataset(path: str | os.PathLike, expected_meta: Mapping[str, Any] | None = None) -> Dataset:
    """Load a dataset written by ``save_dataset``, refusing one that is damaged or was made differently."""
    path = Path(path)
    fix = f"delete {path} to have it collected again"
    payload = read_torch_file(
        path,
        "dataset",
        fix,
        DatasetError,
        FORMAT,
        missing="run the experiment (it collects the data) or point data.cache_dir at the directory that holds it",
    )
    try:
        ds = Dataset.from_tensors(payload["tensors"])
    except Exception as e:
        raise DatasetError(f"dataset file {path} is unreadable or truncated ({load_error_cause(e)}); {fix}") from e
    actual = ds.checksum()
    if actual != payload.get("sha256"):
        raise DatasetError(
            f"dataset file {path} fails its checksum (stored {str(payload.get('sha256'))[:12]}…, "
            f"content {actual[:12]}…): it was modified or damaged; {fix}"
        )
    if expected_meta is not None:
        want, have = _canonical(expected_meta), payload.get("meta", {})
        diff = sorted(k for k in set(want) | set(have) if want.get(k) != have.get(k))
        if diff:
            detail = ", ".join(f"{k}: file {have.get(k)!r} vs expected {want.get(k)!r}" for k in diff)
            raise DatasetError(f"dataset file {path} was made with a different configuration ({detail}); {fix}")
    return ds


def dataset_meta(path: str | os.PathLike) -> dict:
    """The stored meta of a dataset file (no checksum verification); DatasetError if it cannot be read."""
    path = Path(path)
    return dict(
        read_torch_file(path, "dataset", f"delete {path} to have it collected again", DatasetError, FORMAT).get(
            "meta", {}
        )
    )
