"""One obstacle set's declaration (``ObstacleSet``): its shape, how many members the tree allocates, how control
points read it, and the names and maps of its aux entries and slots. What a tree does with sets is ``sets.py``;
each control point's nearest members, ``nearest.py``: both read this declaration."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, Literal

import torch
from pydantic import Field, model_validator
from torch import Tensor

from ..registry import Params
from .aux import PARKED, SHAPE_AUX

#: every shape a controller may meet; a policy allocates a set of each it will meet before it is compiled or exported
SET_SHAPES = ("sphere", "box", "cylinder", "capsule", "plane")
#: the fields of each shape's members beyond centre and radius (name -> dimension)
SET_FIELDS: dict[str, dict[str, int]] = {**SHAPE_AUX, "plane": {"normal": 3}}
#: the distance map measuring each shape's members
SET_MAPS = {
    "sphere": "sphere_obstacle",
    "box": "box_obstacle",
    "cylinder": "cylinder_obstacle",
    "capsule": "capsule_obstacle",
    "plane": "plane_obstacle",
}
#: map parameter reading each field (a box's radius is read by the weights only)
_MAP_KEYS = {
    "center": "center",
    "radius": "radius",
    "velocity": "velocity",
    "half_extents": "half_extents",
    "rotation": "rotation",
    "axis": "axis",
    "half_height": "half_height",
    "half_length": "half_length",
    "normal": "normal",
}


class ObstacleSet(Params):
    """Up to ``n_max`` obstacles of one shape, present or absent call by call."""

    shape: Literal["sphere", "box", "cylinder", "capsule", "plane"]
    n_max: int = Field(ge=1, le=4096, description="how many members the tree allocates")
    moving: bool = Field(False, description="members carry a velocity (3) as well")
    name: str | None = Field(
        None,
        pattern=r"^[A-Za-z_][A-Za-z0-9_]*[A-Za-z_]$",
        description="prefix of its aux entries; default: the shape's plural, e.g. 'spheres'",
    )
    per_control_point: bool = Field(
        False,
        description="every control point reads n_max members of its own (aux prefix cp<i>_<prefix>: e.g. the k "
        "nearest points of a cloud, scenes/clouds.py::nearest_per_point) instead of one set all of them share",
    )
    nearest: int | None = Field(
        None,
        ge=1,
        description="every control point reads only this many members of the set, those nearest to it, selected "
        "every call (scenes/nearest.py): k edges per control point however large n_max; exact while the others lie "
        "beyond the obstacle leaf's support",
    )

    @model_validator(mode="after")
    def _one_way_to_read(self):
        if self.nearest is not None and self.per_control_point:
            raise ValueError(
                "nearest selects each control point's members from one shared set; per_control_point gives every "
                "control point a set of its own: choose one"
            )
        if self.nearest is not None and self.nearest >= self.n_max:
            raise ValueError(
                f"nearest ({self.nearest}) must be < n_max ({self.n_max}): with nearest >= n_max every control point "
                "reads every member anyway; leave nearest out"
            )
        return self

    @property
    def prefix(self) -> str:
        return self.name or ("boxes" if self.shape == "box" else f"{self.shape}s")

    def for_control_point(self, i: int) -> ObstacleSet:
        """The set control point ``i`` (from 1) reads: this one, or its own copy ``cp<i>_<prefix>`` when every
        control point has members of its own (``per_control_point``) or its own ``nearest`` of this set's."""
        if self.nearest is not None:
            return self.model_copy(update={"name": f"cp{i}_{self.prefix}", "n_max": self.nearest, "nearest": None})
        if not self.per_control_point:
            return self
        return self.model_copy(update={"name": f"cp{i}_{self.prefix}", "per_control_point": False})

    def fields(self) -> dict[str, int]:
        """Field name -> dimension k of the member's ``(B, N_max, k)`` tensor."""
        out = {"center": 3, "radius": 1, **SET_FIELDS[self.shape]}
        if self.moving:
            out["velocity"] = 3
        return out

    def set_dims(self) -> dict[str, tuple[int, ...]]:
        """Aux name -> per-sample shape of what the caller passes: ``(N_max, k)`` per field, ``(N_max,)`` the mask."""
        dims: dict[str, tuple[int, ...]] = {f"{self.prefix}_{f}": (self.n_max, k) for f, k in self.fields().items()}
        dims[f"{self.prefix}_mask"] = (self.n_max,)
        return dims

    def slot_name(self, i: int, field: str) -> str:
        """The aux entry slot ``i`` (from 1) reads for ``field`` (or ``present``)."""
        return f"{self.prefix}{i}_{field}"

    def slot_dims(self) -> dict[str, int]:
        """Aux name -> dimension of every slot's entries: what a tree holding this set declares."""
        dims = {}
        for i in range(1, self.n_max + 1):
            dims.update({self.slot_name(i, f): k for f, k in self.fields().items()})
            dims[self.slot_name(i, "present")] = 1
        return dims

    def slot_map(self, i: int) -> dict[str, Any]:
        """The tree-spec map measuring slot ``i``'s member from a control point (3-D), masked by its presence."""
        spec: dict[str, Any] = {"type": SET_MAPS[self.shape], "present": self.slot_name(i, "present")}
        for f in self.fields():
            if f == "radius" and self.shape in ("box", "plane"):
                continue  # read by the weights only
            spec[_MAP_KEYS[f]] = self.slot_name(i, f)
        return spec

    def weight_bind(self, i: int) -> dict[str, str]:
        """How a control point's shared obstacle weight (reading ``obstacle_center``, ``obstacle_radius``) reads
        slot ``i``'s member."""
        return {"obstacle_center": self.slot_name(i, "center"), "obstacle_radius": self.slot_name(i, "radius")}

    def slots(self, aux: Mapping[str, Tensor]) -> dict[str, Tensor]:
        """The slot entries of this set from its ``(B, N_max, k)`` tensors and mask: absent members parked first."""
        if self.per_control_point:
            raise ValueError(
                f"obstacle set '{self.prefix}' has members per control point: make the slots of each control point's "
                f"own set, sets_read(sets, number of control points)"
            )
        if self.nearest is not None:
            raise ValueError(
                f"obstacle set '{self.prefix}' gives each control point its {self.nearest} nearest members: make its "
                "slots with with_slots(sets, aux, points=<the control spheres' centres, (B, C, 3)>)"
            )
        if f"{self.prefix}_mask" not in aux:
            raise KeyError(
                f"obstacle set '{self.prefix}' needs aux '{self.prefix}_mask' of shape (B, {self.n_max}): "
                f"1 where a member is present, 0 where absent"
            )
        mask = aux[f"{self.prefix}_mask"]
        self._check(f"{self.prefix}_mask", mask, (self.n_max,))
        present = mask if mask.dtype == torch.bool else mask > 0.5
        out: dict[str, Tensor] = {}
        dtype = None
        for f, k in self.fields().items():
            name = f"{self.prefix}_{f}"
            if name not in aux:
                raise KeyError(f"obstacle set '{self.prefix}' needs aux '{name}' of shape (B, {self.n_max}, {k})")
            t = aux[name]
            self._check(name, t, (self.n_max, k))
            dtype = t.dtype
            safe = torch.where(present.unsqueeze(-1), t, t.new_tensor(PARKED[f]))
            for i, member in enumerate(safe.unbind(1), start=1):  # one call for every member's view
                out[self.slot_name(i, f)] = member
        for i, on in enumerate(present.to(dtype).split(1, dim=1), start=1):
            out[self.slot_name(i, "present")] = on
        return out

    def _check(self, name: str, t: Tensor, shape: tuple[int, ...]) -> None:
        if t.dim() != len(shape) + 1 or tuple(t.shape[1:]) != shape:
            raise ValueError(
                f"aux '{name}' must be (B, {', '.join(map(str, shape))}) for obstacle set "
                f"'{self.prefix}' (n_max = {self.n_max}); got {tuple(t.shape)}"
            )
