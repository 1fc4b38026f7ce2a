"""Point clouds as obstacles: the points a depth camera sees, reduced to at most N_max spheres of one radius that
fill a sphere obstacle set (``scenes/sets.py``), so a tree built once takes a new cloud every call.

The reduction, stated: the points are binned on a grid of cubes of side ``voxel`` (from the world origin), each
occupied cube becomes one member at the centroid of its points, with ``radius`` (choose it ≥ half the cube's
diagonal, √3/2·voxel, and the sensor's noise, so the spheres cover the surface the points sample). Where more cubes
are occupied than the set has members, the members kept are the cubes nearest to ``near`` (e.g. the control
spheres' centres: what can be hit first), ties broken by the cube's index, so the choice is deterministic.

Or, per control point (``ObstacleSet.per_control_point``): every control point's own members are the ``k`` points of
the cloud nearest to its centre (``nearest_per_point``); no binning, so a small ``k`` serves a dense cloud.

Velocities from successive clouds (optional, for a set with ``moving: true``): a cloud has no point identities, so
each member's velocity is its displacement from the nearest member of the previous cloud over the time between the
two (``member_velocities``), taken as zero where that nearest member is farther than ``max_speed`` times the interval
(a surface that came into view, not one that moved). The estimate is a first-order one: a surface sliding along
itself shows no displacement (the aperture problem), and the binning adds up to a cube's side of noise per frame.

What Theorem 2 promises: between two clouds the members are fixed aux state and V_r does not rise. When a new
cloud replaces the members (or the kept cubes switch as the arm moves), the aux state jumps, and V_r may jump with
it, as at any change of the world (docs/math.md §13).
"""

from __future__ import annotations

import torch
from torch import Tensor

from .obstacle_set import ObstacleSet


def voxel_centroids(points: Tensor, voxel: float) -> Tensor:
    """(M, 3) centroids of the occupied cubes of side ``voxel`` (cube index order) of ``points`` (P, 3); the
    non-finite points (a depth camera's missing returns) are dropped first."""
    if voxel <= 0:
        raise ValueError(f"voxel must be > 0 (the side of the cubes the points are binned in, m); given {voxel}")
    points = points[torch.isfinite(points).all(-1)]
    if points.shape[0] == 0:
        return points.new_zeros(0, 3)
    cells = torch.floor(points / voxel).to(torch.long)
    keys, inverse = torch.unique(cells, dim=0, return_inverse=True)
    sums = points.new_zeros(keys.shape[0], 3).index_add_(0, inverse, points)
    counts = torch.zeros(keys.shape[0], dtype=points.dtype).index_add_(0, inverse, torch.ones_like(points[:, 0]))
    return sums / counts[:, None]


def keep_nearest(centres: Tensor, n_max: int, near: Tensor | None) -> Tensor:
    """At most ``n_max`` of ``centres`` (M, 3): all if they fit, else the ``n_max`` nearest to any row of ``near``
    (K, 3) (without ``near``: the first ``n_max`` in cube order)."""
    if centres.shape[0] <= n_max:
        return centres
    if near is None:
        return centres[:n_max]
    distance = torch.cdist(centres, near.to(centres)).min(-1).values
    order = torch.sort(distance, stable=True).indices  # stable: ties keep cube order
    return centres[order[:n_max]]


def cloud_members(points: Tensor, voxel: float, n_max: int, near: Tensor | None = None) -> tuple[Tensor, Tensor]:
    """The sphere members (n_max, 3) and their mask (n_max,) of a cloud: voxel centroids, the nearest kept."""
    kept = keep_nearest(voxel_centroids(points, voxel), n_max, near)
    centres = points.new_zeros(n_max, 3)
    mask = points.new_zeros(n_max)
    centres[: kept.shape[0]] = kept
    mask[: kept.shape[0]] = 1.0
    return centres, mask


def nearest_per_point(points: Tensor, centres: Tensor, k: int) -> tuple[Tensor, Tensor]:
    """For every centre (C, 3), the ``k`` points of the cloud (P, 3) nearest to it, nearest first, as members
    (C, k, 3) and their mask (C, k): fewer than ``k`` finite points leave the last members absent. Non-finite points
    (missing returns) are dropped first. A partial selection (``torch.topk``), not a sort of the whole cloud: where
    two points tie at the k-th distance, which one is kept is topk's (deterministic) choice."""
    if k < 1:
        raise ValueError(f"k must be ≥ 1 (the members each control point reads); given {k}")
    points = points[torch.isfinite(points).all(-1)]
    C, found = centres.shape[0], min(k, points.shape[0])
    members = points.new_zeros(C, k, 3)
    mask = points.new_zeros(C, k)
    if found:
        distance = torch.cdist(centres.to(points), points)
        order = torch.topk(distance, found, dim=-1, largest=False, sorted=True).indices
        members[:, :found] = points[order]
        mask[:, :found] = 1.0
    return members, mask


def per_point_aux(obstacle_set: ObstacleSet, members: Tensor, mask: Tensor, radius: float) -> dict[str, Tensor]:
    """The aux of a per-control-point sphere set for one sample: control point i's members ``members[i - 1]``
    (C, k, 3) with ``radius``, as ``cp<i>_<prefix>_center`` (1, k, 3), ``_radius`` (1, k, 1) and ``_mask`` (1, k)."""
    if not obstacle_set.per_control_point or obstacle_set.shape != "sphere":
        raise ValueError(f"set '{obstacle_set.prefix}' must be a sphere set with per_control_point: true")
    out = {}
    for i in range(1, members.shape[0] + 1):
        p = obstacle_set.for_control_point(i).prefix
        out[f"{p}_center"] = members[i - 1].unsqueeze(0)
        out[f"{p}_radius"] = members.new_full((1, members.shape[1], 1), radius)
        out[f"{p}_mask"] = mask[i - 1].unsqueeze(0)
    return out


def member_velocities(
    centres: Tensor, mask: Tensor, previous: Tensor, previous_mask: Tensor, interval: float, max_speed: float
) -> Tensor:
    """(…, n, 3) velocities of the members ``centres`` (…, n, 3) (present where ``mask`` (…, n) is 1) from the
    members of the previous cloud, ``previous`` (…, m, 3) with ``previous_mask`` (…, m), taken ``interval`` seconds
    earlier: each member's displacement from the nearest previous member over ``interval``; zero for an absent
    member, where no previous member is present, and where the nearest is farther than ``max_speed · interval``."""
    if not interval > 0:
        raise ValueError(f"the interval between two clouds must be > 0 (s); given {interval}")
    if not max_speed > 0:
        raise ValueError(f"max_speed must be > 0 (m/s: the fastest an obstacle is taken to move); given {max_speed}")
    gap = torch.cdist(centres, previous.to(centres))
    gap = torch.where(previous_mask[..., None, :] > 0, gap, torch.full_like(gap, float("inf")))
    distance, nearest = gap.min(-1)
    matched = torch.gather(previous.to(centres), -2, nearest[..., None].expand(*nearest.shape, 3))
    keep = (mask > 0) & (distance <= max_speed * interval)
    return torch.where(keep[..., None], (centres - matched) / interval, torch.zeros_like(centres))
