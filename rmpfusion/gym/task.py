"""What a Gymnasium environment of rmpfusion steps: an experiment's environment, the tree whose q̈ an action is a
residual on, the task cost that rewards are made of, and the decision clock.

A task is built from the same configs as ``rmpfusion-run`` (an experiment name and overrides), so a policy trained
by a reinforcement-learning library meets the environment, tree and scene an rmpfusion experiment evaluates.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Literal

import torch
from torch import Tensor

from ..core.tree import RMPTree
from ..envs.protocol import Env
from ..learn.task_cost import TaskCost
from ..pipeline.compose import compose_run
from ..pipeline.config import DataConfig, RunConfig
from ..pipeline.construct import build_expert, build_unit_weights, make_env
from ..pipeline.experiment import evaluation_horizon

Base = Literal["unit_weights", "expert", "none"]


class TaskError(ValueError):
    """A Gymnasium task that cannot be built as asked: said in one line with what to change."""


@dataclass
class GymTask:
    """One experiment's pieces, as a Gymnasium environment steps them.

    ``base`` is the tree an action is a residual on: ``unit_weights`` (RMPflow: the experiment's tree with every
    weight 1, what a learner may start from), ``expert`` (the hand-designed weights) or ``none`` (the action is q̈
    itself). The action a ∈ [−1, 1]^d adds ``action_scale``·a to the base's q̈ at every integration step of a
    decision interval."""

    run: RunConfig
    env: Env
    base: RMPTree | None
    cost: TaskCost
    horizon: float  # s: an episode's time-out
    decision_interval: float  # s between actions
    action_scale: float
    split: str

    @property
    def decisions(self) -> int:
        return round(self.horizon / self.decision_interval)

    @property
    def aux_names(self) -> list[str]:
        """The order aux entries take in an observation (after q and q̇)."""
        return sorted(self.env.aux_dims())

    @property
    def observation_dim(self) -> int:
        return 2 * self.env.dim + sum(self.env.aux_dims().values())

    def observe(self, q: Tensor, qd: Tensor, aux: Mapping[str, Tensor]) -> Tensor:
        """(B, observation_dim): q, q̇ and every aux entry in ``aux_names`` order."""
        return torch.cat([q, qd, *(aux[k] for k in self.aux_names)], dim=-1)


def build_task(
    experiment: str,
    overrides: Sequence[str] = (),
    base: Base = "unit_weights",
    decision_interval: float = 0.1,
    action_scale: float = 5.0,
    horizon: float | None = None,
    cost: Mapping[str, float] | None = None,
    split: str = "train",
) -> GymTask:
    """The task of an experiment. ``horizon`` defaults to the experiment's evaluation horizon (``eval.horizon``, else
    its demonstrations' length); ``cost`` sets the task cost's weights (``rmpfusion.learn.task_cost.TaskCost``,
    default the distance to the goal integrated over time)."""
    run = compose_run([f"experiment={experiment}", *overrides])
    if not isinstance(run.data, DataConfig):
        raise TaskError(f"experiment '{experiment}' learns from recorded demonstrations: it has no simulated task")
    env = make_env(run)
    horizon = horizon if horizon is not None else evaluation_horizon(run.eval, run.data)
    steps = decision_interval / env.dt
    if not decision_interval > 0 or abs(steps - round(steps)) > 1e-6 * steps:
        raise TaskError(
            f"decision_interval={decision_interval} must be a positive whole number of the environment's "
            f"integration steps ({env.dt} s)"
        )
    if not action_scale > 0:
        raise TaskError(f"action_scale={action_scale} must be positive (the q̈ that an action of 1 adds)")
    if split not in ("train", "val", "test"):
        raise TaskError(f"split='{split}': starts are drawn from the train, val or test split's distribution")
    trees = {"unit_weights": build_unit_weights, "expert": build_expert}
    if base not in (*trees, "none"):
        raise TaskError(f"base='{base}': give unit_weights, expert or none")
    tree = trees[base](run, env.aux_dims()).double() if base != "none" else None
    return GymTask(
        run=run,
        env=env,
        base=tree,
        cost=TaskCost(**(cost or {})),
        horizon=float(horizon),
        decision_interval=decision_interval,
        action_scale=action_scale,
        split=split,
    )
