"""Torque mode: every sample has its own simulated world (``env.sim``: pybullet, MuJoCo, a plugin's), and the
policy's acceleration becomes joint torques by computed-torque control (the simulator's own inverse dynamics). The
simulated robot is then the paper's feedback-linearised system, integrated by the simulator itself."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

import numpy as np
import torch
from torch import Tensor

from ...sims import SimulationError, WorldSettings
from ..common import evaluate_policy
from ..faults import IsolatingPolicy
from ..rollout import Rollout
from .rollout_records import GoalTracker, Recorder, finish
from .task import ManipulatorTask
from .worlds import TaskWorld, sample_aux


def rollout_torque(
    env: ManipulatorTask,
    policy: Callable[..., Any],
    q0: Tensor,
    qd0: Tensor,
    aux: Mapping[str, Tensor],
    n_steps: int,
    every: int,
    monitor: Callable[..., Any] | None,
) -> Rollout:
    """``n_steps`` simulator steps recorded every ``every`` steps; a sample whose world fails (a simulator error)
    or whose policy answers a non-finite acceleration ends there with its reason, the others go on."""
    dt = env.dt
    policy = IsolatingPolicy(policy)  # a sample whose evaluation raises gets NaN, the others go on
    worlds = _Worlds(env, policy, q0, qd0)
    try:
        worlds.open(aux)
        rec = Recorder()
        goal_hit = GoalTracker(q0.shape[0], env.dtype)
        worlds.read_states()
        goal_hit.update(0.0, env.ee_position(worlds.q), aux["goal"], env.params.goal_tolerance, worlds.alive, worlds.q)
        for k in range(n_steps + 1):
            a, V, D = evaluate_policy(policy, worlds.q, worlds.qd, env.aux_at(aux, k * dt) if env.moving else aux)
            if k % every == 0:
                rec.add(k * dt, worlds.q, worlds.qd, a, V, D, worlds.alive, monitor)
            if k == n_steps:
                break
            if env.moving:  # the obstacles where they are at the end of the step, which the clearance sees
                worlds.move_obstacles(env.aux_at(aux, (k + 1) * dt))
            worlds.step(a, k)
            worlds.read_states()
            goal_hit.update(
                (k + 1) * dt, env.ee_position(worlds.q), aux["goal"], env.params.goal_tolerance, worlds.alive, worlds.q
            )
    finally:
        worlds.close()
    return finish(env, "torque", rec, aux, worlds.min_clear, worlds.first_hit, goal_hit, worlds.errors)


class _Worlds:
    """The batch's simulated worlds, one a sample, and what each has seen: its state (q, q̇ of the actuated joints,
    the held joints' apart), whether it is still alive and why not, its smallest clearance and first collision time."""

    def __init__(self, env: ManipulatorTask, policy: IsolatingPolicy, q0: Tensor, qd0: Tensor):
        B = q0.shape[0]
        self.env, self.policy, self.q0, self.qd0 = env, policy, q0, qd0
        self.errors: list[str | None] = [None] * B
        self.alive = torch.ones(B, dtype=torch.bool)
        self.scenes: list[TaskWorld | None] = []
        self.min_clear = torch.full((B,), float(env.params.clearance_query), dtype=env.dtype)
        self.first_hit = torch.full((B,), float("inf"), dtype=env.dtype)
        self.q, self.qd = q0.clone(), qd0.clone()

    def open(self, aux: Mapping[str, Tensor]) -> None:
        """A world per sample at its initial state (the GUI, if asked for, shows sample 0)."""
        env = self.env
        gui = env.params.gui
        for b in range(self.q0.shape[0]):
            try:
                settings = WorldSettings(gravity=env.params.gravity, timestep=env.dt, gui=gui and b == 0)
                sc = TaskWorld(env.robot, settings, env.params.sim)
                sc.set_env(env.scene, sample_aux(aux, b))
                sc.reset(self.q0[b].cpu().numpy(), self.qd0[b].cpu().numpy())
                self.scenes.append(sc)
                self.min_clear[b] = sc.clearance(env.params.clearance_query)
                if self.min_clear[b] <= 0.0:
                    self.first_hit[b] = 0.0
            except SimulationError as e:
                self.scenes.append(None)
                self.errors[b] = f"simulator error at setup: {e}"
                self.alive[b] = False

    def kill(self, b: int, reason: str) -> None:
        self.alive[b] = False
        self.errors[b] = reason
        sc = self.scenes[b]
        if sc is not None:
            sc.close()
            self.scenes[b] = None

    def read_states(self) -> None:
        """(q, q̇) of every live world into ``q`` and ``qd`` (in place: the policy and the records see them)."""
        for b, sc in enumerate(self.scenes):
            if not self.alive[b] or sc is None:  # a world that is gone is dead
                continue
            try:
                qa, qda = sc.sim.state()
            except SimulationError as e:
                self.kill(b, f"simulator error reading state: {e}")
                continue
            n = self.env.dim
            self.q[b] = torch.as_tensor(qa[:n], dtype=self.env.dtype)
            self.qd[b] = torch.as_tensor(qda[:n], dtype=self.env.dtype)

    def step(self, a: Tensor, k: int) -> None:
        """One simulator step of every live world under the torques that realise the accelerations ``a`` at step k."""
        a_np = a.detach().cpu().numpy()
        for b, sc in enumerate(self.scenes):
            if not self.alive[b] or sc is None:  # a world that is gone is dead
                continue
            if not np.isfinite(a_np[b]).all():
                self.kill(b, self.policy.explain(b, f"non-finite acceleration at t={k * self.env.dt:.4f}s"))
                continue
            try:
                self._step_one(b, sc, a_np[b], k)
            except SimulationError as e:
                self.kill(b, f"simulator error at t={k * self.env.dt:.4f}s: {e}")

    def _step_one(self, b: int, sc: TaskWorld, a: np.ndarray, k: int) -> None:
        dt = self.env.dt
        sc.step_computed_torque(a, self.env.robot.params.held_joint_gains)
        self.min_clear[b] = min(float(self.min_clear[b]), sc.clearance(self.env.params.clearance_query))
        if self.min_clear[b] <= 0.0 and self.first_hit[b].isinf():
            self.first_hit[b] = (k + 1) * dt

    def move_obstacles(self, aux: Mapping[str, Tensor]) -> None:
        """Every live world's moving obstacles to where ``aux`` (at the current time) has them."""
        for b, sc in enumerate(self.scenes):
            if self.alive[b] and sc is not None:
                sc.move_obstacles(self.env.scene, sample_aux(aux, b))

    def close(self) -> None:
        for sc in self.scenes:
            if sc is not None:
                sc.close()
