"""Obstacle sets: the obstacles of one shape as batched, masked aux state, so that how many are present may change
from one call to the next (0 … N_max) while the tree, and its compiled code, stay the same.

A set named ``spheres`` of N_max members reaches the caller as one ``(B, N_max, k)`` tensor per field,
``spheres_center`` (k = 3), ``spheres_radius`` (1), …, and ``spheres_mask`` ``(B, N_max)`` (1 or True: present). The
tree is built once with one slot per member: slot i (from 1) reads ``spheres{i}_center``, ``spheres{i}_radius``, …
and ``spheres{i}_present`` (B, 1), which ``ObstacleSet.slots`` makes from the set tensors (column views). Where a
member is absent its fields are replaced by a parked obstacle before anything reads them (whatever the caller left
there, NaN included, never reaches a value or a gradient), and its distance map, masked by ``present``, reports it
absent (``maps/shapes.py``): the member then contributes exactly nothing to the tree (docs/math.md §13).

The fields of each shape are those of a scene's obstacles (``scenes/aux.py``) plus ``velocity`` for a moving set;
every shape has a ``radius``, the size the shared obstacle weights read (a box's smallest half extent, as in a
scene; for a plane, the size the caller wants its weight to see).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping

import torch
from torch import Tensor

from ..registry import TASK_MAPS
from .nearest import NearestSelection, selection_for
from .obstacle_set import SET_SHAPES, ObstacleSet


def every_shape(n_max: int, moving: bool = False) -> list[ObstacleSet]:
    """One set of every shape a controller may meet, each of ``n_max`` members: what a policy allocates up front
    (an exported policy cannot add a shape later)."""
    return [ObstacleSet(shape=s, n_max=n_max, moving=moving) for s in SET_SHAPES]


def sets_read(sets: list[ObstacleSet], n_control_points: int) -> list[ObstacleSet]:
    """The sets a tree's ``n_control_points`` control points read: a shared set once, a per-control-point set once
    per control point (``ObstacleSet.for_control_point``)."""
    out: list[ObstacleSet] = []
    for s in sets:
        own = s.per_control_point or s.nearest is not None
        out += [s.for_control_point(i) for i in range(1, n_control_points + 1)] if own else [s]
    return out


def sets_given(sets: list[ObstacleSet], n_control_points: int) -> list[ObstacleSet]:
    """The sets as a caller passes them to a tree that makes its own slot entries (``SetsSource``, an exported
    program): a ``nearest`` set whole (the tree selects each control point's members), the others as the control
    points read them (``sets_read``)."""
    return [r for s in sets for r in ([s] if s.nearest is not None else sets_read([s], n_control_points))]


def set_dims(sets: list[ObstacleSet]) -> dict[str, int]:
    """Every slot entry of ``sets``: the aux a tree holding them declares."""
    dims: dict[str, int] = {}
    for s in sets:
        dims.update(s.slot_dims())
    if len({s.prefix for s in sets}) != len(sets):
        raise ValueError(f"obstacle sets need distinct names; given {[s.prefix for s in sets]}")
    return dims


def with_slots(sets: list[ObstacleSet], aux: Mapping[str, Tensor], points: Tensor | None = None) -> dict[str, Tensor]:
    """``aux`` with every set's slot entries added: what the tree is called with. A set with ``nearest`` selects
    each control point's members first, from ``points`` (B, C, 3), the control spheres' centres (``Robot.
    sphere_centres``); its selection's own entries (``cp<i>_<prefix>_*``) are added too."""
    out = {**aux}  # not dict(aux): torch.compile traces a literal, not dict.copy
    for s in sets:
        if s.nearest is None:
            out.update(s.slots(aux))
            continue
        if points is None:
            raise ValueError(
                f"obstacle set '{s.prefix}' gives each control point its {s.nearest} nearest members: pass "
                "points=<the control spheres' centres at q, (B, C, 3)>, e.g. Robot.sphere_centres(q)"
            )
        out.update(selection_for(s, points.shape[1]).slots(aux, points))
    return out


class SetsSource:
    """Obstacle sets' slot entries made inside a tree's evaluation (``RMPTree.read_aux_through``, an ``AuxSource``):
    the caller passes each set's tensors and mask (``World.set_aux()``), a handful of tensors, and the per-member
    entries (and a ``nearest`` set's selection) are made where the tree's compiled code makes them too.

    ``sets``: those a tree was built with (``obstacle_sets``), for its ``n_points`` control points. The caller passes
    a per-control-point set once per control point (``sets_read``), a ``nearest`` set whole, selected from
    ``centres(q)`` (B, C, 3), the control spheres' centres (``Robot.sphere_centres``)."""

    def __init__(self, sets: list[ObstacleSet], n_points: int, centres: Callable[[Tensor], Tensor] | None = None):
        if centres is None and any(s.nearest is not None for s in sets):
            raise ValueError(
                "a set with nearest selects each control point's members from the control spheres' centres: pass "
                "centres=<a function of q, e.g. Robot.sphere_centres>"
            )
        self.given = sets_given(sets, n_points)
        self.centres = centres
        self.inputs = {name: shape for s in self.given for name, shape in s.set_dims().items()}
        # made here, once: the compiled evaluation traces their tensor work only (it does not see a cache)
        self.selections = [NearestSelection(s, n_points) for s in self.given if s.nearest is not None]
        self.plain = [s for s in self.given if s.nearest is None]

    def __call__(self, q: Tensor, given: Mapping[str, Tensor]) -> dict[str, Tensor]:
        out: dict[str, Tensor] = {}
        for s in self.plain:
            out.update(s.slots(given))
        if self.selections:
            assert self.centres is not None, "checked when the source was made"
            points = self.centres(q)
            for selection in self.selections:
                out.update(selection.slots(given, points))
        return out


def set_distances(sets: list[ObstacleSet], aux: Mapping[str, Tensor], points: Tensor) -> Tensor:
    """(n, Σ n_max) signed distance from each point (n, 3) to every member of every set, +inf where a member is
    absent: measured by the registered maps a tree holding the sets puts under its control points (``slot_map``),
    so a clearance reported beside a rollout is the distance the tree saw. ``aux`` holds the sets' tensors and
    masks with one row, or one row per point."""
    slots = with_slots(sets, aux)
    n = points.shape[0]
    rows = {k: (v.expand(n, *v.shape[1:]) if v.shape[0] == 1 else v) for k, v in slots.items()}
    dims = {k: v.shape[-1] for k, v in rows.items() if v.dim() == 2}
    cols = []
    for st in sets:
        for i in range(1, st.n_max + 1):
            spec = st.slot_map(i)
            entry = TASK_MAPS.get(spec["type"])
            params = entry.validate({key: v for key, v in spec.items() if key != "type"})
            d = entry.obj(params, 3, dims).to(points.dtype).psi(points, rows)[:, 0]
            present = rows[st.slot_name(i, "present")][:, 0] > 0.5
            cols.append(torch.where(present, d, torch.full_like(d, float("inf"))))
    return torch.stack(cols, -1) if cols else points.new_zeros(n, 0)
