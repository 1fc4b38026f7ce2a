"""Each control point's nearest members of an obstacle set: a tree that evaluates k obstacle edges per control point
however many obstacles the set holds.

A set with ``nearest: k`` (``ObstacleSet.nearest``) reaches the caller as any set does, ``(B, N_max, ·)`` tensors and a
mask, but the tree holds only k slots per control point, ``cp<i>_<prefix>1 … k`` (``ObstacleSet.for_control_point``).
Every call, each control point's slots are filled with the k present members whose surfaces are nearest to its
sphere's centre (``nearest_members``), measured by the shape's registered distance map, the one the tree's edges use.

When this is exact: an obstacle edge contributes nothing, in f, M, V and their gradients, where the distance from the
control sphere's surface to the obstacle is at least the obstacle leaf's support (``r_w`` of the barrier: w = 0, hence
G, M, f, Φ = 0 there, and the weight's ∇w meets only zeros). So whenever every member a control point does not read
lies at least its sphere's radius plus r_w from its centre, the tree equals the tree of all N_max members, in values
and gradients (``selection_exact`` says, per sample, whether that holds). Where it does not, the members left out are
near enough to matter and the policy is an approximation: raise k, or lower N_max by keeping the relevant obstacles.

What Theorem 2 promises: the selection is piecewise constant in q, so between switches the tree is a fixed tree and V_r
does not rise; at a switch of a member that lies beyond the support nothing changes at all; a switch among members
inside it changes the tree, and V_r may jump there (as at any change of the world, docs/math.md §13).
"""

from __future__ import annotations

import functools
from collections.abc import Mapping

import torch
from torch import Tensor

from ..registry import TASK_MAPS
from .aux import PARKED
from .obstacle_set import ObstacleSet


class NearestSelection:
    """Selects, every call, each control point's nearest members of one set (``obstacle_set.nearest`` of them) for a
    robot of ``n_points`` control points. What does not change between calls (each control point's own set, the
    distance map, the entry names) is made once, so a compiled or exported selection traces tensor work only."""

    def __init__(self, obstacle_set: ObstacleSet, n_points: int):
        self.set = obstacle_set
        self.k = obstacle_set.nearest
        self.per_point = [obstacle_set.for_control_point(i) for i in range(1, n_points + 1)] if self.k else []
        self.fields = obstacle_set.fields()
        self.names = {f: f"{obstacle_set.prefix}_{f}" for f in [*self.fields, "mask"]}
        self.rows = {f: obstacle_set.slot_name(1, f) for f in self.fields}  # the map reads any member as slot 1's
        any_member = obstacle_set.slot_map(1)
        spec = {key: v for key, v in any_member.items() if key not in ("type", "present")}
        entry = TASK_MAPS.get(any_member["type"])
        self.measure = entry.obj(entry.validate(spec), 3, {self.rows[f]: k for f, k in self.fields.items()}).double()

    def distances(self, aux: Mapping[str, Tensor], points: Tensor) -> Tensor:
        """(B, C, N_max) signed distance from each point ``points`` (B, C, 3) to every member's surface (the set's
        ``(B, N_max, ·)`` tensors and mask in ``aux``, batch 1 broadcast), +inf where a member is absent: the shape's
        registered map over every (point, member) pair, absent members parked first (what a caller left in their
        fields, NaN included, is never measured)."""
        B, n = points.shape[0], self.set.n_max
        mask = aux[self.names["mask"]]
        present = (mask if mask.dtype == torch.bool else mask > 0.5).expand(B, n)
        rows: dict[str, Tensor] = {}  # (B, 1, N_max, k): broadcast against the points (B, C, 1, 3)
        for f, k in self.fields.items():
            t = aux[self.names[f]].expand(B, n, k)
            rows[self.rows[f]] = torch.where(present[..., None], t, t.new_tensor(PARKED[f]))[:, None]
        d = self.measure.psi(points[:, :, None], rows)[..., 0]
        return torch.where(present[:, None], d, torch.full_like(d, float("inf")))

    def members(self, aux: Mapping[str, Tensor], points: Tensor) -> tuple[dict[str, Tensor], Tensor]:
        """The aux of every control point's own k slots-to-be (``cp<i>_<prefix>_<field>`` (B, k, ·) and ``_mask``
        (B, k)), holding the k present members nearest to point i (nearest first; fewer present leave the last ones
        absent), and (B, C) the distance of the nearest member left out (+inf where none is)."""
        if self.k is None:
            raise ValueError(f"obstacle set '{self.set.prefix}' has no nearest: every control point reads all of it")
        distance = self.distances(aux, points)
        B, C, n = distance.shape
        order = torch.topk(distance, min(self.k + 1, n), dim=-1, largest=False, sorted=True)
        chosen = order.indices[..., : self.k]  # (B, C, k)
        left_out = order.values[..., self.k] if n > self.k else distance.new_full((B, C), float("inf"))
        batch = torch.arange(B, device=points.device)[:, None, None]
        gathered = {f: aux[self.names[f]].expand(B, n, k)[batch, chosen] for f, k in self.fields.items()}
        gathered["mask"] = aux[self.names["mask"]].to(points.dtype).expand(B, n)[batch, chosen]
        out = {f"{own.prefix}_{f}": t[:, i] for i, own in enumerate(self.per_point) for f, t in gathered.items()}
        return out, left_out

    def slots(self, aux: Mapping[str, Tensor], points: Tensor) -> dict[str, Tensor]:
        """The selection's own entries and every control point's slot entries: what the tree reads of this set."""
        chosen, _ = self.members(aux, points)
        out = {**chosen}
        for own in self.per_point:
            out.update(own.slots(chosen))
        return out


@functools.lru_cache(maxsize=64)
def selection_for(obstacle_set: ObstacleSet, n_points: int) -> NearestSelection:
    """The selection of ``obstacle_set`` for ``n_points`` control points, made once (a set is immutable)."""
    return NearestSelection(obstacle_set, n_points)


def nearest_members(obstacle_set: ObstacleSet, aux: Mapping[str, Tensor], points: Tensor) -> tuple[dict, Tensor]:
    """``NearestSelection.members`` of the set for the control points ``points`` (B, C, 3)."""
    return selection_for(obstacle_set, points.shape[1]).members(aux, points)


def member_distances(obstacle_set: ObstacleSet, aux: Mapping[str, Tensor], points: Tensor) -> Tensor:
    """``NearestSelection.distances``: (B, C, N_max) from each point to every member's surface, +inf if absent."""
    return selection_for(obstacle_set, points.shape[1]).distances(aux, points)


def selection_exact(left_out: Tensor, sphere_radii: Tensor, support: float) -> Tensor:
    """(B,) whether each sample's selection equals the whole set: every member left out (``left_out`` (B, C), from
    ``nearest_members``) lies at least the control sphere's radius (``sphere_radii`` (C,)) plus the obstacle leaf's
    ``support`` (its r_w) from the control point, where its edge would contribute exactly nothing."""
    return (left_out - sphere_radii.to(left_out) >= support).all(-1)
