"""Every parameter with a physical meaning carries its valid range in its model (a bound or a validator), so a bad
value in YAML is refused at validation, naming its path, instead of running into NaN or nonsense later.

The walk covers every entry of every registry (and the models their fields nest, such as the Franka obstacles or
the leaf settings of the ``arm_reach`` generator) plus the run config's data/train/eval blocks. A field is
*physical* when its name has one of ``PHYSICAL`` as a ``_``-separated word; a new one added without a range fails
here. Deliberate exceptions go in ``EXEMPT`` with the reason.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Annotated, Any, get_args, get_origin

import annotated_types
import pytest
from pydantic import BaseModel
from pydantic.fields import FieldInfo

import rmpfusion  # noqa: F401  (registers the built-ins)
from rmpfusion.learn.config import TrainParams
from rmpfusion.pipeline.config import DataConfig, EvalConfig, RecordedDataConfig
from rmpfusion.registry import ENVS, LEAF_RMPS, LEARNERS, ROBOTS, TASK_MAPS, TRAIN_METHODS, TREE_GENERATORS, WEIGHTS

REGISTRIES = (LEAF_RMPS, TASK_MAPS, WEIGHTS, ROBOTS, ENVS, LEARNERS, TREE_GENERATORS, TRAIN_METHODS)
CONFIG_BLOCKS = {"data": DataConfig, "data (recorded)": RecordedDataConfig, "train": TrainParams, "eval": EvalConfig}

#: Words that make a numeric field a physical quantity, a size, a count or a range (a field name is split at
#: ``_``). Positions and linear maps (center, offset, origin, matrix, bias) are left out: any value is a place.
PHYSICAL = frozenset(
    {
        "radius",
        "radii",
        "dt",
        "gain",
        "scale",
        "sigma",
        "alpha",
        "eta",
        "epsilon",
        "r",
        "w",
        "u",
        "l",
        "tol",
        "rtol",
        "atol",
        "tolerance",
        "distance",
        "clearance",
        "gap",
        "margin",
        "horizon",
        "interval",
        "duration",
        "times",
        "rate",
        "fps",
        "speed",
        "spread",
        "jitter",
        "extents",
        "height",
        "lr",
        "fraction",
        "ratio",
        "floor",
        "steepness",
        "hidden",
        "width",
        "size",
        "clip",
        "every",
        "iterations",
        "tries",
        "envs",
        "trajectories",
        "trajectory",
        "points",
        "obstacles",
        "value",
        "low",
        "high",
        "workspace",
        "region",
        "along",
        "across",
        "axis",
        "camera",
        "q",
        "indices",
        "joints",
        "limit",
        "snapshots",
        "gravity",
    }
)

#: (model qualname, field) -> why it has no range of its own (a model's subclasses share its exemptions).
EXEMPT = {
    ("Logistic.Params", "switch_distance"): "d0 is a signed distance (< 0 inside the surface): every value is a place",
    ("JointLimit.Params", "limit"): "a joint position, any sign; which side it bounds is `side`",
    ("ManipulatorParams", "gravity"): "the world's vertical acceleration, any sign (0: no gravity)",
    ("TrainParams", "snapshots"): "checked against train.iterations by RunConfig, which sees both",
}

_BOUNDS = (annotated_types.Gt, annotated_types.Ge, annotated_types.Lt, annotated_types.Le, annotated_types.Interval)


def _members(ann: Any) -> Iterator[Any]:
    """Every type an annotation is made of (through Optional/Union, containers and Annotated)."""
    yield ann
    for arg in get_args(ann):
        if not isinstance(arg, (str, int, float)) and arg is not Ellipsis:
            yield from _members(arg)


def _numeric(ann: Any) -> bool:
    return any(m in (int, float) for m in _members(ann))


def _has_bound(metadata) -> bool:
    return any(isinstance(m, _BOUNDS) or (isinstance(m, FieldInfo) and _has_bound(m.metadata)) for m in metadata)


def _bounded(ann: Any, metadata: list) -> bool:
    """A bound on the field itself, or on the items of a container (``list[Annotated[int, Field(ge=1)]]``)."""
    return _has_bound(metadata) or any(get_origin(m) is Annotated and _has_bound(m.__metadata__) for m in _members(ann))


def _validated(model: type[BaseModel], name: str) -> bool:
    decorators = model.__pydantic_decorators__.field_validators.values()
    return any(name in d.info.fields or "*" in d.info.fields for d in decorators)


def _nested_models(ann: Any) -> Iterator[type[BaseModel]]:
    for m in _members(ann):
        if isinstance(m, type) and issubclass(m, BaseModel):
            yield m


def models() -> dict[str, type[BaseModel]]:
    """Where a model is used -> the model: every registry entry's, the models its fields nest, the config blocks."""
    found: dict[str, type[BaseModel]] = {}

    def visit(where: str, model: type[BaseModel]) -> None:
        if model in found.values():
            return
        found[where] = model
        for name, f in model.model_fields.items():
            subs = list(dict.fromkeys(_nested_models(f.annotation)))
            for sub in subs:  # a union's members each under their own name (obstacle shapes, motions)
                visit(f"{where}.{name}" + (f"[{sub.__qualname__}]" if len(subs) > 1 else ""), sub)

    for reg in REGISTRIES:
        for e in reg.entries():
            visit(f"{reg.kind} '{e.name}'", e.params)
    for block, model in CONFIG_BLOCKS.items():
        visit(block, model)
    return found


def physical_fields(model: type[BaseModel]) -> list[str]:
    return [n for n, f in model.model_fields.items() if _numeric(f.annotation) and PHYSICAL & set(n.split("_"))]


def unranged(model: type[BaseModel]) -> list[str]:
    return [
        n
        for n in physical_fields(model)
        if not any((base.__qualname__, n) in EXEMPT for base in model.__mro__)
        and not _bounded(model.model_fields[n].annotation, model.model_fields[n].metadata)
        and not _validated(model, n)
    ]


MODELS = models()


@pytest.mark.parametrize("where", sorted(MODELS))
def test_every_physical_parameter_has_a_range(where):
    model = MODELS[where]
    missing = unranged(model)
    assert not missing, (
        f"{where} ({model.__qualname__}): {missing} carry no range; give each a Field(gt=/ge=/lt=/le=) "
        f"or a field_validator that says what is allowed, or exempt it in EXEMPT with the reason"
    )


def test_the_walk_reaches_what_it_should():
    kinds = {w.split(" '")[0] for w in MODELS}
    assert {r.kind for r in REGISTRIES} <= kinds and set(CONFIG_BLOCKS) <= set(MODELS)
    names = {m.__qualname__ for m in MODELS.values()}
    assert {
        "Sphere",
        "Box",
        "Static",
        "Waypoints",
        "ControlPoint",
        "GoalAttractor.Params",
        "MLPWeight.Params",
    } <= names  # nested
    assert sum(len(physical_fields(m)) for m in MODELS.values()) > 80


def test_exemptions_name_fields_that_exist():
    by_name = {m.__qualname__: m for m in MODELS.values()}
    stale = [k for k in EXEMPT if k[0] not in by_name or k[1] not in by_name[k[0]].model_fields]
    assert not stale, f"EXEMPT lists fields that no longer exist: {stale}"


def test_a_field_without_a_range_is_caught():
    from pydantic import Field, field_validator

    class Loose(BaseModel):
        radius: float = 1.0
        gain: float | list[float] = 1.0
        label: str = "x"
        use_gain: bool = True

    class Tight(BaseModel):
        radius: float = Field(1.0, gt=0)
        gain: float | list[float] = 1.0
        hidden: list[Annotated[int, Field(ge=1)]] = [8]

        @field_validator("gain")
        @classmethod
        def _g(cls, v):
            return v

    assert unranged(Loose) == ["radius", "gain"]
    assert unranged(Tight) == []
