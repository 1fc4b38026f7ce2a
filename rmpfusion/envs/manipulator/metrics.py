"""The reaching task's per-trajectory metrics (paper §4.2) and which of them are compared with the expert."""

from __future__ import annotations

import torch
from torch import Tensor

from ..rollout import Rollout

#: Metrics compared with the expert's as per-trajectory ratios learner/expert (paper Fig. 5b). The paper's
#: "goal distance at the end of an execution" is not among them: an execution ends at ``goal_tolerance``, so
#: for every policy that reaches the goal it is ~0.05 m and its ratio is 1 by construction. The distance at the
#: time-out (the rollout always continues to it) and the closest approach say how well each policy got there.
RATIO_METRICS = ("time", "cspace_length", "ee_length", "timeout_goal_distance", "min_goal_distance")
#: A rollout that never collides but comes closer than this to an obstacle (m) is a close pass: what the expert's
#: obstacle weights prevent (ours; the expert keeps ≥ 3 cm on the validation starts, unit obstacle weights < 1 cm).
CLOSE_PASS = 0.01


def task_metrics(ro: Rollout, dtype: torch.dtype) -> dict[str, Tensor]:
    """Per-trajectory (B,) metrics of paper §4.2 on a rollout whose horizon is the time-out.

    An execution ends when the end effector first comes within ``goal_tolerance`` of the goal, else at the
    time-out. ``time``: its duration; ``cspace_length`` / ``ee_length``: distance travelled in configuration
    space (rad) and by the end effector (m) during it; ``goal_distance``: end-effector–goal distance when it
    ended (the paper's). ``timeout_goal_distance``: the distance at the time-out; ``min_goal_distance``: the
    closest the end effector came at any record. Also ``reached``, ``collided`` (any link within zero distance
    of an obstacle during the whole rollout), ``min_clearance`` and ``close_pass`` (no collision, but closer than
    ``CLOSE_PASS``). A rollout ended by an error gets NaN
    execution metrics.
    """
    assert (  # the execution records every manipulator rollout carries (None only for other environments)
        ro.time_to_goal is not None
        and ro.goal_distance is not None
        and ro.cspace_length is not None
        and ro.ee_length is not None
        and ro.end_goal_distance is not None
    )
    timeout = float(ro.times[-1])
    failed = torch.tensor([e is not None for e in ro.error])
    time = torch.where(ro.reached, ro.time_to_goal, torch.full_like(ro.time_to_goal, timeout))
    closest = torch.where(ro.goal_distance.isfinite(), ro.goal_distance, float("inf")).min(0).values
    out = {
        "time": time,
        "cspace_length": ro.cspace_length,
        "ee_length": ro.ee_length,
        "goal_distance": ro.end_goal_distance,
        "timeout_goal_distance": ro.goal_distance[-1],
        "min_goal_distance": closest,
    }
    out = {k: torch.where(failed, float("nan"), v) for k, v in out.items()}
    out.update(
        {
            "reached": ro.reached.to(dtype),
            "collided": ro.collided.to(dtype),
            "min_clearance": ro.min_clearance,
            "error": failed.to(dtype),
            "close_pass": (~ro.collided & (ro.min_clearance < CLOSE_PASS)).to(dtype),
        }
    )
    return out
