"""Recorded demonstrations as the ``Dataset`` every learner trains on: the states on the step grid, the
accelerations the smoothing differentiator gave as labels, the goal as aux state, one trajectory per
demonstration."""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
import torch

from ..envs.demonstrations import Dataset
from .signals import States


def recorded_dataset(
    states: Sequence[States],
    every: int = 1,
    dtype: torch.dtype = torch.float64,
    aux_of: Callable[[torch.Tensor], dict[str, torch.Tensor]] | None = None,
) -> Dataset:
    """One dataset of ``states`` (each a demonstration), keeping every ``every``-th grid sample. Each
    demonstration's aux state is ``aux_of`` of its goal (the configuration it comes to rest at; the environment's
    ``recorded_aux``: e.g. an arm's end-effector goal, obstacles and posture), by default the goal itself as the aux
    entry ``goal``; a demonstration's own aux entries (from its file's columns) come along and take precedence."""
    parts: dict[str, list[np.ndarray]] = {k: [] for k in ("q", "qd", "qdd", "t", "traj")}
    goals = torch.as_tensor(np.stack([st.goal for st in states]), dtype=dtype)
    per_demo = aux_of(goals) if aux_of is not None else {"goal": goals}
    aux: dict[str, list[np.ndarray]] = {}
    for n, st in enumerate(states):
        rows = slice(None, None, every)
        T = len(st.t[rows])
        for key, value in (("q", st.q), ("qd", st.qd), ("qdd", st.qdd), ("t", st.t)):
            parts[key].append(value[rows])
        parts["traj"].append(np.full(T, n))
        own = {k: v[n].detach().cpu().numpy() for k, v in per_demo.items()}
        own.update({k: np.asarray(v, np.float64) for k, v in st.aux.items()})
        for name, value in own.items():
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
