"""Distances to rigid obstacles that may move: spheres, boxes, finite cylinders, capsules, and a plane.

Each obstacle map measures y = d(x − c), the signed distance from the point x to the shape around centre c
(negative inside), with analytic J = ∇d and J̇ẋ = d²d[v, v]. An obstacle that translates at velocity ċ
(``velocity``, constant or aux) changes y as well: ẏ = ∇d·(ẋ − ċ) and ÿ = Jẍ + d²d[ẋ − ċ, ẋ − ċ] (its
acceleration is taken as 0: constant velocity, or straight segments between waypoints), so the maps return the
rate relative to the obstacle and the curvature term of the relative velocity. With ``velocity`` absent
(a static obstacle) ẏ = Jẋ as for every other map. What Theorem 2 still says when an obstacle moves is in
docs/math.md §8.

A map given ``present`` (the aux entry of one member of an obstacle set, 1 present, 0 absent; ``scenes/sets.py``)
is masked BEFORE anything is measured: where the obstacle is absent, or where the point sits where the distance has
no direction (a sphere's centre, a capsule's or cylinder's axis), the shape is measured at a safe offset instead and
the map returns y = ABSENT_DISTANCE with ẏ = 0, J = 0, J̇ẋ = 0, so a barrier above it is exactly zero and no
infinity or NaN ever enters the values or their gradients (docs/math.md §13).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import ClassVar

import torch
from pydantic import Field, field_validator
from torch import Tensor

from ..core.auxstate import AuxOrValue, AuxParam, constant
from ..core.taskmap import TaskMap
from ..examples import AuxInput, Example
from ..registry import TASK_MAPS, Params, numbers_repr
from .distances import _positive_radius, _radial, _values

Measure = tuple[Tensor, Tensor, Tensor]  # distance (B, 1), gradient (B, 3), d²d[v, v] (B, 1)

#: what a masked map reports for an absent obstacle (m): beyond the support of every barrier, so the barrier above it
#: is exactly zero (G, B, Φ and their derivatives); its J, ẏ and J̇ẋ are 0
ABSENT_DISTANCE = 1e6


def _checked(v: AuxOrValue | None, ok, what: str) -> AuxOrValue | None:
    """A constant parameter's numbers must pass ``ok`` (an aux name is checked where it is made)."""
    vals = None if v is None else _values(v)
    if vals is not None and not ok(vals):
        raise ValueError(f"{what}; given {v!r}")
    return v


def _axis(v):
    return _checked(
        v,
        lambda x: len(x) == 3 and any(a != 0 for a in x),
        "axis must be a non-zero 3-vector (the shape's direction) or the name of an aux entry",
    )


def _non_negative(v):
    return _checked(v, lambda x: all(a >= 0 for a in x), "must be ≥ 0 (a half length) or the name of an aux entry")


def _positive(v):
    return _checked(v, lambda x: all(a > 0 for a in x), "must be > 0 (a half size) or the name of an aux entry")


def _dot(a: Tensor, b: Tensor) -> Tensor:
    return (a * b).sum(-1, keepdim=True)


def _perpendicular(a: Tensor) -> Tensor:
    """A unit vector perpendicular to the unit vector a (…, 3): off the axis of a capsule or cylinder."""
    ex, ey = a.new_tensor((1.0, 0.0, 0.0)), a.new_tensor((0.0, 1.0, 0.0))
    u = torch.linalg.cross(a, torch.where(a[..., :1].abs() < 0.9, ex, ey).expand_as(a))
    return u / u.norm(dim=-1, keepdim=True)


class ShapeParams(Params):
    center: AuxOrValue = Field(description="the shape's centre (3), or an aux name")
    velocity: AuxOrValue | None = Field(None, description="the shape's velocity (3) or an aux name; absent: static")

    @field_validator("velocity")
    @classmethod
    def _speed(cls, v):
        return _checked(
            v,
            lambda x: len(x) == 3 and all(abs(a) <= 100.0 for a in x),
            "velocity must be 3 numbers within ±100 m/s, or the name of an aux entry",
        )

    present: str | None = Field(
        None, description="aux entry (1): 1 where the obstacle is present, 0 where absent; absent: always present"
    )


class ObstacleDistance(TaskMap):
    """Base: the distance to a shape around ``center`` moving at ``velocity``; subclasses give ``measure``.

    Distances to obstacles of one shape stack (``core/stacking.py``): the (control point × obstacle) edges of a
    tree evaluate as one group, each member reading its own obstacle's aux state."""

    Params = ShapeParams
    stack_fields: ClassVar[tuple[str, ...]] = ("center", "velocity", "present")
    registered: ClassVar[str]  # the name each shape registers under, which its messages use

    def stack_settings(self) -> tuple:
        # static and moving obstacles compute different rates; masked and unmasked ones different outputs
        return (self.velocity is None, self.present is None)

    def __init__(self, params: ShapeParams, in_dim: int, aux_dims: Mapping[str, int] | None = None):
        super().__init__(in_dim, aux_dims)
        name = type(self).registered
        if in_dim != 3:
            raise ValueError(f"{name} measures distances in 3-D space; the parent has dimension {in_dim}")
        self.center = self._param(params.center, "center", 3)
        self.velocity = None if params.velocity is None else self._param(params.velocity, "velocity", 3)
        self.present = None if params.present is None else self._param(params.present, "present", 1)
        self.out_dim = 1

    def _param(self, value: AuxOrValue, key: str, dim: int) -> AuxParam:
        p = AuxParam(value, self.aux_dims, f"{type(self).registered}.{key}")
        if p.dim != dim:
            raise ValueError(f"{type(self).registered}.{key} must have dimension {dim}, got {p.dim}")
        return p

    def measure(self, p: Tensor, v: Tensor, aux) -> Measure:  # pragma: no cover - abstract
        raise NotImplementedError

    def safe_offset(self, aux) -> Tensor:
        """An offset from the centre where the shape's distance has a direction, whatever its size and pose: where
        a masked map measures an absent obstacle (a subclass whose distance is singular along a line overrides it)."""
        return self.center(aux).new_tensor((1.0, 0.0, 0.0))

    def distance(self, p: Tensor, aux) -> Tensor:
        """The signed distance alone at offsets ``p`` from the centre: ``measure``'s first output, which a shape whose
        distance costs less without its derivatives computes directly (ranking many obstacles, scenes/nearest.py)."""
        return self.measure(p, torch.zeros_like(p), aux)[0]

    def psi(self, x, aux=None):
        if self.present is not None:
            return self.forward(x, torch.zeros_like(x), aux)[0]
        return self.distance(x - self.center(aux), aux)

    def forward(self, x, xd, aux=None):
        p = x - self.center(aux)
        rel = xd if self.velocity is None else xd - self.velocity(aux)
        if self.present is None:
            d, g, c = self.measure(p, rel, aux)
            return d, _dot(g, rel), g.unsqueeze(-2), c
        acting = self._acting(p, rel, aux)
        p = torch.where(acting, p, self.safe_offset(aux))  # masked before measuring: nothing singular is computed
        rel = torch.where(acting, rel, torch.zeros_like(rel))
        d, g, c = self.measure(p, rel, aux)
        zero = torch.zeros_like(d)
        return (
            torch.where(acting, d, zero + ABSENT_DISTANCE),
            torch.where(acting, _dot(g, rel), zero),
            torch.where(acting, g, torch.zeros_like(g)).unsqueeze(-2),
            torch.where(acting, c, zero),
        )

    def _acting(self, p: Tensor, rel: Tensor, aux) -> Tensor:
        """(…, 1) bool: the obstacle is present and the distance at ``p`` has a direction (its gradient is finite
        and of unit length). Found without a graph, so a singular point never reaches autograd."""
        with torch.no_grad():
            d, g, c = self.measure(p.detach(), rel.detach(), aux)
            regular = (
                torch.isfinite(d) & torch.isfinite(c) & torch.isfinite(g).all(-1, keepdim=True) & (_dot(g, g) > 0.25)
            )
        assert self.present is not None, "only a masked map (given present) asks whether it acts"
        return (self.present(aux) > 0.5) & regular

    def extra_repr(self) -> str:
        """The dimensions: every number of the shape (centre, size, pose) is an ``AuxParam``, shown below them."""
        return numbers_repr({"in_dim": self.in_dim, "out_dim": self.out_dim})


# The examples are static obstacles (no velocity: ẏ = Jẋ); tests/test_scenes.py checks moving ones in time.
@TASK_MAPS.register(
    "sphere_obstacle",
    examples=[
        Example({"center": [0.3, -0.2, 0.1], "radius": 0.5}, 3, scale=2.0),
        Example({"center": "c3", "radius": "r"}, 3, scale=2.0, aux={"c3": AuxInput.normal(3), "r": AuxInput.radius()}),
        Example(
            {"center": "c3", "radius": "r", "present": "on"},
            3,
            scale=2.0,  # a member of an obstacle set
            aux={"c3": AuxInput.normal(3), "r": AuxInput.radius(), "on": AuxInput.presence()},
        ),
    ],
)
class SphereObstacle(ObstacleDistance):
    """|x − c| − R."""

    registered = "sphere_obstacle"
    stack_fields = ObstacleDistance.stack_fields + ("radius",)

    class Params(ShapeParams):
        radius: AuxOrValue = Field(description="> 0, or an aux name")
        _radius = field_validator("radius")(lambda v: _positive_radius(v, "sphere"))

    def __init__(self, params, in_dim, aux_dims=None):
        super().__init__(params, in_dim, aux_dims)
        self.radius = self._param(params.radius, "radius", 1)

    def measure(self, p, v, aux):
        r, g, _, c = _radial(p, v)
        return r - self.radius(aux), g, c

    def distance(self, p, aux):
        return torch.linalg.vector_norm(p, dim=-1, keepdim=True) - self.radius(aux)


@TASK_MAPS.register(
    "capsule_obstacle",
    examples=[
        Example({"center": [0.1, 0.0, 0.2], "radius": 0.2, "half_length": 0.6, "axis": [0.6, 0.0, 0.8]}, 3, scale=1.5),
        Example(
            {"center": [0.1, 0.0, 0.2], "radius": 0.2, "half_length": 0.6, "axis": [0.6, 0.0, 0.8], "present": "on"},
            3,
            scale=1.5,
            aux={"on": AuxInput.presence()},
        ),
    ],
)
class CapsuleObstacle(ObstacleDistance):
    """Distance to the segment c ± h·a, minus R: a cylinder of radius R with hemispherical caps."""

    registered = "capsule_obstacle"
    stack_fields = ObstacleDistance.stack_fields + ("radius", "axis", "half_length")

    class Params(ShapeParams):
        radius: AuxOrValue = Field(description="> 0, or an aux name")
        axis: AuxOrValue = Field((0.0, 0.0, 1.0), description="unit direction of the segment (3), or an aux name")
        half_length: AuxOrValue = Field(description="half the distance between the caps' centres (≥ 0), or aux")
        _radius = field_validator("radius")(lambda v: _positive_radius(v, "capsule"))
        _axis = field_validator("axis")(_axis)
        _half_length = field_validator("half_length")(_non_negative)

    def __init__(self, params, in_dim, aux_dims=None):
        super().__init__(params, in_dim, aux_dims)
        self.radius = self._param(params.radius, "radius", 1)
        self.axis = self._param(params.axis, "axis", 3)
        self.half_length = self._param(params.half_length, "half_length", 1)

    def safe_offset(self, aux):
        return _perpendicular(self.axis(aux))

    def measure(self, p, v, aux):
        a, h = self.axis(aux), self.half_length(aux)
        z = _dot(p, a)
        middle = z.abs() < h  # beside the segment: the nearest point moves along it with the obstacle's frame
        q = p - z.clamp(-h, h) * a
        qd = v - torch.where(middle, _dot(v, a), torch.zeros_like(z)) * a
        r, g, _, c = _radial(q, qd)
        return r - self.radius(aux), g, c


@TASK_MAPS.register(
    "cylinder_obstacle",
    examples=[
        Example({"center": [0.0, 0.1, 0.0], "radius": 0.4, "half_height": 0.5, "axis": [0.0, 0.6, 0.8]}, 3, scale=1.5),
        Example(
            {"center": [0.0, 0.1, 0.0], "radius": 0.4, "half_height": 0.5, "axis": [0.0, 0.6, 0.8], "present": "on"},
            3,
            scale=1.5,
            aux={"on": AuxInput.presence()},
        ),
    ],
)
class CylinderObstacle(ObstacleDistance):
    """Signed distance to a finite cylinder: radius R around the axis a through c, |z| ≤ h along it."""

    registered = "cylinder_obstacle"
    stack_fields = ObstacleDistance.stack_fields + ("radius", "axis", "half_height")

    class Params(ShapeParams):
        radius: AuxOrValue = Field(description="> 0, or an aux name")
        axis: AuxOrValue = Field((0.0, 0.0, 1.0), description="unit direction of the axis (3), or an aux name")
        half_height: AuxOrValue = Field(description="half the height along the axis (> 0), or an aux name")
        _radius = field_validator("radius")(lambda v: _positive_radius(v, "cylinder"))
        _axis = field_validator("axis")(_axis)
        _half_height = field_validator("half_height")(_positive)

    def __init__(self, params, in_dim, aux_dims=None):
        super().__init__(params, in_dim, aux_dims)
        self.radius = self._param(params.radius, "radius", 1)
        self.axis = self._param(params.axis, "axis", 3)
        self.half_height = self._param(params.half_height, "half_height", 1)

    def safe_offset(self, aux):
        return _perpendicular(self.axis(aux))

    def measure(self, p, v, aux):
        a = self.axis(aux)
        z = _dot(p, a)
        side = p - z * a
        rho, u, _, c_rho = _radial(side, v - _dot(v, a) * a)  # distance from the axis, its gradient and curvature
        dr, dz, sz = rho - self.radius(aux), z.abs() - self.half_height(aux), torch.sign(z)
        rim = (dr > 0) & (dz > 0)
        rim_d = torch.sqrt(dr.clamp(min=0) ** 2 + dz.clamp(min=0) ** 2).clamp(min=1e-300)
        g_rim = (dr * u + dz * sz * a) / rim_d
        rate_r, rate_z = _dot(u, v), sz * _dot(a, v)
        c_rim = (rate_r**2 + rate_z**2 - _dot(g_rim, v) ** 2) / rim_d + dr / rim_d * c_rho
        radial = ~rim & (dr >= dz)  # the side, or inside nearer the side than a cap
        d = torch.where(rim, rim_d, torch.where(radial, dr, dz))
        g = torch.where(rim, g_rim, torch.where(radial, u, sz * a))
        c = torch.where(rim, c_rim, torch.where(radial, c_rho, torch.zeros_like(c_rho)))
        return d, g, c


@TASK_MAPS.register(
    "box_obstacle",
    examples=[
        # rotated about (1, 2, 2)/3 by 0.7 rad, the box's axes in the world row by row
        Example(
            {
                "center": [0.1, 0.0, -0.1],
                "half_extents": [0.3, 0.5, 0.2],
                "rotation": [0.791, -0.3772, 0.4817, 0.4817, 0.8694, -0.1102, -0.3772, 0.3193, 0.8694],
            },
            3,
            scale=1.5,
        ),
        Example(
            {"center": [0.1, 0.0, -0.1], "half_extents": [0.3, 0.5, 0.2], "present": "on"},
            3,
            scale=1.5,
            aux={"on": AuxInput.presence()},
        ),
    ],
)
class BoxObstacle(ObstacleDistance):
    """Signed distance to a box with half extents e, rotated by R (world = R · box frame), around c."""

    registered = "box_obstacle"
    stack_fields = ObstacleDistance.stack_fields + ("half_extents", "rotation")

    class Params(ShapeParams):
        half_extents: AuxOrValue = Field(description="> 0 along every axis of the box (3), or an aux name")
        rotation: AuxOrValue = Field(
            (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0),
            description="R row by row (9): box axes in the world; or an aux name",
        )
        _rotation = field_validator("rotation")(
            lambda v: _checked(
                v,
                lambda x: len(x) == 9 and all(abs(a) <= 1.0 + 1e-6 for a in x),
                "rotation must be a rotation matrix row by row (9 numbers within ±1) or the name of an aux entry",
            )
        )

        @field_validator("half_extents")
        @classmethod
        def _sizes(cls, v: AuxOrValue) -> AuxOrValue:
            vals = _values(v)
            if vals is not None and not all(x > 0 for x in vals):
                raise ValueError(f"half_extents must be > 0 along every axis or the name of an aux entry; given {v!r}")
            return v

    def __init__(self, params, in_dim, aux_dims=None):
        super().__init__(params, in_dim, aux_dims)
        self.half_extents = self._param(params.half_extents, "half_extents", 3)
        self.rotation = self._param(params.rotation, "rotation", 9)

    def measure(self, p, v, aux):
        R = self.rotation(aux).reshape(*self.rotation(aux).shape[:-1], 3, 3)
        to_box = lambda w: (w.unsqueeze(-2) @ R).squeeze(-2)
        pl, vl = to_box(p), to_box(v)
        s = torch.sign(pl)
        excess = pl.abs() - self.half_extents(aux)
        out = excess.clamp(min=0)
        outside = (excess > 0).any(-1, keepdim=True)
        d_out = out.norm(dim=-1, keepdim=True).clamp(min=1e-300)
        rate = torch.where(excess > 0, s * vl, torch.zeros_like(vl))
        g_out = s * out / d_out
        c_out = (_dot(rate, rate) - _dot(g_out, vl) ** 2) / d_out
        d_in, i = excess.max(-1, keepdim=True)
        g_in = torch.zeros_like(pl).scatter(-1, i, s.gather(-1, i))
        gl = torch.where(outside, g_out, g_in)
        g = (R @ gl.unsqueeze(-1)).squeeze(-1)
        return torch.where(outside, d_out, d_in), g, torch.where(outside, c_out, torch.zeros_like(c_out))


@TASK_MAPS.register(
    "plane_obstacle",
    examples=[
        Example({"center": [0.1, -0.2, 0.3], "normal": [0.0, 0.6, 0.8]}, 3, scale=2.0),
        Example(
            {"center": "c3", "normal": "n", "present": "on"},
            3,
            scale=2.0,
            aux={"c3": AuxInput.normal(3), "n": AuxInput.normal(3), "on": AuxInput.presence()},
        ),
    ],
)
class PlaneObstacle(ObstacleDistance):
    """nᵀ(x − c) / |n|: the signed height above the plane through c with normal n (a table top, a wall) as an
    obstacle of a set: its pose is aux state and it may move; ``plane_distance`` is the fixed ground."""

    registered = "plane_obstacle"
    stack_fields = ObstacleDistance.stack_fields + ("normal",)

    class Params(ShapeParams):
        normal: AuxOrValue = Field((0.0, 0.0, 1.0), description="the plane's normal (3, normalised), or an aux name")
        _normal = field_validator("normal")(_axis)

    def __init__(self, params, in_dim, aux_dims=None):
        super().__init__(params, in_dim, aux_dims)
        self.normal = self._param(params.normal, "normal", 3)

    def measure(self, p, v, aux):
        n = self.normal(aux)
        n = (n / n.norm(dim=-1, keepdim=True)).expand_as(p)
        d = _dot(p, n)
        return d, n, torch.zeros_like(d)


@TASK_MAPS.register("plane_distance", examples=[Example({"normal": [0.0, 0.3, 1.0], "height": 0.2}, 3, scale=2.0)])
class PlaneDistance(TaskMap):
    """nᵀx − h: the height of the point above a plane with unit normal n (a table top, the floor)."""

    stack_fields = ("n", "height")
    n: Tensor  # buffer: the unit normal

    class Params(Params):
        normal: list[float] = Field([0.0, 0.0, 1.0], min_length=1, description="the plane's normal (normalised)")
        height: AuxOrValue = Field(0.0, description="offset of the plane along the normal (m), or an aux name")

        _height = field_validator("height")(
            lambda v: _checked(
                v,
                lambda x: len(x) == 1 and abs(x[0]) <= 100.0,
                "height must be one number within ±100 m or an aux name",
            )
        )

        @field_validator("normal")
        @classmethod
        def _nonzero(cls, v: list[float]) -> list[float]:
            if not any(a != 0 for a in v):
                raise ValueError(f"normal must be a non-zero vector; given {v}")
            return v

    def __init__(self, params: Params, in_dim: int, aux_dims: Mapping[str, int] | None = None):
        super().__init__(in_dim, aux_dims)
        n = constant(params.normal)
        if n.numel() != in_dim:
            raise ValueError(f"plane_distance.normal has {n.numel()} entries for a {in_dim}-dimensional parent")
        self.register_buffer("n", n / n.norm())
        self.height = AuxParam(params.height, self.aux_dims, "plane_distance.height")
        if self.height.dim != 1:
            raise ValueError(f"plane_distance.height must be a scalar, got dimension {self.height.dim}")
        self.out_dim = 1

    def psi(self, x, aux=None):
        return (x * self.n).sum(-1, keepdim=True) - self.height(aux)

    def forward(self, x, xd, aux=None):
        y = self.psi(x, aux)
        J = self.n.unsqueeze(-2).expand(*y.shape[:-1], 1, self.in_dim)
        return y, (xd * self.n).sum(-1, keepdim=True), J, torch.zeros_like(y)

    def extra_repr(self) -> str:
        return numbers_repr({"in_dim": self.in_dim, "out_dim": self.out_dim, "normal": self.n})
