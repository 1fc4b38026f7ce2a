"""Hand-designed weight functions with analytic gradients: the fixed weights of expert policies. Their numbers
broadcast against the samples, so weights of one type stack (``core/stacking.py``)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import ClassVar

import torch
from pydantic import Field, field_validator
from torch import Tensor

from .. import registry
from ..core.auxstate import AuxOrValue, AuxParam
from ..core.weight import WeightFunction
from ..examples import AuxInput, Example
from ..registry import WEIGHTS, numbers_repr


@WEIGHTS.register("constant", examples=[Example({"value": 2.5}, 2)])
class Constant(WeightFunction):
    """w = value > 0 everywhere; ∇w = 0, so pullback* skips h_i."""

    is_constant = True
    reads = "nothing"
    stack_fields = ("c",)

    class Params(registry.Params):  # registry.Params: this class takes its base's name
        value: float = Field(1.0, description="> 0: positive weights keep the policy Lyapunov-stable (Theorem 2)")

        @field_validator("value")
        @classmethod
        def _positive(cls, v: float) -> float:
            if not v > 0:
                raise ValueError(
                    f"constant weight must be > 0 (positive weights are what keep the policy "
                    f"Lyapunov-stable, Theorem 2); given {v}"
                )
            return v

    def __init__(self, params: Params, in_dim: int, aux_dims: Mapping[str, int] | None = None):
        super().__init__(in_dim, aux_dims)
        self.c = params.value

    def value(self, x, aux):
        return self.c + torch.zeros_like(x[..., 0])

    def forward(self, x, aux=None):
        return self.value(x, aux), None

    def extra_repr(self) -> str:
        return numbers_repr({"in_dim": self.in_dim, "value": self.c})


class _Range(registry.Params):
    low: float = Field(gt=0, description="weight far from the feature's switching point")
    high: float = Field(gt=0)


def _surface_radius(v: AuxOrValue) -> AuxOrValue:
    """A constant radius is ≥ 0: 0 measures from the centre point itself, a negative one is no surface."""
    if not isinstance(v, str):
        vals = [float(x) for x in v] if isinstance(v, Sequence) else [float(v)]
        if not all(x >= 0 for x in vals):
            raise ValueError(
                f"radius must be ≥ 0 (0 measures the distance from the centre point; a negative radius "
                f"is no surface) or the name of an aux entry; given {v!r}"
            )
    return v


class _DistanceWeight(WeightFunction):
    """Base for weights of the distance d = |x − center| − radius (center/radius constant or aux)."""

    stack_fields: ClassVar[tuple[str, ...]] = ("center", "radius", "low", "high")

    def __init__(self, params, in_dim: int, aux_dims: Mapping[str, int] | None = None):
        super().__init__(in_dim, aux_dims)
        self.center = AuxParam(params.center, self.aux_dims, f"{type(self).__name__}.center")
        self.radius = AuxParam(params.radius, self.aux_dims, f"{type(self).__name__}.radius")
        if self.center.dim != in_dim:
            raise ValueError(f"weight center has dimension {self.center.dim}, parent space has {in_dim}")
        self.low, self.high = params.low, params.high

    def _distance(self, x, aux) -> tuple[Tensor, Tensor]:
        diff = x - self.center(aux)
        r = diff.norm(dim=-1).clamp(min=1e-12)
        return r - self.radius(aux)[..., 0], diff / r[..., None]

    def shape(self, d: Tensor) -> tuple[Tensor, Tensor]:  # pragma: no cover - abstract
        raise NotImplementedError

    def value(self, x, aux):
        return self.forward(x, aux)[0]

    def forward(self, x, aux=None):
        d, dd_dx = self._distance(x, aux)
        s, ds = self.shape(d)
        w = self.low + (self.high - self.low) * s
        return w, ((self.high - self.low) * ds)[..., None] * dd_dx


@WEIGHTS.register(
    "rbf",
    examples=[
        Example(
            {"low": 0.5, "high": 4.0, "center": "obstacle_center", "radius": "obstacle_radius", "sigma": 0.7},
            2,
            scale=2.0,
            aux={"obstacle_center": AuxInput.normal(2), "obstacle_radius": AuxInput.radius()},
        ),
        Example({"low": 2.0, "high": 0.1, "center": [1.0, -1.0]}, 2, scale=2.0),
    ],
)
class RBF(_DistanceWeight):
    """w = low + (high − low)·exp(−d²/2σ²), d = |x − center| − radius: high near a point or surface."""

    class Params(_Range):
        center: AuxOrValue
        radius: AuxOrValue = Field(0.0, description="≥ 0 (0: a point), or an aux name")
        sigma: float = Field(1.0, gt=0)

        @field_validator("radius")
        @classmethod
        def _radius(cls, v: AuxOrValue) -> AuxOrValue:
            return _surface_radius(v)

    stack_fields = _DistanceWeight.stack_fields + ("sigma",)

    def __init__(self, params: Params, in_dim: int, aux_dims: Mapping[str, int] | None = None):
        super().__init__(params, in_dim, aux_dims)
        self.sigma = params.sigma

    def shape(self, d):
        e = torch.exp(-(d**2) / (2 * self.sigma**2))
        return e, -d / self.sigma**2 * e

    def extra_repr(self) -> str:
        return numbers_repr({"in_dim": self.in_dim, "low": self.low, "high": self.high, "sigma": self.sigma})


@WEIGHTS.register(
    "logistic",
    examples=[
        Example(
            {
                "low": 0.2,
                "high": 3.0,
                "center": "obstacle_center",
                "radius": "obstacle_radius",
                "steepness": -3.0,
                "switch_distance": 0.5,
            },
            2,
            scale=2.0,
            aux={"obstacle_center": AuxInput.normal(2), "obstacle_radius": AuxInput.radius()},
        )
    ],
)
class Logistic(_DistanceWeight):
    """w = low + (high − low)·σ(k·(d − d0)), d = |x − center| − radius: a smooth switch at distance d0.

    k > 0 turns the edge on far away; k < 0 turns it on near the center.
    """

    class Params(_Range):
        center: AuxOrValue
        radius: AuxOrValue = Field(0.0, description="≥ 0 (0: a point), or an aux name")
        steepness: float = Field(4.0, description="k; its sign picks which side is 'high'")
        switch_distance: float = Field(0.0, description="d0, any sign: d is a signed distance (< 0 inside)")

        @field_validator("radius")
        @classmethod
        def _radius(cls, v: AuxOrValue) -> AuxOrValue:
            return _surface_radius(v)

        @field_validator("steepness")
        @classmethod
        def _nonzero(cls, v: float) -> float:
            if not (v > 0 or v < 0):  # NaN too
                raise ValueError(
                    f"steepness must be non-zero (k = 0 is a constant weight: use type constant instead); given {v}"
                )
            return v

    stack_fields = _DistanceWeight.stack_fields + ("k", "d0")

    def __init__(self, params: Params, in_dim: int, aux_dims: Mapping[str, int] | None = None):
        super().__init__(params, in_dim, aux_dims)
        self.k, self.d0 = params.steepness, params.switch_distance

    def shape(self, d):
        s = torch.sigmoid(self.k * (d - self.d0))
        return s, self.k * s * (1 - s)

    def extra_repr(self) -> str:
        return numbers_repr(
            {
                "in_dim": self.in_dim,
                "low": self.low,
                "high": self.high,
                "steepness": self.k,
                "switch_distance": self.d0,
            }
        )
