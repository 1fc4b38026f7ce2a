"""A world that changes between controller calls: obstacles added, moved, resized and removed, and the goal set,
within the obstacle sets a tree (or an exported policy) was built with, so nothing is rebuilt or recompiled.

The world holds each set's ``(B, N_max, k)`` field tensors and ``(B, N_max)`` mask (``scenes/sets.py``) and hands a
controller its aux state (``aux()``): the goal, the set tensors and the slot entries the tree reads. Adding an
obstacle takes the set's first free slot; removing one clears its mask bit (its fields are parked by the sets, never
read). A set that is full is an error naming the set and its ``n_max``: the tree cannot grow at run time, so the
fix is a larger ``n_max`` when the tree is built.

An obstacle that appears inside the arm is measured like any other: its distance map clamps the distance at its
floor (``maps/shapes.py``), so the barrier pushes out as hard as it can and nothing becomes NaN (docs/math.md §13).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import torch
from torch import Tensor

from .aux import PARKED
from .clouds import cloud_members, member_velocities
from .obstacle_set import ObstacleSet
from .sets import with_slots

#: the fields that give an obstacle its size (``resize``), the others are its pose (``move``)
SIZE_FIELDS = ("radius", "half_extents", "half_height", "half_length")


class WorldError(ValueError):
    """A change the world cannot make: the message names the obstacle or set, and what is allowed."""


class World:
    """The run-time world of a controller: a goal and the members of its obstacle sets, for a batch of ``batch``."""

    def __init__(
        self,
        sets: Sequence[ObstacleSet],
        goal: Sequence[float] | Tensor = (0.0, 0.0, 0.0),
        batch: int = 1,
        dtype: torch.dtype = torch.float64,
    ):
        self.sets = {s.prefix: s for s in sets}
        if len(self.sets) != len(sets):
            raise WorldError(f"obstacle sets need distinct names; given {[s.prefix for s in sets]}")
        self.batch, self.dtype = batch, dtype
        self.tensors: dict[str, Tensor] = {}
        for s in sets:
            for f, k in s.fields().items():
                self.tensors[f"{s.prefix}_{f}"] = torch.tensor(PARKED[f], dtype=dtype).expand(batch, s.n_max, k).clone()
            self.tensors[f"{s.prefix}_mask"] = torch.zeros(batch, s.n_max, dtype=dtype)
        self.goal = self._row(goal, 3, "goal")
        self.where: dict[str, tuple[str, int]] = {}  # obstacle id -> (set prefix, member index from 0)

    # ------------------------------------------------------------------ changes
    def add(self, shape: str, *, name: str | None = None, set: str | None = None, **fields) -> str:
        """Add an obstacle of ``shape`` with its fields (``center``, ``radius``, …) in the first free member of its
        set (the one named ``set``, else the only set of that shape); returns its id (``name`` or ``<set><n>``)."""
        s = self._set_for(shape, set)
        mask = self.tensors[f"{s.prefix}_mask"]
        free = (mask[0] == 0).nonzero().flatten()
        if free.numel() == 0:
            raise WorldError(
                f"obstacle set '{s.prefix}' is full: all {s.n_max} members are present; remove one, or "
                f"build the tree with a larger n_max for this set"
            )
        slot = int(free[0])
        oid = name or f"{s.prefix}{slot + 1}"
        if oid in self.where:
            raise WorldError(
                f"an obstacle named '{oid}' is already in the world; remove it first or choose another name"
            )
        missing = [f for f in s.fields() if f not in fields and f not in ("velocity", "rotation", "radius")]
        if missing:
            raise WorldError(f"adding a {shape} needs {', '.join(missing)} (its fields: {', '.join(s.fields())})")
        values = {"radius": self._default_radius(s.shape, fields), **fields}
        self._write(s, slot, values)
        mask[:, slot] = 1.0
        self.where[oid] = (s.prefix, slot)
        return oid

    def move(self, oid: str, **pose) -> None:
        """Move obstacle ``oid``: any of its pose fields (``center``, ``velocity``, ``rotation``, ``axis``, ``normal``)."""
        s, slot = self._find(oid)
        sizes = [f for f in pose if f in SIZE_FIELDS]
        if sizes:
            raise WorldError(
                f"move changes an obstacle's pose; {', '.join(sizes)} is its size: use resize('{oid}', ...)"
            )
        self._write(s, slot, pose)

    def resize(self, oid: str, **size) -> None:
        """Resize obstacle ``oid``: any of its size fields (``radius``, ``half_extents``, ``half_height``,
        ``half_length``); a box's radius (what the weights see) follows its smallest half extent."""
        s, slot = self._find(oid)
        pose = [f for f in size if f not in SIZE_FIELDS]
        if pose:
            raise WorldError(
                f"resize changes an obstacle's size; {', '.join(pose)} is its pose: use move('{oid}', ...)"
            )
        if s.shape == "box" and "half_extents" in size and "radius" not in size:
            size = {**size, "radius": min(float(v) for v in size["half_extents"])}
        self._write(s, slot, size)

    def remove(self, oid: str) -> None:
        """Remove obstacle ``oid``: its member becomes absent (and free for the next ``add``)."""
        s, slot = self._find(oid)
        self.tensors[f"{s.prefix}_mask"][:, slot] = 0.0
        del self.where[oid]

    def set_goal(self, goal: Sequence[float] | Tensor) -> None:
        self.goal = self._row(goal, 3, "goal")

    def set_cloud(
        self,
        set_name: str,
        points: Tensor,
        voxel: float,
        radius: float,
        near: Tensor | None = None,
        since: float | None = None,
        max_speed: float = 2.0,
    ) -> int:
        """Fill the sphere set ``set_name`` with a point cloud (P, 3) in world coordinates, replacing whatever it
        held: one sphere of ``radius`` per occupied cube of side ``voxel``, the nearest to ``near`` kept when they are
        more than the set's members (``scenes/clouds.py``). The set then belongs to the cloud (its members have no
        ids to move or remove one by one). In a moving set, ``since`` (the seconds since the previous cloud) gives
        the members velocities from their displacement since that cloud (``member_velocities``; none beyond
        ``max_speed`` m/s); without it they are at rest. Returns how many members the cloud filled."""
        if set_name not in self.sets:
            raise WorldError(f"no obstacle set '{set_name}'; sets: {', '.join(self.sets) or 'none'}")
        s = self.sets[set_name]
        if s.shape != "sphere":
            raise WorldError(f"a point cloud fills a set of spheres; '{set_name}' holds {s.shape}s")
        if not radius > 0:
            raise WorldError(f"a cloud's spheres need a radius > 0 (m); given {radius}")
        if any(prefix == set_name for prefix, _ in self.where.values()):
            raise WorldError(
                f"obstacle set '{set_name}' holds obstacles added one by one "
                f"({', '.join(o for o, (p, _) in self.where.items() if p == set_name)}); a cloud needs a "
                "set of its own"
            )
        if since is not None and "velocity" not in s.fields():
            raise WorldError(
                f"obstacle set '{set_name}' is not moving: its members have no velocity to estimate from the "
                "previous cloud; build it with moving: true, or leave out since"
            )
        centres, mask = cloud_members(torch.as_tensor(points, dtype=self.dtype), voxel, s.n_max, near)
        if "velocity" in s.fields():
            previous, previous_mask = self.tensors[f"{set_name}_center"][0], self.tensors[f"{set_name}_mask"][0]
            self.tensors[f"{set_name}_velocity"][:] = (
                member_velocities(centres, mask, previous, previous_mask, since, max_speed)
                if since is not None
                else 0.0
            )
        self.tensors[f"{set_name}_center"][:] = centres
        self.tensors[f"{set_name}_radius"][:] = radius
        self.tensors[f"{set_name}_mask"][:] = mask
        return int(mask.sum())

    # ------------------------------------------------------------------ what a controller reads
    def present(self) -> list[str]:
        """The ids of the obstacles in the world."""
        return list(self.where)

    def set_aux(self) -> dict[str, Tensor]:
        """The goal and every set's tensors and mask: what an exported policy takes as inputs."""
        return {"goal": self.goal, **self.tensors}

    def aux(self, points: Tensor | None = None) -> dict[str, Tensor]:
        """The aux state a tree built with these sets is called with (the set tensors and their slot entries). A set
        with ``nearest`` needs ``points``, the control spheres' centres at the state the tree is called at (B, C, 3)."""
        return with_slots(list(self.sets.values()), self.set_aux(), points)

    # ------------------------------------------------------------------ internals
    def _set_for(self, shape: str, name: str | None) -> ObstacleSet:
        if name is not None:
            if name not in self.sets:
                raise WorldError(f"no obstacle set '{name}'; sets: {', '.join(self.sets) or 'none'}")
            s = self.sets[name]
            if s.shape != shape:
                raise WorldError(f"obstacle set '{name}' holds {s.shape}s, not {shape}s")
            return s
        of_shape = [s for s in self.sets.values() if s.shape == shape]
        if not of_shape:
            held = sorted({s.shape for s in self.sets.values()})
            raise WorldError(
                f"no obstacle set holds {shape}s (the tree was built with sets of {', '.join(held) or 'no'} "
                f"shape); a policy can meet only the shapes allocated before it was built"
            )
        if len(of_shape) > 1:
            raise WorldError(
                f"several sets hold {shape}s ({', '.join(s.prefix for s in of_shape)}); say which with set="
            )
        return of_shape[0]

    def _find(self, oid: str) -> tuple[ObstacleSet, int]:
        if oid not in self.where:
            raise WorldError(f"no obstacle '{oid}' in the world; present: {', '.join(self.where) or 'none'}")
        prefix, slot = self.where[oid]
        return self.sets[prefix], slot

    @staticmethod
    def _default_radius(shape: str, fields: Mapping) -> float:
        if "radius" in fields:
            return fields["radius"]
        if shape == "box":
            return min(float(v) for v in fields["half_extents"])
        if shape == "plane":
            return 1.0  # the size a plane's weight sees: give radius= to choose another
        raise WorldError(f"adding a {shape} needs radius")

    def _write(self, s: ObstacleSet, slot: int, values: Mapping) -> None:
        fields = s.fields()
        for f, v in values.items():
            if f not in fields:
                raise WorldError(f"a {s.shape} in set '{s.prefix}' has no field '{f}'; its fields: {', '.join(fields)}")
            self.tensors[f"{s.prefix}_{f}"][:, slot] = self._row(v, fields[f], f"{s.prefix}.{f}")

    def _row(self, v, k: int, what: str) -> Tensor:
        t = torch.as_tensor(v, dtype=self.dtype)
        t = t.reshape(-1) if t.dim() <= 1 else t
        if t.shape[-1] != k or not bool(torch.isfinite(t).all()):
            raise WorldError(f"{what} must be {k} finite number(s); given {v!r}")
        return t.expand(self.batch, k).clone() if t.dim() == 1 else t
