"""Distance task maps to obstacles: 1-D coordinates for barrier RMPs. Each stacks (``core/stacking.py``): one
group evaluates the distances of many (point, obstacle) pairs at once, each reading its own obstacle's aux."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import torch
from pydantic import Field, field_validator
from torch import Tensor

from ..core.algebra import matvec
from ..core.auxstate import CONSTANT_DTYPE, AuxOrValue, AuxParam, constant
from ..core.taskmap import TaskMap
from ..examples import AuxInput, Example
from ..registry import TASK_MAPS, Params, numbers_repr


def _radial(d: Tensor, dd: Tensor) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """For r = |d|: (r, u = ∂r/∂d, ṙ = u·ḋ, d²r[ḋ, ḋ]) with d the (projected) offset and ḋ its velocity."""
    r = torch.linalg.vector_norm(d, dim=-1, keepdim=True)
    u = d / r
    ud = (u * dd).sum(-1, keepdim=True)
    c = ((dd * dd).sum(-1, keepdim=True) - ud * ud) / r
    return r, u, ud, c


def _values(v: Any) -> list[float] | None:
    """The numbers of a constant parameter (a number or a list of them); None for an aux name."""
    if isinstance(v, str):
        return None
    return [float(x) for x in v] if isinstance(v, Sequence) else [float(v)]


def _positive_radius(v: AuxOrValue, shape: str) -> AuxOrValue:
    vals = _values(v)
    if vals is not None and not all(x > 0 for x in vals):
        raise ValueError(
            f"radius must be > 0 (a {shape} of radius ≤ 0 has no surface to keep a distance from) or "
            f"the name of an aux entry; given {v!r}"
        )
    return v


@TASK_MAPS.register(
    "sphere_distance",
    examples=[
        Example({"center": [0.3, -0.2], "radius": 1.5}, 2, scale=3.0),
        Example(
            {"center": "c", "radius": "r", "normalized": True},
            2,
            scale=3.0,
            aux={"c": AuxInput.normal(2), "r": AuxInput.radius()},
        ),
    ],
)
class SphereDistance(TaskMap):
    """Distance to a sphere (circle in 2D): ``|y−c| − R``, or ``|y−c|/R − 1`` when ``normalized``."""

    stack_fields = ("center", "radius")

    class Params(Params):
        center: AuxOrValue
        radius: AuxOrValue = Field(1.0, description="> 0, or the name of an aux entry")
        normalized: bool = False

        @field_validator("radius")
        @classmethod
        def _radius(cls, v: AuxOrValue) -> AuxOrValue:
            return _positive_radius(v, "sphere")

    def __init__(self, params: Params, in_dim: int, aux_dims: Mapping[str, int] | None = None):
        super().__init__(in_dim, aux_dims)
        self.center = AuxParam(params.center, self.aux_dims, "sphere_distance.center")
        self.radius = AuxParam(params.radius, self.aux_dims, "sphere_distance.radius")
        if self.center.dim != in_dim:
            raise ValueError(f"sphere_distance.center has dimension {self.center.dim}, parent space has {in_dim}")
        if self.radius.dim != 1:
            raise ValueError(f"sphere_distance.radius must be a scalar, got dimension {self.radius.dim}")
        self.normalized = params.normalized
        self.out_dim = 1

    def stack_settings(self) -> tuple:
        return (self.normalized,)

    def psi(self, x, aux):
        r = (x - self.center(aux)).norm(dim=-1, keepdim=True)
        R = self.radius(aux)
        return r / R - 1.0 if self.normalized else r - R

    def forward(self, x, xd, aux=None):
        R = self.radius(aux)
        r, u, ud, c = _radial(x - self.center(aux), xd)
        if self.normalized:  # y = r/R − 1: every derivative of r over R
            return r / R - 1.0, ud / R, (u / R).unsqueeze(-2), c / R
        return r - R, ud, u.unsqueeze(-2), c

    def extra_repr(self) -> str:
        return numbers_repr({"in_dim": self.in_dim, "out_dim": self.out_dim, "normalized": self.normalized})


@TASK_MAPS.register(
    "cylinder_distance",
    examples=[Example({"center": [0.1, 0.2, 0.0], "radius": 0.3, "axis": [0.0, 0.3, 1.0]}, 3, scale=3.0)],
)
class CylinderDistance(TaskMap):
    """Distance to an infinite cylinder with a given axis through ``center``: ``|P(y−c)| − R``."""

    stack_fields = ("center", "radius", "P")
    P: Tensor  # buffer: I − aaᵀ, the projection across the unit axis a

    class Params(Params):
        center: AuxOrValue
        radius: AuxOrValue = Field(1.0, description="> 0, or the name of an aux entry")
        axis: Sequence[float] = Field((0.0, 0.0, 1.0), description="the cylinder's direction: any non-zero vector")

        @field_validator("radius")
        @classmethod
        def _radius(cls, v: AuxOrValue) -> AuxOrValue:
            return _positive_radius(v, "cylinder")

        @field_validator("axis")
        @classmethod
        def _axis(cls, v: Sequence[float]) -> Sequence[float]:
            if not any(float(a) != 0.0 for a in v):
                raise ValueError(
                    f"axis must be a non-zero vector (it is the direction the cylinder extends in); given {list(v)}"
                )
            return v

    def __init__(self, params: Params, in_dim: int, aux_dims: Mapping[str, int] | None = None):
        super().__init__(in_dim, aux_dims)
        self.center = AuxParam(params.center, self.aux_dims, "cylinder_distance.center")
        self.radius = AuxParam(params.radius, self.aux_dims, "cylinder_distance.radius")
        a = constant(list(params.axis))
        if a.numel() != in_dim or self.center.dim != in_dim:
            raise ValueError(f"cylinder_distance.axis and center need dimension {in_dim}")
        if float(a.norm()) == 0.0:
            raise ValueError("cylinder_distance.axis must be non-zero")
        a = a / a.norm()
        self.register_buffer("P", torch.eye(in_dim, dtype=CONSTANT_DTYPE) - torch.outer(a, a))
        self.out_dim = 1

    def psi(self, x, aux):
        return matvec(self.P, x - self.center(aux)).norm(dim=-1, keepdim=True) - self.radius(aux)

    def forward(self, x, xd, aux=None):
        P = self.P  # symmetric: P v = vᵀ P
        r, u, ud, c = _radial(matvec(P, x - self.center(aux)), matvec(P, xd))
        j = matvec(P, u)  # chain through the projection: j·ẋ = u·Pẋ = ṙ
        return r - self.radius(aux), ud, j.unsqueeze(-2), c

    def extra_repr(self) -> str:
        return numbers_repr({"in_dim": self.in_dim, "out_dim": self.out_dim, "projection": self.P})


@TASK_MAPS.register(
    "box_distance", examples=[Example({"center": [0.0, 0.0, 0.0], "half_extents": [0.5, 1.0, 0.25]}, 3, scale=3.0)]
)
class BoxDistance(TaskMap):
    """Signed distance to an axis-aligned box (``center``, ``half_extents``); derivatives by autodiff."""

    stack_fields = ("center", "half_extents")

    class Params(Params):
        center: AuxOrValue
        half_extents: AuxOrValue = Field(description="≥ 0 along every axis, or an aux name")

        @field_validator("half_extents")
        @classmethod
        def _half_extents(cls, v: AuxOrValue) -> AuxOrValue:
            vals = _values(v)
            if vals is not None and not all(x >= 0 for x in vals):
                raise ValueError(
                    f"half_extents must all be ≥ 0 (a box cannot reach a negative length from its "
                    f"centre) or the name of an aux entry; given {v!r}"
                )
            return v

    def __init__(self, params: Params, in_dim: int, aux_dims: Mapping[str, int] | None = None):
        super().__init__(in_dim, aux_dims)
        self.center = AuxParam(params.center, self.aux_dims, "box_distance.center")
        self.half_extents = AuxParam(params.half_extents, self.aux_dims, "box_distance.half_extents")
        if self.center.dim != in_dim or self.half_extents.dim != in_dim:
            raise ValueError(f"box_distance.center and half_extents need dimension {in_dim}")
        self.out_dim = 1

    def psi(self, x, aux):
        q = (x - self.center(aux)).abs() - self.half_extents(aux)
        outside = q.clamp(min=0).norm(dim=-1, keepdim=True)
        inside = q.max(dim=-1, keepdim=True).values.clamp(max=0)
        return outside + inside

    def extra_repr(self) -> str:
        return numbers_repr({"in_dim": self.in_dim, "out_dim": self.out_dim})
