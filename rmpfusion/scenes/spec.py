"""Scenes as data (conf/scene/): obstacles of four shapes, each static or moving, and an optional ground plane.

A scene is what a manipulator environment simulates and what the manipulator tree reads its obstacle distances
from: every obstacle becomes one distance edge under every control point, and its pose and size reach the tree
as aux state (``scenes/aux.py``), so the same tree runs in every scene whose obstacles have the same shapes in the
same order (the test split's scene moves and resizes them).
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field, field_validator

from ..registry import Params

Vec3 = tuple[float, float, float]
#: how far from the origin a scene may place anything (m): beyond any arm's reach, so a typo like 55 for 0.55 is caught
REACH = 10.0


def _nonzero(v: Vec3, what: str) -> Vec3:
    if not any(abs(a) > 0 for a in v):
        raise ValueError(f"{what} must be a non-zero vector (it is a direction); given {list(v)}")
    return v


class Static(Params):
    """The obstacle stays where it is."""

    type: Literal["static"] = "static"


class Linear(Params):
    """The obstacle moves at a constant velocity from its centre."""

    type: Literal["linear"]
    velocity: Vec3 = Field(description="m/s, each component within ±2 m/s")

    @field_validator("velocity")
    @classmethod
    def _bounded(cls, v: Vec3) -> Vec3:
        if not all(abs(a) <= 2.0 for a in v):
            raise ValueError(
                f"velocity components must lie within ±2 m/s (faster than an arm can react); given {list(v)}"
            )
        return v


class Waypoints(Params):
    """The obstacle travels at a constant speed from its centre through ``points`` (offsets from the centre, m)
    and back to the centre, over and over; its velocity jumps at the corners."""

    type: Literal["waypoints"]
    points: list[Vec3] = Field(min_length=1, description="offsets from the centre (m), visited in order")
    speed: float = Field(gt=0, le=2.0, description="m/s along the path")

    @field_validator("points")
    @classmethod
    def _within_reach(cls, v: list[Vec3]) -> list[Vec3]:
        if not all(abs(a) <= REACH for p in v for a in p):
            raise ValueError(f"waypoint offsets must lie within ±{REACH} m; given {v}")
        return v


Motion = Annotated[Static | Linear | Waypoints, Field(discriminator="type")]


class _Obstacle(Params):
    center: Vec3 = Field(description="m, world frame; where a moving obstacle starts")
    motion: Motion = Static()

    @field_validator("center")
    @classmethod
    def _reachable(cls, v: Vec3) -> Vec3:
        if not all(abs(a) <= REACH for a in v):
            raise ValueError(f"center must lie within ±{REACH} m of the robot's base; given {list(v)}")
        return v

    @property
    def moving(self) -> bool:
        return self.motion.type != "static"


class Sphere(_Obstacle):
    type: Literal["sphere"]
    radius: float = Field(gt=0, le=REACH, description="m")


class Box(_Obstacle):
    type: Literal["box"]
    half_extents: Vec3 = Field(description="m, half the box's size along its own x, y, z")
    rpy: Vec3 = Field((0.0, 0.0, 0.0), description="orientation: roll, pitch, yaw (rad), URDF convention")

    @field_validator("half_extents")
    @classmethod
    def _positive(cls, v: Vec3) -> Vec3:
        if not all(0 < a <= REACH for a in v):
            raise ValueError(f"half_extents must be > 0 (and ≤ {REACH} m) along every axis; given {list(v)}")
        return v


class Cylinder(_Obstacle):
    type: Literal["cylinder"]
    radius: float = Field(gt=0, le=REACH, description="m")
    height: float = Field(gt=0, le=2 * REACH, description="m, along the axis, centred on center")
    axis: Vec3 = Field((0.0, 0.0, 1.0), description="the cylinder's direction (normalised)")

    @field_validator("axis")
    @classmethod
    def _axis(cls, v: Vec3) -> Vec3:
        return _nonzero(v, "axis")


class Capsule(_Obstacle):
    type: Literal["capsule"]
    radius: float = Field(gt=0, le=REACH, description="m")
    length: float = Field(ge=0, le=2 * REACH, description="m, between the centres of the two end caps")
    axis: Vec3 = Field((0.0, 0.0, 1.0), description="the capsule's direction (normalised)")

    @field_validator("axis")
    @classmethod
    def _axis(cls, v: Vec3) -> Vec3:
        return _nonzero(v, "axis")


Obstacle = Annotated[Sphere | Box | Cylinder | Capsule, Field(discriminator="type")]
SHAPES = ("sphere", "box", "cylinder", "capsule")


class Ground(Params):
    """A horizontal plane (a table top or the floor) that every control point keeps above."""

    height: float = Field(0.0, ge=-REACH, le=REACH, description="m, z of the plane")


class Scene(Params):
    """Obstacles and an optional ground plane."""

    obstacles: list[Obstacle] = Field(default_factory=list)
    ground: Ground | None = None

    @property
    def moving(self) -> bool:
        return any(o.moving for o in self.obstacles)

    def layout(self) -> list[tuple[str, str]]:
        """(shape, motion kind) of every obstacle slot: what a tree built for this scene depends on."""
        return [(o.type, "static" if not o.moving else "moving") for o in self.obstacles]


def same_layout(a: Scene, b: Scene, what: str) -> None:
    """Refuse a second scene (the test split's) that a tree built for ``a`` could not run in."""
    if a.layout() != b.layout() or (a.ground is None) != (b.ground is None):
        raise ValueError(
            f"{what} must have the obstacles of the training scene, with the same shapes in the same "
            f"order, each static or moving as there, and a ground plane if and only if it has one (the "
            f"tree has one distance edge per obstacle); training: {a.layout()}, given: {b.layout()}"
        )


__all__ = [
    "SHAPES",
    "Box",
    "Capsule",
    "Cylinder",
    "Ground",
    "Linear",
    "Obstacle",
    "Scene",
    "Sphere",
    "Static",
    "Waypoints",
    "same_layout",
]
