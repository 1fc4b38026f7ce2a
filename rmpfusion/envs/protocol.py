"""What the pipeline, the evaluation and the figures may ask of an environment.

``Env`` is what every registered environment provides; the capability protocols are what only some do (task
metrics, rendering, a planar workspace). Callers test a capability with ``isinstance`` against these types
instead of probing for attribute names, so a misspelt or missing method is a type error at the protocol, not a
feature that silently switches off.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

import numpy as np
import torch
from torch import Tensor

from .demonstrations import Dataset
from .rollout import Rollout


@runtime_checkable
class Env(Protocol):
    """A batched environment: sampling of aux states and starts, closed-loop rollouts, demonstrations.

    It exists so that the experiment pipeline runs any registered environment with the same calls: the
    configuration dimension and step grid (``dim``, ``dt``) size trees and recordings; ``sample_envs`` and
    ``sample_initial_states`` draw reproducibly from a generator; ``demonstrations`` is the environment's own
    protocol for the expert's data (how long a demonstration is, which obstacles a split uses).
    """

    #: configuration dimension d: q, q̇ and q̈ are (B, d)
    dim: int

    @property
    def dt(self) -> float:
        """The integration step (s); horizons and record intervals are multiples of it."""
        ...

    def aux_dims(self) -> dict[str, int]:
        """Names and sizes of the per-sample aux state; pass to ``build_tree(..., aux_dims=...)``."""
        ...

    def sample_envs(
        self, n_envs: int, generator: torch.Generator | None = None, split: str = "train"
    ) -> dict[str, Tensor]:
        """``n_envs`` environments of a data split as an aux dict of (n_envs, k) tensors."""
        ...

    def sample_initial_states(
        self, envs_aux: Mapping[str, Tensor], n_per_env: int, generator: torch.Generator | None = None
    ) -> tuple[Tensor, Tensor, dict[str, Tensor]]:
        """(q0, q̇0, aux) for n_envs·n_per_env samples, environment-major."""
        ...

    def rollout(
        self,
        policy: Callable[..., Any],
        q0: Tensor,
        qd0: Tensor,
        aux: Mapping[str, Tensor],
        horizon: float,
        record_every: float,
        monitor: Callable[..., Any] | None = None,
        progress: Callable[[int, int], Any] | None = None,
        enable_grad: bool = False,
    ) -> Rollout:
        """Run q̈ = policy(q, q̇, aux) for ``horizon`` seconds, recorded every ``record_every`` seconds."""
        ...

    def demonstrations(
        self,
        expert: Callable[..., Any],
        n_envs: int,
        n_traj: int,
        n_points: int,
        interval: float,
        generator: torch.Generator | None = None,
        split: str = "train",
        progress: Callable[[int, int], Any] | None = None,
    ) -> Dataset:
        """The expert's demonstrations of a data split, at most ``n_points`` records ``interval`` s apart."""
        ...


@runtime_checkable
class ComputesOn(Protocol):
    """An environment whose rollouts evaluate policies on a chosen device (``device`` in the run config). It exists
    because where a rollout can compute is the environment's call: the batched 2-D particle integrates on the
    device itself; pybullet stays on the CPU and sends each step's state to the policy's device and back. Either
    way the rollout it returns, and the datasets made of it, are on the CPU."""

    def to(self, device: torch.device | str) -> Any:
        """Evaluate policies on ``device`` from now on (returns the environment)."""
        ...


@runtime_checkable
class HasTaskMetrics(Protocol):
    """Per-trajectory metrics of the environment's task beyond success and collision (paper §4.2: time, path
    lengths, goal distance). It exists because only a task that defines an *execution* has them; the pipeline
    then reports them per policy and builds the task table."""

    def task_metrics(self, rollout: Rollout) -> dict[str, Tensor]:
        """``{name: (B,)}`` of a rollout whose horizon is the time-out."""
        ...


@runtime_checkable
class Reaches(Protocol):
    """A reaching task: how far each start's straight end-effector reach to its goal passes from the obstacles, so a
    run can say whether the obstacle is in the way (``scenes/crossing.py``) before it trains."""

    @property
    def ee_radius(self) -> float:
        """The end effector's control-sphere radius (m): a reach whose path clearance is below it crosses."""
        ...

    def path_clearance(self, q0: Tensor, aux: Mapping[str, Tensor]) -> Tensor:
        """(B, K) clearance of each straight reach from each obstacle's surface (m)."""
        ...

    def describe_task(self) -> str | None:
        """A line saying how the task was laid out, when the environment derived it (else None)."""
        ...


@runtime_checkable
class HasRatioMetrics(Protocol):
    """The task metrics compared with the expert as per-trajectory ratios learner/expert (paper Fig. 5b). It
    exists because a ratio means something only for some metrics (a distance that is ~0 for every policy makes
    a ratio of noise), and which ones is the environment's call."""

    ratio_metrics: tuple[str, ...]


@dataclass(frozen=True)
class RenderSettings:
    """How an environment's figures render executions: frame size, the times of a render strip, the GIF's frame
    rate and which test trajectory is shown (None: the figures choose)."""

    size: tuple[int, int]  # width, height of a frame (pixels)
    times: tuple[float, ...]  # s
    gif_fps: float
    trajectory: int | None = None


@runtime_checkable
class Renders(Protocol):
    """An environment that draws its own state as images (the Franka Panda in pybullet). It exists so that the
    figures of an execution (render strips, GIFs, paths drawn on a frame) need only this interface, and the
    settings they use come from ``render_settings`` rather than from the environment's parameter model."""

    @property
    def render_settings(self) -> RenderSettings: ...

    def render(
        self, q: Tensor | Sequence[float], aux: Mapping[str, Tensor], width: int, height: int, sample: int
    ) -> np.ndarray:
        """(height, width, 3) uint8 image of the configuration ``q`` in environment ``aux[sample]``."""
        ...

    def project(self, points: Any, width: int, height: int) -> np.ndarray:
        """(N, 2) pixel coordinates (column, row) of world points (N, 3) in ``render``'s image."""
        ...


@runtime_checkable
class TimeVaryingAux(Protocol):
    """An environment whose aux state changes during a rollout (moving obstacles). It exists so that the
    evaluation asks the expert about a learner's state with the aux state of that moment, as the rollout did."""

    def aux_at(self, aux: Mapping[str, Tensor], t: Tensor | float) -> dict[str, Tensor]:
        """``aux`` (at t = 0) at times ``t`` ((B,) or one time)."""
        ...


@runtime_checkable
class PlanarWorkspace(Protocol):
    """An environment whose configuration space is the plane with circular obstacles (the 2-D particle). It
    exists so that figures can draw trajectories over the obstacles directly in configuration space, which is
    meaningless for a manipulator's joint space."""

    def obstacles(self, aux: Mapping[str, Tensor]) -> tuple[Tensor, Tensor]:
        """Centres (B, K, 2) and radii (B, K) of the obstacles of each sample."""
        ...


@runtime_checkable
class DifferentiableRollouts(Protocol):
    """An environment that integrates rollouts in torch, whose ``rollout(..., enable_grad=True)`` keeps the autograd
    graph from the policy's parameters to every recorded state, on any integration step (the 2-D particle, the
    plane, the manipulator in kinematic mode). It exists because trajectory matching (``train.method=match``)
    back-propagates a rollout's distance to a demonstration through the rollout, which a simulator stepped outside
    torch (pybullet's torque loop) cannot offer."""

    def gradient_refusal(self) -> str | None:
        """None when rollouts keep the graph as this environment is configured; otherwise why they do not and the
        setting that would make them (the manipulator in torque mode steps pybullet)."""
        ...

    def with_step(self, dt: float) -> DifferentiableRollouts:
        """The same environment integrated on another step: gradients through long rollouts cost less on a
        coarser one, while evaluation keeps the experiment's own step."""
        ...


@runtime_checkable
class DifferentiableTask(Protocol):
    """An environment whose task geometry is differentiable in the configuration (the 2-D particle). It exists
    because policy optimisation through the simulator (``train.method=apg``) back-propagates a task cost (the goal
    distance, the clearance) through rollouts; a clearance measured by a simulator's collision queries has no
    gradient."""

    def goal_distance(self, q: Tensor, aux: Mapping[str, Tensor]) -> Tensor:
        """(..., B) distance of configurations q (..., B, d) to the goal, differentiable in q."""
        ...

    def clearance(self, q: Tensor, aux: Mapping[str, Tensor]) -> Tensor:
        """(..., B) signed distance of configurations q (..., B, d) to the nearest obstacle (< 0 inside),
        differentiable in q."""
        ...


@dataclass(frozen=True)
class ObstacleDepths:
    """How configurations lie against the obstacles of their world, point by point: what is asked of a recording
    before anything learns from it (a demonstration that passes through an obstacle teaches the tree to go through
    it). For each configuration: the smallest clearance (m, < 0 inside) of any of the environment's points from any
    obstacle (``measure`` says what it is), which point and which obstacle give it, and, where the measure is a
    bound that may find an entry the body does not make (an arm's spheres contain its links' meshes), the
    simulator's own clearance of the configurations the measure finds inside."""

    clearance: Tensor  # (M,) m; +inf where the world has no obstacle
    point: Tensor  # (M,) long: index into ``points``
    obstacle: Tensor  # (M,) long: index into ``obstacles``
    points: tuple[str, ...]  # what each point is (a control point, a link's sphere, the position)
    obstacles: tuple[str, ...]  # what each obstacle is (the scene's obstacle k and its shape, the ground)
    measure: str  # what the clearance measures, said where it is reported
    #: (M,) the simulator's clearance (m, ≤ 0: the body touches or enters) where ``clearance`` < 0, NaN elsewhere;
    #: None where the measure is the body itself (the plane's point)
    confirmed: Tensor | None = None


@runtime_checkable
class LearnsFromRecordings(Protocol):
    """An environment that learns from recorded demonstrations (``data.source: recorded``). It exists because a
    recording holds configurations only: what the tree reads besides them (the goal in the task's own space, the
    obstacles, a posture) and which configurations may start a convergence check are the environment's to say.
    A recording's goal is the configuration it ends at (the mean of its final rest)."""

    def recorded_aux(self, goals: Tensor) -> dict[str, Tensor]:
        """The aux state ``{name: (n, k)}`` of demonstrations ending at the configurations ``goals`` (n, d)."""
        ...

    def recorded_starts(self, candidates: Tensor) -> Tensor:
        """(n,) bool: which configurations ``candidates`` (n, d) may start a rollout at rest (inside the limits,
        clear of the obstacles)."""
        ...

    def recorded_depths(self, q: Tensor, aux: Mapping[str, Tensor]) -> ObstacleDepths:
        """How configurations ``q`` (M, d) of recordings lie against the obstacles their aux rows (M, ·) place."""
        ...


@runtime_checkable
class JointSpace(Protocol):
    """An environment whose configuration is a robot's joints. It exists so that joint-space recordings are
    checked against the robot file they claim to be of (joint count, names and limits) before anything is learned."""

    @property
    def robot_description(self) -> Any:
        """The robot file (``rmpfusion.robots.RobotDescription``)."""
        ...

    def ee_position(self, q: Tensor) -> Tensor:
        """(B, 3) end-effector point of configurations q (B, d)."""
        ...
