"""Recorded demonstrations as the ``Dataset`` every learner trains on: the states on the step grid, the
accelerations the smoothing differentiator gave as labels, the goal as aux state, one trajectory per
demonstration."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch

from ..envs.demonstrations import Dataset
from .signals import States


def recorded_dataset(states: Sequence[States], every: int = 1, dtype: torch.dtype = torch.float64) -> Dataset:
    """One dataset of ``states`` (each a demonstration), keeping every ``every``-th grid sample; the goal of each
    demonstration is the aux entry ``goal``, and its extra aux entries come along."""
    parts: dict[str, list[np.ndarray]] = {k: [] for k in ("q", "qd", "qdd", "t", "traj")}
    aux: dict[str, list[np.ndarray]] = {"goal": []}
    for n, st in enumerate(states):
        rows = slice(None, None, every)
        T = len(st.t[rows])
        for key, value in (("q", st.q), ("qd", st.qd), ("qdd", st.qdd), ("t", st.t)):
            parts[key].append(value[rows])
        parts["traj"].append(np.full(T, n))
        aux["goal"].append(np.repeat(st.goal[None], T, axis=0))
        for name, value in st.aux.items():
            aux.setdefault(name, []).append(np.repeat(np.asarray(value, np.float64)[None], T, axis=0))
    t = lambda key: torch.as_tensor(np.concatenate(parts[key]), dtype=dtype)
    traj = torch.as_tensor(np.concatenate(parts["traj"]), dtype=torch.long)
    n = len(states)
    return Dataset(
        q=t("q"),
        qd=t("qd"),
        qdd=t("qdd"),
        t=t("t"),
        traj_id=traj,
        env_id=traj.clone(),
        aux={k: torch.as_tensor(np.concatenate(v), dtype=dtype) for k, v in aux.items()},
        collided=torch.zeros(n, dtype=torch.bool),
        success=torch.ones(n, dtype=torch.bool),
    )
