"""Kinematic mode: the closed loop q̈ = π(q, q̇, aux) integrated in torch for the whole batch at once (fast, for
data collection), then every integration step replayed in the simulator (``env.sim``) to find collisions after the fact."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

import torch
from torch import Tensor

from ...sims import SimulationError
from ..common import evaluate_policy, qdd_of, rk4, semi_implicit_euler
from ..faults import IsolatingPolicy
from ..rollout import Rollout
from .rollout_records import GoalTracker, Recorder, finish
from .task import ManipulatorTask
from .worlds import sample_aux


def rollout_kinematic(
    env: ManipulatorTask,
    policy: Callable[..., Any],
    q0: Tensor,
    qd0: Tensor,
    aux: Mapping[str, Tensor],
    n_steps: int,
    every: int,
    monitor: Callable[..., Any] | None,
    replayed: Callable[[int], Any] | None = None,
) -> Rollout:
    """``n_steps`` integration steps recorded every ``every`` steps; a sample whose policy evaluation raises or
    whose state stops being finite ends there with its reason, the others go on. ``replayed(b)`` is called once
    sample b's path has been checked for collisions."""
    policy = IsolatingPolicy(policy)  # a sample whose evaluation raises gets NaN, the others go on
    errors: list[str | None] = [None] * q0.shape[0]
    rec, path, goal_hit, alive = _integrate(env, policy, q0, qd0, aux, n_steps, every, monitor, errors)
    death = rec.death_index(alive, errors, n_steps, every)
    min_clear, first_hit = _replay_collisions(env, torch.stack(path), aux, n_steps, death, errors, replayed)
    return finish(env, "kinematic", rec, aux, min_clear, first_hit, goal_hit, errors)


def _integrate(env: ManipulatorTask, policy: IsolatingPolicy, q0, qd0, aux, n_steps, every, monitor, errors):
    """The torch integration: (records, q at every integration step, goal tracker, alive). Semi-implicit Euler
    evaluates the policy once a step (the recorded evaluation drives the step); RK4 reuses it at record steps."""
    dt, B, p = env.dt, q0.shape[0], env.params
    q, qd = q0.clone(), qd0.clone()
    alive = torch.ones(B, dtype=torch.bool)
    rec = Recorder()
    path = [q.detach().clone()]  # every integration step, replayed in the simulator for collisions
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


def _replay_collisions(
    env: ManipulatorTask,
    Q: Tensor,
    aux,
    n_steps: int,
    death: list[int],
    errors: list[str | None],
    replayed: Callable[[int], Any] | None = None,
) -> tuple[Tensor, Tensor]:
    """(smallest clearance, first collision time) of every sample from its configurations Q (n_steps+1, B, dof) up
    to the step it died at, by the simulator's closest points in the env's collision world (moving obstacles where they
    were at each step)."""
    dt, B, query = env.dt, Q.shape[1], float(env.params.clearance_query)
    min_clear = torch.full((B,), query, dtype=env.dtype)
    first_hit = torch.full((B,), float("inf"), dtype=env.dtype)
    sc = env.checker()
    for b in range(B):
        try:
            sc.set_env(env.scene, sample_aux(aux, b))
            last = n_steps if errors[b] is None else death[b]
            for k in range(last + 1):
                if env.moving:
                    sc.move_obstacles(
                        env.scene, sample_aux(env.aux_at({n: v[b : b + 1] for n, v in aux.items()}, k * dt), 0)
                    )
                sc.reset(Q[k, b].cpu().numpy())
                min_clear[b] = min(float(min_clear[b]), sc.clearance(env.params.clearance_query))
                if min_clear[b] <= 0.0 and first_hit[b].isinf():
                    first_hit[b] = k * dt
        except SimulationError as e:
            errors[b] = f"simulator error during collision check: {e}"
            env.worlds.discard_checker()  # a broken world is not reused
        if replayed is not None:
            replayed(b)
    return min_clear, first_hit
