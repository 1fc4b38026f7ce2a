"""Kinematic mode: the closed loop q̈ = π(q, q̇, aux) integrated in torch for the whole batch at once (fast, for
data collection), then every integration step checked for collisions after the fact: bounded in torch by the robot's
spheres for the whole batch, the simulator (``env.sim``) asked only where the bound cannot decide (``collisions.py``)."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

import torch
from torch import Tensor

from ..common import evaluate_policy, qdd_of, rk4, semi_implicit_euler
from ..faults import IsolatingPolicy
from ..rollout import Rollout
from .collisions import check_collisions
from .rollout_records import GoalTracker, Recorder, finish
from .task import ManipulatorTask


def rollout_kinematic(
    env: ManipulatorTask,
    policy: Callable[..., Any],
    q0: Tensor,
    qd0: Tensor,
    aux: Mapping[str, Tensor],
    n_steps: int,
    every: int,
    monitor: Callable[..., Any] | None,
    checked: Callable[[int], Any] | None = None,
) -> Rollout:
    """``n_steps`` integration steps recorded every ``every`` steps; a sample whose policy evaluation raises or
    whose state stops being finite ends there with its reason, the others go on. ``checked(b)`` is called once
    sample b's path has been checked for collisions."""
    policy = IsolatingPolicy(policy)  # a sample whose evaluation raises gets NaN, the others go on
    errors: list[str | None] = [None] * q0.shape[0]
    rec, path, goal_hit, alive = integrate(env, policy, q0, qd0, aux, n_steps, every, monitor, errors)
    death = rec.death_index(alive, errors, n_steps, every)
    min_clear, first_hit = check_collisions(env, torch.stack(path), aux, n_steps, death, errors, checked)
    return finish(env, "kinematic", rec, aux, min_clear, first_hit, goal_hit, errors)


def integrate(env: ManipulatorTask, policy: IsolatingPolicy, q0, qd0, aux, n_steps, every, monitor, errors):
    """The torch integration, before the collision check: (records, q at every integration step, goal tracker,
    alive). Semi-implicit Euler evaluates the policy once a step (the recorded evaluation drives the step); RK4
    reuses it at record steps. What ``tools/bench.py``'s rollout row times a step of."""
    dt, B, p = env.dt, q0.shape[0], env.params
    q, qd = q0.clone(), qd0.clone()
    alive = torch.ones(B, dtype=torch.bool)
    rec = Recorder()
    path = [q.detach().clone()]  # every integration step, checked for collisions
    goal_hit = GoalTracker(B, env.dtype)
    goal_hit.update(0.0, env.ee_position(q), aux["goal"], p.goal_tolerance, alive, q)
    euler = p.integrator == "semi_implicit_euler"

    aux_k = aux

    def accel(x, xd):  # RK4's stages see the obstacles where they are at the start of the step
        return qdd_of(policy(x, xd, aux_k))

    for k in range(n_steps + 1):
        a = None
        aux_k = env.aux_at(aux, k * dt) if env.moving else aux
        if k % every == 0 or euler:
            a, V, D = evaluate_policy(policy, q, qd, aux_k)
            if k % every == 0:
                rec.add(k * dt, q, qd, a, V, D, alive, monitor)
        if k == n_steps:
            break
        q_new, qd_new = (semi_implicit_euler if euler else rk4)(accel, q, qd, dt, a)
        finite = q_new.isfinite().all(-1) & qd_new.isfinite().all(-1)
        for b in (alive & ~finite).nonzero().flatten().tolist():
            errors[b] = policy.explain(b, f"non-finite state at t={(k + 1) * dt:.4f}s")
        alive = alive & finite  # a new tensor: the where() below keeps this mask for its gradient
        # a dead sample keeps its last finite state so the batched evaluation stays well posed
        q = torch.where(alive[:, None], q_new, q)
        qd = torch.where(alive[:, None], qd_new, torch.zeros_like(qd))
        path.append(q.detach().clone())
        goal_hit.update((k + 1) * dt, env.ee_position(q), aux["goal"], p.goal_tolerance, alive, q)
    return rec, path, goal_hit, alive
