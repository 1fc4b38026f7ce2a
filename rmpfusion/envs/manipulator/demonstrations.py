"""The manipulator expert's demonstrations (paper §4.2): trajectories of 5–10 s that end once the expert has settled at
the goal, from the split's obstacle placement, with a goal per trajectory."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import torch
from torch import Tensor

from ..demonstrations import Dataset
from ..rollout import Rollout
from .params import ManipulatorParams
from .task import ManipulatorTask


def demonstration_lengths(p: ManipulatorParams, ro: Rollout) -> Tensor:
    """(B,) records to keep of each demonstration (paper §4.2: trajectories of 5–10 s).

    A demonstration runs until the expert has settled at the goal (within ``demo_settle_distance`` and
    slower than ``demo_settle_speed``) but at least ``demo_min_duration``; at most the whole rollout.
    Records after an error (NaN) are never kept.
    """
    assert ro.goal_distance is not None  # every manipulator rollout records its end effector's goal distance
    finite = ro.q.isfinite().all(-1) & ro.qd.isfinite().all(-1)  # (T, B)
    settled = (
        (ro.goal_distance <= p.demo_settle_distance)
        & (ro.qd.norm(dim=-1) <= p.demo_settle_speed)
        & (ro.times[:, None] >= p.demo_min_duration - 1e-9)
        & finite
    )
    T = ro.q.shape[0]
    idx = torch.arange(T)[:, None].expand_as(settled)
    first_settled = torch.where(settled, idx, T).min(0).values  # T when never settled
    first_bad = torch.where(~finite, idx, T).min(0).values
    return torch.minimum(first_settled + 1, first_bad).clamp(max=T)


def demonstrations(
    env: ManipulatorTask,
    expert: Callable[..., Any],
    n_envs: int,
    n_traj: int,
    n_points: int,
    interval: float,
    generator: torch.Generator | None = None,
    split: str = "train",
    progress: Callable[[int, int], Any] | None = None,
) -> Dataset:
    """The expert's demonstrations of a data split (paper §4.2) as a ``Dataset``.

    ``n_envs`` obstacle placements of the split's scene (``scene_of``) × ``n_traj`` (start, goal) pairs; the
    expert runs for at most ``(n_points − 1)·interval`` s in ``collect_mode``, recorded every ``interval`` s
    and cut by ``demonstration_lengths``. Each record is (q, q̇, aux at that time, the expert's q̈ there).
    """
    envs = env.sample_envs(n_envs, generator, split=split)
    q0, qd0, aux = env.sample_initial_states(envs, n_traj, generator)
    with torch.no_grad():
        ro = env.rollout(
            expert,
            q0,
            qd0,
            aux,
            horizon=(n_points - 1) * interval,
            record_every=interval,
            mode=env.params.collect_mode,
            progress=progress,
        )
    lengths = demonstration_lengths(env.params, ro).tolist()
    B = q0.shape[0]
    rows = [(b, k) for b in range(B) for k in range(lengths[b])]  # trajectory-major, time-ordered
    bi = torch.tensor([r[0] for r in rows], dtype=torch.long)
    ki = torch.tensor([r[1] for r in rows], dtype=torch.long)
    return Dataset(
        q=ro.q[ki, bi].contiguous(),
        qd=ro.qd[ki, bi].contiguous(),
        qdd=ro.qdd[ki, bi].detach().contiguous(),
        aux=env.aux_at({k: v[bi].contiguous() for k, v in aux.items()}, ro.times[ki]),
        env_id=bi // n_traj,
        traj_id=bi,
        t=ro.times[ki].contiguous(),
        collided=ro.collided.clone(),
        success=ro.success.clone(),
    )
