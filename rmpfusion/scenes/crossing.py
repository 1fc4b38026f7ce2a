"""Is the obstacle in the way? The one definition of a reach that "crosses" an obstacle.

A reach from a start to a goal crosses an obstacle when the straight end-effector segment from the start's end
effector to the goal passes within ``radius`` of the obstacle's surface, ``radius`` being the end effector's control
sphere: a sphere of that size moved along the straight line would touch the obstacle, so the policy cannot take the
straight path. For a standing cylinder this is the segment coming within (cylinder radius + r) of its axis inside its
height (within r of its caps above and below). The measure is the segment's clearance, the least signed distance
(negative inside) from a point of the segment to the obstacle's surface, with the distance maps the scene's own
shapes use (``scenes/distance.py``: sphere, box, finite cylinder, capsule), so every shape is measured by one rule.

Every shape is convex, so the signed distance along a segment is convex in the segment's parameter and one
ternary search finds its least value. A moving obstacle is measured where it is at t = 0; the ground plane is not an
obstacle a reach crosses.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import torch
from torch import Tensor

from .distance import distances
from .spec import Scene

#: ternary-search rounds: each keeps 2/3 of the interval, so 60 rounds resolve a 2 m segment to 1e-10 m
_ROUNDS = 60


def segment_clearance(scene: Scene, aux: Mapping[str, Tensor], start: Tensor, end: Tensor) -> Tensor:
    """(B, K) least signed distance from the segment start[b] → end[b] (B, 3) to obstacle k's surface (negative: the
    segment enters it), for the scene's K obstacles at their aux state (rows: one per segment)."""
    cols = [_one_obstacle(scene, aux, start, end, k) for k in range(len(scene.obstacles))]
    return torch.stack(cols, -1) if cols else start.new_zeros(start.shape[0], 0)


def _one_obstacle(scene: Scene, aux: Mapping[str, Tensor], start: Tensor, end: Tensor, k: int) -> Tensor:
    """(B,) the least distance to obstacle ``k`` (from 0) along each segment, by ternary search on its parameter."""

    def at(t: Tensor) -> Tensor:
        return distances(scene, aux, start + t[:, None] * (end - start))[:, k]

    lo, hi = start.new_zeros(start.shape[0]), start.new_ones(start.shape[0])
    for _ in range(_ROUNDS):
        a, b = lo + (hi - lo) / 3, hi - (hi - lo) / 3
        left = at(a) <= at(b)  # the minimum lies in [lo, b] when d(a) ≤ d(b) (convexity), else in [a, hi]
        hi = torch.where(left, b, hi)
        lo = torch.where(left, lo, a)
    ends = torch.stack([at(torch.zeros_like(lo)), at(torch.ones_like(lo)), at((lo + hi) / 2)], -1)
    return ends.min(-1).values


def crosses(clearance: Tensor, radius: float) -> Tensor:
    """(B,) bool: the path crosses some obstacle, i.e. its segment clearance (B, K) from some obstacle's surface is
    below ``radius`` (the end effector's control sphere)."""
    if clearance.shape[-1] == 0:
        return torch.zeros(clearance.shape[0], dtype=torch.bool)
    return (clearance < radius).any(-1)


@dataclass(frozen=True)
class CrossingSummary:
    """How many of a set of reaches cross an obstacle, and how far their straight paths pass from it."""

    paths: int
    crossing_fraction: float
    radius: float
    clearance_quantiles: dict[str, float]  # of each path's least clearance over the obstacles (m)

    def as_dict(self) -> dict:
        return {
            "paths": self.paths,
            "crossing_fraction": self.crossing_fraction,
            "radius": self.radius,
            "clearance_quantiles": dict(self.clearance_quantiles),
        }


QUANTILES = {"min": 0.0, "q10": 0.1, "q25": 0.25, "median": 0.5, "q75": 0.75, "q90": 0.9, "max": 1.0}


def summarize(clearance: Tensor, radius: float) -> CrossingSummary:
    """The crossing fraction and the clearance distribution of paths with segment clearances ``clearance`` (B, K)."""
    n = clearance.shape[0]
    if clearance.shape[-1] == 0 or n == 0:
        return CrossingSummary(n, 0.0, radius, {})
    least = clearance.min(-1).values.double()
    qs = torch.quantile(least, torch.tensor(list(QUANTILES.values()), dtype=torch.float64))
    return CrossingSummary(
        n, float(crosses(clearance, radius).double().mean()), radius, {name: float(v) for name, v in zip(QUANTILES, qs)}
    )
