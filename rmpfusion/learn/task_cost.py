"""The task cost that policy optimisation minimises without an expert (``apg``, ``pg``): a weighted sum of terms a
reaching task is judged by, accumulated over the intervals between a rollout's records.

For consecutive records k → k+1 of one trajectory, h apart, with d the distance to the goal, c the clearance to
the nearest obstacle over the interval and q the configuration:

    goal_distance    h·(d_k + d_{k+1})/2                    ∫ d dt: small when the goal is reached early
    time_to_goal     h·(s_k + s_{k+1})/2,  s = σ((d − tol)/τ)   ∫ 1[d > tol] dt smoothed: the time to the goal
    path_length      ‖q_{k+1} − q_k‖                         the path's length
    clearance        h·τ·softplus((margin − c)/τ)            ∫ (margin − c)⁺ dt smoothed: coming near obstacles
    final_distance   d at the last record (added to the last interval)

One function computes them for both methods: APG from records that carry the autograd graph, the policy gradient
from records of its segments (``rollout_costs``), so the two optimise the same objective.
"""

from __future__ import annotations

from collections.abc import Mapping

import torch
import torch.nn.functional as F
from pydantic import Field, model_validator
from torch import Tensor

from ..envs.rollout import Rollout
from ..registry import Params

TERMS = ("goal_distance", "time_to_goal", "path_length", "clearance", "final_distance")


class TaskCost(Params):
    """The weights of the task cost's terms (0 leaves a term out) and the constants of its smoothings."""

    goal_distance: float = Field(1.0, ge=0, description="weight of ∫ d dt (distance to the goal over time)")
    time_to_goal: float = Field(0.0, ge=0, description="weight of the smoothed time spent beyond goal_tolerance")
    path_length: float = Field(0.0, ge=0, description="weight of the path's length")
    clearance: float = Field(0.0, ge=0, description="weight of ∫ (clearance_margin − clearance)⁺ dt, smoothed")
    final_distance: float = Field(0.0, ge=0, description="weight of the distance to the goal at the end")
    goal_tolerance: float = Field(0.1, gt=0, description="the distance that counts as at the goal (time_to_goal)")
    clearance_margin: float = Field(0.1, ge=0, description="clearance below which the clearance term grows")
    temperature: float = Field(0.05, gt=0, description="τ of both smoothings, in the unit of distance")

    @model_validator(mode="after")
    def _something_to_minimise(self):
        if not any(self.weights().values()):
            raise ValueError(
                f"at least one of the weights {', '.join(TERMS)} must be > 0 (a cost of 0 has nothing to "
                "minimise); given all 0"
            )
        return self

    def weights(self) -> dict[str, float]:
        return {k: getattr(self, k) for k in TERMS}


def interval_costs(
    cost: TaskCost, times: Tensor, q: Tensor, distance: Tensor, clearance: Tensor | None, final: bool = True
) -> dict[str, Tensor]:
    """Each weighted term of ``cost`` per interval between records: ``{term: (T−1, B)}``.

    ``times`` (T,), ``q`` (T, B, d) and ``distance`` (T, B) are the records; ``clearance`` (T−1, B) is each
    interval's clearance (None: no obstacles to keep clear of). ``final`` adds the final distance to the last
    interval (a truncated window that is not the rollout's last leaves it out). Terms with weight 0 are left out.
    """
    h = (times[1:] - times[:-1]).to(distance)[:, None]
    mean = lambda x: 0.5 * (x[1:] + x[:-1])
    out: dict[str, Tensor] = {}
    w = cost.weights()
    if w["goal_distance"]:
        out["goal_distance"] = w["goal_distance"] * h * mean(distance)
    if w["time_to_goal"]:
        out["time_to_goal"] = (
            w["time_to_goal"] * h * mean(torch.sigmoid((distance - cost.goal_tolerance) / cost.temperature))
        )
    if w["path_length"]:
        out["path_length"] = w["path_length"] * (q[1:] - q[:-1]).norm(dim=-1)
    if w["clearance"] and clearance is not None:
        tau = cost.temperature
        out["clearance"] = w["clearance"] * h * tau * F.softplus((cost.clearance_margin - clearance) / tau)
    if w["final_distance"] and final:
        last = torch.zeros_like(distance[1:])
        last[-1] = distance[-1]
        out["final_distance"] = w["final_distance"] * last
    return out


def total(terms: Mapping[str, Tensor]) -> Tensor:
    """The task cost per interval (T−1, B): the sum of the weighted terms."""
    return torch.stack(list(terms.values())).sum(0)


def record_clearance(clearance: Tensor) -> Tensor:
    """Each interval's clearance from clearances at the records (T, B): the nearer of its two ends."""
    return torch.minimum(clearance[1:], clearance[:-1])


def rollout_costs(cost: TaskCost, ro: Rollout, final: bool = True) -> dict[str, Tensor]:
    """``interval_costs`` of a recorded rollout whose records span one interval each of its own (a segment of
    the policy gradient: records at the start and the end); the clearance of the interval is the rollout's
    closest approach over every integration step (``min_clearance``)."""
    if ro.goal_distance is None:
        raise ValueError(
            "the task cost needs rollouts that record the distance to the goal (Rollout.goal_distance); "
            "this environment's rollouts do not"
        )
    clear = ro.min_clearance.to(ro.goal_distance)[None].expand(len(ro.times) - 1, -1)
    return interval_costs(cost, ro.times, ro.q, ro.goal_distance, clear, final)
