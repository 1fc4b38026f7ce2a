"""The record of a batched closed-loop rollout, one type for every environment.

Evaluation, demonstration collection and the figures read rollouts without knowing which environment made them,
so the fields they read are typed here once instead of probed with ``getattr``. What only a manipulator has (an
end effector, the execution that ends at the goal) is optional and None elsewhere.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields, replace

import torch
from torch import Tensor


@dataclass
class Rollout:
    """A batch of B closed-loop trajectories sampled at the T record times ``times``.

    ``V`` and ``dissipation`` (q̇ᵀ B q̇ at the root, so dV/dt should equal −dissipation) exist only when the policy
    returns a TreeOutput (an RMPTree does); for a plain callable they are None. A sample ended early by an error
    (a simulator fault, a non-finite state) has its reason in ``error`` and NaN records from then on; its flags
    count only what happened before. Environments that never end a sample early leave ``error`` empty.
    """

    times: Tensor  # (T,)
    q: Tensor  # (T, B, d)
    qd: Tensor  # (T, B, d)
    qdd: Tensor  # (T, B, d): the policy's command
    collided: Tensor  # (B,) bool: in collision at some integration step
    reached: Tensor  # (B,) bool: within the goal tolerance at some integration step
    success: Tensor  # (B,) bool: reached (the 2-D env: at the final time), never collided, no error
    min_clearance: Tensor  # (B,) closest approach to an obstacle (≤ 0 or negative: collision)
    first_collision_time: Tensor  # (B,) first integration time in collision (s), inf if never
    V: Tensor | None = None  # (T, B)
    dissipation: Tensor | None = None  # (T, B): q̇ᵀBq̇ at the root
    error: list[str | None] = field(default_factory=list)  # (B,) why each sample ended early, None if it did not
    goal_distance: Tensor | None = None  # (T, B) the controlled point (particle, end effector) to the goal
    # a manipulator's end effector and its execution (paper §4.2): from t = 0 until the goal tolerance is first
    # reached, else the whole horizon
    mode: str | None = None  # how the rollout was integrated (Franka: "torque" or "kinematic")
    ee: Tensor | None = None  # (T, B, 3) end-effector position
    time_to_goal: Tensor | None = None  # (B,) first time within the goal tolerance (s), NaN if never
    cspace_length: Tensor | None = None  # (B,) Σ‖Δq‖ over the execution's integration steps (rad)
    ee_length: Tensor | None = None  # (B,) Σ‖Δee‖ (m)
    end_goal_distance: Tensor | None = None  # (B,) goal distance when the execution ended (m)
    # obstacles moved during the rollout: the aux state changed from outside, which Theorem 2 does not cover
    # (docs/math.md §8), so the Lyapunov monitor reports these rollouts apart
    moving: bool = False

    @property
    def batch_size(self) -> int:
        return self.q.shape[1]

    def to(self, device: torch.device | str) -> Rollout:
        """Every tensor of the record on ``device`` (a rollout computed on a GPU is read on the CPU)."""
        moved = {
            f.name: getattr(self, f.name).to(device) for f in fields(self) if isinstance(getattr(self, f.name), Tensor)
        }
        return replace(self, **moved)
