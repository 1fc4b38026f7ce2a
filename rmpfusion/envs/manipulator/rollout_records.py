"""What both rollout modes record on the way: the records (NaN rows once a sample has died), the goal tracker
(the execution of paper §4.2, which ends on reaching the goal) and the finished ``Rollout``."""

from __future__ import annotations

from collections.abc import Mapping

import torch
from torch import Tensor

from ..rollout import Rollout
from .task import ManipulatorTask


def _kept(x: Tensor) -> Tensor:
    """A record as kept: with its graph under ``torch.enable_grad``, else a plain value (a policy that differentiates
    inside its call, such as a learned map's Jacobian, may return a graph even when the rollout asked for none)."""
    return x if torch.is_grad_enabled() else x.detach()


class Recorder:
    """Records at the record times; samples that died get NaN rows. Under ``torch.enable_grad`` the records keep
    the autograd graph (what trajectory matching back-propagates through); otherwise they are plain values."""

    def __init__(self) -> None:
        self.t: list[float] = []
        self.q: list[Tensor] = []
        self.qd: list[Tensor] = []
        self.qdd: list[Tensor] = []
        self.V: list[Tensor] = []
        self.D: list[Tensor] = []
        self.alive: list[Tensor] = []

    def add(self, t, q, qd, a, V, D, alive, monitor=None):
        """Record one time; ``monitor(i, t, q, qd, qdd, V)`` sees the live values of record i."""
        if monitor is not None:
            monitor(len(self.t), t, q, qd, a, V)
        alive = alive.clone()  # the caller's mask changes in place later; the records' gradients keep this one
        m = alive[:, None]
        nan = float("nan")
        self.t.append(t)
        self.q.append(_kept(torch.where(m, q, nan)))
        self.qd.append(_kept(torch.where(m, qd, nan)))
        self.qdd.append(_kept(torch.where(m, a, nan)))
        if V is not None:
            self.V.append(_kept(torch.where(alive, V, nan)))
        if D is not None:
            self.D.append(_kept(torch.where(alive, D, nan)))
        self.alive.append(alive)

    @staticmethod
    def stack(xs):
        return torch.stack(xs)

    def death_index(self, alive, errors, n_steps, every) -> list[int]:
        """Last integration step each sample was alive at (approximate to a record for dead ones)."""
        out = []
        for b in range(alive.shape[0]):
            if errors[b] is None:
                out.append(n_steps)
                continue
            last = max((i for i, a in enumerate(self.alive) if bool(a[b])), default=0)
            out.append(min(n_steps, (last + 1) * every))
        return out


class GoalTracker:
    """Per integration step: the first time within the goal tolerance, and the *execution* up to then (paper
    §4.2: an execution ends on reaching the goal or at the time-out): configuration-space and end-effector
    path lengths and the goal distance where it ended."""

    def __init__(self, B: int, dtype: torch.dtype) -> None:
        self.reached = torch.zeros(B, dtype=torch.bool)
        self.time = torch.full((B,), float("nan"), dtype=dtype)
        self.cspace_length = torch.zeros(B, dtype=dtype)
        self.ee_length = torch.zeros(B, dtype=dtype)
        self.end_distance = torch.full((B,), float("nan"), dtype=dtype)
        self._prev: tuple[Tensor, Tensor] | None = None

    def update(self, t, ee, goal, tol, alive, q=None):
        ee = ee.detach()
        dist = (ee - goal).norm(dim=-1)
        going = alive & ~self.reached  # executions still running at this step
        if q is not None:
            q = q.detach()
            if self._prev is not None:
                pq, pe = self._prev
                self.cspace_length += torch.where(going, (q - pq).norm(dim=-1), 0.0)
                self.ee_length += torch.where(going, (ee - pe).norm(dim=-1), 0.0)
            self._prev = (q.clone(), ee.clone())
        self.end_distance = torch.where(going, dist, self.end_distance)
        hit = (dist <= tol) & going
        self.time = torch.where(hit, torch.full_like(self.time, t), self.time)
        self.reached |= hit


def finish(
    env: ManipulatorTask,
    mode: str,
    rec: Recorder,
    aux: Mapping[str, Tensor],
    min_clear: Tensor,
    first_hit: Tensor,
    goal_hit: GoalTracker,
    errors: list[str | None],
) -> Rollout:
    """The ``Rollout`` of the records: end-effector paths and goal distances from the recorded q (NaN where a
    sample had died), collision from the smallest clearance, success = reached, never collided, no error."""
    q = rec.stack(rec.q)
    T, B = q.shape[:2]
    ee = env.ee_position(q.nan_to_num().reshape(T * B, env.dim)).reshape(T, B, 3)
    ee = torch.where(q.isnan().any(-1, keepdim=True), torch.full_like(ee, float("nan")), ee)
    gd = (ee - aux["goal"].unsqueeze(0)).norm(dim=-1)
    collided = min_clear <= 0.0
    ok = torch.tensor([e is None for e in errors])
    return Rollout(
        mode=mode,
        times=torch.tensor(rec.t, dtype=env.dtype),
        q=q,
        qd=rec.stack(rec.qd),
        qdd=rec.stack(rec.qdd),
        ee=ee,
        goal_distance=gd,
        collided=collided,
        min_clearance=min_clear,
        first_collision_time=first_hit,
        reached=goal_hit.reached,
        time_to_goal=goal_hit.time,
        success=goal_hit.reached & ~collided & ok,
        error=list(errors),
        cspace_length=goal_hit.cspace_length,
        ee_length=goal_hit.ee_length,
        end_goal_distance=goal_hit.end_distance,
        V=rec.stack(rec.V) if rec.V else None,
        moving=env.moving,
        dissipation=rec.stack(rec.D) if rec.D else None,
    )
