"""rmpfusion's tasks as Gymnasium environments: one episode (``RMPfusionEnv``) or a batch stepped together
(``RMPfusionVectorEnv``, one simulator call for every sub-environment).

Observation: q, q̇ and the aux state (goal, obstacles; moving obstacles at the current time), float32. Action: a
residual on the base tree's q̈ (``GymTask.base``; RMP² trains its policies this way), a ∈ [−1, 1]^d scaled by
``action_scale`` and added at every integration step of a decision interval; with no base tree it is q̈ itself.
Reward: minus the task cost of the interval (``learn/task_cost.py``, the objective the ``apg`` and ``pg`` methods
minimise). An episode is ``terminated`` when the goal is reached (within the environment's goal tolerance) or an
obstacle is hit, and ``truncated`` at the time-out or when the simulator ends a sample with an error. A collision
costs what staying at that distance from the goal until the time-out would, so ending an episode by hitting an
obstacle never pays.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

import gymnasium as gym
import numpy as np
import torch
from gymnasium.vector import AutoresetMode, VectorEnv
from torch import Tensor

from ..envs.common import qdd_of
from ..envs.protocol import TimeVaryingAux
from ..learn.task_cost import rollout_costs, total
from .task import GymTask


@runtime_checkable
class HoldsASimulator(Protocol):
    """An environment with a simulator process to shut down (pybullet's)."""

    def close(self) -> None: ...


@dataclass
class Step:
    """What a decision interval did to a batch: the new state, the reward and how each episode stands."""

    q: Tensor
    qd: Tensor
    reward: Tensor  # (B,)
    reached: Tensor  # (B,) bool
    collided: Tensor  # (B,) bool
    failed: Tensor  # (B,) bool: the simulator ended the sample with an error
    goal_distance: Tensor  # (B,)
    clearance: Tensor  # (B,) the closest approach to an obstacle during the interval


class BatchStepper:
    """B episodes of one task, advanced one decision interval at a time in one rollout of the environment."""

    def __init__(self, task: GymTask):
        self.task = task

    def starts(self, n: int, gen: torch.Generator) -> tuple[Tensor, Tensor, dict[str, Tensor]]:
        env = self.task.env
        envs = env.sample_envs(n, gen, split=self.task.split)
        return env.sample_initial_states(envs, 1, gen)

    def aux_at(self, aux0: Mapping[str, Tensor], t: Tensor) -> dict[str, Tensor]:
        """The aux state at times ``t`` (B,): moving obstacles where they are by then."""
        env = self.task.env
        return env.aux_at(aux0, t) if isinstance(env, TimeVaryingAux) else dict(aux0)

    def policy(self, action: Tensor):
        """q̈ at every integration step: the base tree's plus the scaled action, held for the interval."""
        scaled = self.task.action_scale * action
        base = self.task.base
        if base is None:
            return lambda q, qd, aux: scaled
        return lambda q, qd, aux: qdd_of(base(q, qd, aux)) + scaled

    def step(self, q: Tensor, qd: Tensor, aux: Mapping[str, Tensor], t: Tensor, action: Tensor) -> Step:
        """One interval from (q, q̇) at times ``t`` (B,), the aux state given at t = 0."""
        task = self.task
        now = self.aux_at(aux, t)
        h = task.decision_interval
        ro = task.env.rollout(self.policy(action), q, qd, now, horizon=h, record_every=h)
        assert ro.goal_distance is not None, "rmpfusion's tasks record the distance to the goal"
        failed = torch.tensor([e is not None for e in ro.error], dtype=torch.bool) if ro.error else None
        q1, qd1 = ro.q[-1], ro.qd[-1]
        finite = q1.isfinite().all(-1) & qd1.isfinite().all(-1)
        failed = ~finite if failed is None else failed | ~finite
        cost = total(rollout_costs(task.cost, ro, final=False))[0]
        distance = ro.goal_distance[-1]
        remaining = (task.horizon - (t + h)).clamp(min=0)
        cost = cost + torch.where(ro.collided, task.cost.goal_distance * distance * remaining, torch.zeros(()))
        keep = ~failed
        return Step(
            q=torch.where(keep[:, None], q1, q),
            qd=torch.where(keep[:, None], qd1, torch.zeros_like(qd)),
            reward=torch.where(keep, -cost, torch.zeros(())),
            reached=ro.reached & keep,
            collided=ro.collided & keep,
            failed=failed,
            goal_distance=torch.where(keep, distance, ro.goal_distance[0]),
            clearance=ro.min_clearance,
        )


def _spaces(task: GymTask) -> tuple[gym.spaces.Box, gym.spaces.Box]:
    obs = gym.spaces.Box(-np.inf, np.inf, shape=(task.observation_dim,), dtype=np.float32)
    act = gym.spaces.Box(-1.0, 1.0, shape=(task.env.dim,), dtype=np.float32)
    return obs, act


def _as_action(action: Any, shape: tuple[int, ...]) -> Tensor:
    a = torch.as_tensor(np.asarray(action, dtype=np.float64)).reshape(shape)
    return a.clamp(-1.0, 1.0)


def _info(s: Step, i: int, t: float) -> dict[str, Any]:
    return {
        "time": t,
        "goal_distance": float(s.goal_distance[i]),
        "clearance": float(s.clearance[i]),
        "reached": bool(s.reached[i]),
        "collided": bool(s.collided[i]),
        "is_success": bool(s.reached[i] & ~s.collided[i]),
    }


class RMPfusionEnv(gym.Env):
    """One episode of an rmpfusion task at a time (``gymnasium.make("rmpfusion/<Experiment>-v0")``)."""

    def __init__(self, task: GymTask):
        self.metadata = {"render_modes": []}  # nothing to render: the run's figures and rmpfusion-view draw tasks
        self.task = task
        self.stepper = BatchStepper(task)
        self.observation_space, self.action_space = _spaces(task)
        self._gen = torch.Generator().manual_seed(0)
        self._state: tuple[Tensor, Tensor, dict[str, Tensor]] | None = None
        self._t = torch.zeros(1, dtype=torch.float64)
        self._decisions = 0

    def _observation(self) -> np.ndarray:
        assert self._state is not None, "reset() first"
        q, qd, aux = self._state
        now = self.stepper.aux_at(aux, self._t)
        return self.task.observe(q, qd, now)[0].numpy().astype(np.float32)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        if seed is not None:
            self._gen = torch.Generator().manual_seed(seed)
        self._state = self.stepper.starts(1, self._gen)
        self._t = torch.zeros(1, dtype=torch.float64)
        self._decisions = 0
        return self._observation(), {"time": 0.0}

    def step(self, action):
        if self._state is None:
            raise RuntimeError("step() before reset(): call reset() to start an episode")
        q, qd, aux = self._state
        s = self.stepper.step(q, qd, aux, self._t, _as_action(action, (1, self.task.env.dim)))
        self._state = (s.q, s.qd, aux)
        self._t = self._t + self.task.decision_interval
        self._decisions += 1
        terminated = bool(s.reached[0] | s.collided[0])
        truncated = not terminated and (self._decisions >= self.task.decisions or bool(s.failed[0]))
        return self._observation(), float(s.reward[0]), terminated, truncated, _info(s, 0, float(self._t[0]))

    def close(self):
        if isinstance(self.task.env, HoldsASimulator):
            self.task.env.close()


class RMPfusionVectorEnv(VectorEnv):
    """``num_envs`` episodes of one task stepped together: one rollout of the environment per step for all of
    them (the environments batch their samples), each episode reset on the step after it ends (Gymnasium's
    next-step autoreset: that step's action is ignored for it and its reward is 0)."""

    def __init__(self, task: GymTask, num_envs: int):
        self.metadata = {"render_modes": [], "autoreset_mode": AutoresetMode.NEXT_STEP}
        if num_envs < 1:
            raise ValueError(f"num_envs={num_envs}: give at least one environment")
        self.task, self.num_envs = task, num_envs
        self.stepper = BatchStepper(task)
        self.single_observation_space, self.single_action_space = _spaces(task)
        self.observation_space = gym.vector.utils.batch_space(self.single_observation_space, num_envs)
        self.action_space = gym.vector.utils.batch_space(self.single_action_space, num_envs)
        self._gen = torch.Generator().manual_seed(0)
        self._q = self._qd = torch.zeros(num_envs, task.env.dim, dtype=torch.float64)
        self._aux: dict[str, Tensor] = {}
        self._t = torch.zeros(num_envs, dtype=torch.float64)
        self._decisions = torch.zeros(num_envs, dtype=torch.long)
        self._ended = torch.zeros(num_envs, dtype=torch.bool)

    def _observations(self) -> np.ndarray:
        now = self.stepper.aux_at(self._aux, self._t)
        return self.task.observe(self._q, self._qd, now).numpy().astype(np.float32)

    def _restart(self, which: Tensor) -> None:
        """New episodes for the environments in ``which`` (B,) bool."""
        n = int(which.sum())
        if n == 0:
            return
        q, qd, aux = self.stepper.starts(n, self._gen)
        self._q, self._qd = self._q.clone(), self._qd.clone()
        self._q[which], self._qd[which] = q, qd
        if not self._aux:
            self._aux = {k: v.new_zeros(self.num_envs, v.shape[-1]) for k, v in aux.items()}
        for k, v in aux.items():
            self._aux[k] = self._aux[k].clone()
            self._aux[k][which] = v
        self._t[which] = 0.0
        self._decisions[which] = 0

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        if seed is not None:
            self._gen = torch.Generator().manual_seed(seed)
        self._aux = {}
        self._restart(torch.ones(self.num_envs, dtype=torch.bool))
        self._ended[:] = False
        return self._observations(), {}

    def step(self, actions):
        restarting = self._ended.clone()
        s = self.stepper.step(
            self._q, self._qd, self._aux, self._t, _as_action(actions, (self.num_envs, self.task.env.dim))
        )
        self._q, self._qd = s.q, s.qd
        self._t = self._t + self.task.decision_interval
        self._decisions += 1
        terminated = s.reached | s.collided
        truncated = ~terminated & ((self._decisions >= self.task.decisions) | s.failed)
        reward = s.reward
        if restarting.any():  # the episodes that ended last step start again now, whatever was asked of them
            self._restart(restarting)
            reward = torch.where(restarting, torch.zeros(()), reward)
            terminated, truncated = terminated & ~restarting, truncated & ~restarting
        self._ended = terminated | truncated
        info = {
            "goal_distance": s.goal_distance.numpy(),
            "reached": s.reached.numpy() & ~restarting.numpy(),
            "collided": s.collided.numpy() & ~restarting.numpy(),
        }
        return self._observations(), reward.numpy(), terminated.numpy(), truncated.numpy(), info

    def close_extras(self, **kwargs):
        if isinstance(self.task.env, HoldsASimulator):
            self.task.env.close()
