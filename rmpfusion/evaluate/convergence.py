"""Where rollouts from rest end up, told apart: converged, at rest away from the goal, or still moving.

A rollout that is not at the goal when the horizon ends is either held somewhere (a spurious equilibrium: it has
stopped, and a longer horizon changes nothing) or still on its way (a slow region: a longer horizon would tell).
One horizon cannot say which unless it also measures the motion at its end, so each rollout is classified at the
horizon:

* **converged**: within ``tolerance`` of the goal;
* **at rest away from the goal**: farther, and its distance to the goal changes slower than ``at_rest_rate`` (by
  default ``tolerance`` per horizon: at that rate it would not close the tolerance in another whole horizon);
* **still moving**: farther, and faster than that;
* **ended early**: its record is not finite (the environment ended it).

The time each start first came within ``tolerance`` is reported too (median and maximum over the starts that did).
"""

from __future__ import annotations

import torch
from torch import Tensor

#: at most this many rollouts of each kind are listed with their positions
SHOWN = 10
#: the distance's rate of change is measured over this last fraction of the horizon
RATE_WINDOW = 0.01


def _last_rate(times: Tensor, goal_distance: Tensor) -> Tensor:
    """|d(distance)/dt| over the last ``RATE_WINDOW`` of the horizon (at least the last record interval), (B,)."""
    T = times.shape[0]
    if T < 2:
        return torch.zeros_like(goal_distance[-1])
    span = float(times[-1] - times[0]) * RATE_WINDOW
    k = int(torch.searchsorted(times, times[-1] - span, right=False).clamp(max=T - 2))
    return (goal_distance[-1] - goal_distance[k]).abs() / float(times[-1] - times[k])


def _where(q: Tensor, dist: Tensor, rate: Tensor, rows: Tensor) -> list[dict]:
    return [
        {"q": q[int(r)].tolist(), "distance": float(dist[int(r)]), "distance_rate": float(rate[int(r)])}
        for r in rows[:SHOWN]
    ]


def _summary(values: Tensor) -> dict:
    if values.numel() == 0:
        return {"min": None, "median": None, "max": None}
    return {"min": float(values.min()), "median": float(values.median()), "max": float(values.max())}


def convergence_outcomes(
    times: Tensor, q_final: Tensor, goal_distance: Tensor, tolerance: float, at_rest_rate: float | None = None
) -> dict:
    """Each rollout's outcome at the horizon ``times[-1]``: ``q_final`` (B, d) the final configurations,
    ``goal_distance`` (T, B) the distance to the goal at the records ``times`` (T,)."""
    horizon = float(times[-1])
    rest = tolerance / horizon if at_rest_rate is None else at_rest_rate
    final = goal_distance[-1]
    rate = _last_rate(times, goal_distance)
    finite = torch.isfinite(final) & torch.isfinite(rate)
    converged = finite & (final <= tolerance)
    at_rest = finite & ~converged & (rate < rest)
    moving = finite & ~converged & ~at_rest
    within = (goal_distance <= tolerance).double()
    reached = within.any(0)
    first = times[within.argmax(0)][reached]
    rest_rows, moving_rows = at_rest.nonzero().flatten(), moving.nonzero().flatten()
    return {
        "horizon_s": horizon,
        "starts": int(final.numel()),
        "converged": int(converged.sum()),
        "at_rest_away": int(at_rest.sum()),
        "still_moving": int(moving.sum()),
        "ended_early": int((~finite).sum()),
        "at_rest_rate": rest,
        "time_to_tolerance": {"starts": int(reached.sum()), **_summary(first)},
        "at_rest_away_distance": _summary(final[rest_rows]),
        "at_rest_away_where": _where(q_final, final, rate, rest_rows),
        "still_moving_where": _where(q_final, final, rate, moving_rows),
    }


def outcomes_line(o: dict, tolerance: float) -> str:
    """The outcomes in one sentence for a run's log."""
    t = o["time_to_tolerance"]
    reach = (
        f"; {t['starts']} came within {tolerance:g} of it (median {t['median']:.3g} s, max {t['max']:.3g} s)"
        if t["starts"]
        else ""
    )
    d = o["at_rest_away_distance"]
    rest = f" ({d['min']:.3g} to {d['max']:.3g} from the goal)" if o["at_rest_away"] else ""
    early = f", {o['ended_early']} ended early" if o["ended_early"] else ""
    return (
        f"over {o['horizon_s']:.4g} s from {o['starts']} starts at rest: {o['converged']} converged, "
        f"{o['at_rest_away']} at rest away from the goal{rest}, {o['still_moving']} still moving{early}{reach}"
    )
