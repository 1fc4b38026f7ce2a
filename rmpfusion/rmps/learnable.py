"""Leaf parameters a config may declare learnable: ``gain: {learn: true, init: 1.0}`` instead of ``gain: 1.0``.

Every number of a leaf whose field has a valid range (``Field(gt=0)``, ``ge=0``, ...) may be learned, in every leaf
whose ``Params`` extend ``LeafParams`` (the built-in GDS leaves but ``moving_goal_attractor`` and
``velocity_limit``, which declare no stacked numbers yet; the RMPflow ports; a plugin's that do): the number is
validated as written (its field's own checks and the leaf's cross-field checks see the initial value), then
handed to the leaf as a ``core.learnable.LearnedFloat`` carrying the field's range, narrowed by ``min``/``max``
when given. The leaf stores it as it stores a constant (``self.gain = params.gain``) and it becomes a parameter
of the tree, kept inside that range (``core/learnable.py``), so the leaf stays the GDS its ranges allow and Theorem
2 keeps holding while it learns. ``{learn: false, init: x}`` is the constant x.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, SupportsFloat

import annotated_types
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_serializer, model_validator
from pydantic.fields import FieldInfo

from ..core.learnable import LearnedFloat
from ..registry import Params


class LearnSpec(BaseModel):
    """How a learnable number is written."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)
    learn: bool = Field(description="true: trained with the learner; false: the constant init")
    init: float = Field(description="the value it starts from, strictly inside its range")
    min: float | None = Field(None, description="narrows the field's own lower bound")
    max: float | None = Field(None, description="narrows the field's own upper bound")


def field_range(field: FieldInfo) -> tuple[float | None, float | None]:
    """(lower, upper) of a field's own bounds (None where it has none)."""
    lower = upper = None
    for m in field.metadata:
        if isinstance(m, (annotated_types.Gt, annotated_types.Ge)):
            lower = _bound(m.gt if isinstance(m, annotated_types.Gt) else m.ge)
        if isinstance(m, (annotated_types.Lt, annotated_types.Le)):
            upper = _bound(m.lt if isinstance(m, annotated_types.Lt) else m.le)
    return lower, upper


def _bound(value: object) -> float:
    """A field's bound as a number (a number's field is bounded by numbers)."""
    if not isinstance(value, SupportsFloat):
        raise TypeError(f"a learnable number's field is bounded by a number, not {value!r}")
    return float(value)


def _narrowed(name: str, field: FieldInfo, spec: LearnSpec) -> tuple[float | None, float | None]:
    """The range a learned number stays in: its field's, narrowed by the spec's min/max (never widened)."""
    lower, upper = field_range(field)
    for bound, value, tighter in (
        ("min", spec.min, lambda a, b: b is None or a >= b),
        ("max", spec.max, lambda a, b: b is None or a <= b),
    ):
        own = lower if bound == "min" else upper
        if value is not None and not tighter(value, own):
            raise ValueError(
                f"{name}: {bound}={value} lies outside the parameter's own range "
                f"({lower}, {upper}); {bound} can only narrow it"
            )
    lower = spec.min if spec.min is not None else lower
    upper = spec.max if spec.max is not None else upper
    if (lower is not None and not spec.init > lower) or (upper is not None and not spec.init < upper):
        raise ValueError(
            f"{name}: a learned value must start strictly inside its range ({lower}, {upper}): it is "
            f"kept there by a parameterisation that reaches the bounds only in the limit; given "
            f"init={spec.init}"
        )
    return lower, upper


def _spec(value: Any) -> LearnSpec | None:
    """The learn spec a value is written as (a mapping, or a LearnedFloat handed on), else None."""
    if isinstance(value, LearnedFloat):
        return LearnSpec(learn=True, init=float(value), min=value.lower, max=value.upper)
    if isinstance(value, Mapping) and "learn" in value:
        return LearnSpec.model_validate(dict(value))
    return None


class LeafParams(Params):
    """Base of a leaf RMP's parameters: any number whose field has a range may be written ``{learn: true, init:
    x[, min: a, max: b]}`` (see the module docstring)."""

    @model_validator(mode="wrap")
    @classmethod
    def _learnable_numbers(cls, data: Any, handler):
        if not isinstance(data, Mapping):
            return handler(data)
        plain, learned = dict(data), {}
        for name, value in data.items():
            try:
                spec = _spec(value)
            except ValidationError as e:
                said = "; ".join(f"{'.'.join(map(str, err['loc']))}: {err['msg']}" for err in e.errors())
                raise ValueError(
                    f"{name}: {said} (a learnable number is written {{learn: true, init: x}}, optionally "
                    "with min and max)"
                ) from None
            if spec is None:
                continue
            field = cls.model_fields.get(name)
            if field is None or field.annotation is not float:
                raise ValueError(
                    f"{name}: only a number of the leaf can be learned; this leaf's numbers: "
                    f"{', '.join(n for n, f in cls.model_fields.items() if f.annotation is float)}"
                )
            plain[name] = spec.init
            if spec.learn:
                learned[name] = spec
        model = handler(plain)
        for name, spec in learned.items():
            lower, upper = _narrowed(name, cls.model_fields[name], spec)
            written = spec.model_dump(exclude_none=True)
            model.__dict__[name] = LearnedFloat(getattr(model, name), lower, upper, written)
        return model

    @model_serializer(mode="wrap")
    def _as_written(self, handler) -> dict[str, Any]:
        """Learned numbers as they were declared, so a stored config validates to the same learnable leaf."""
        out = handler(self)
        for name, value in self.__dict__.items():
            if isinstance(value, LearnedFloat) and isinstance(out, dict):
                out[name] = dict(value.written)
        return out

    def learned(self) -> dict[str, LearnedFloat]:
        """The numbers declared learnable (name → initial value with its range)."""
        return {n: v for n, v in self.__dict__.items() if isinstance(v, LearnedFloat)}
