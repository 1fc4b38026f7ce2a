"""Learned numbers: a module's number (a leaf's gain, metric scale, barrier constant, damping) trained with the
rest of the learner, kept inside its valid range by construction.

A number the config declares learnable arrives as a ``LearnedFloat`` (a float that also carries the range it must
stay in). Assigned to a module attribute that the class declares as a number (its ``stack_fields``), it becomes an
unconstrained parameter ``<name>_raw`` and reading the attribute computes the number from it, every time:

    (lower, upper)   lower + (upper − lower)·sigmoid(raw)
    (lower, ∞)       lower + exp(raw)
    (−∞, upper)      upper − exp(raw)
    (−∞, ∞)          raw

so the number never leaves its range, whatever the optimiser does: a leaf stays a GDS for every value of its
parameters' ranges, so a tree keeps Theorem 2 while it learns them. The module's math reads ``self.gain`` as it
reads a constant; a group of such modules restacks the members' raw parameters at every call
(``core/stacking.py::LiveStack``), so every member computes its own number and gets its own gradient.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import torch
from torch import Tensor, nn

if TYPE_CHECKING:
    from typing import Self  # Python 3.11; annotations only, which are not evaluated


class LearnedFloat(float):
    """A number's initial value that is to be learned within (lower, upper) (None: unbounded on that side); the
    initial value lies strictly inside. ``written`` is how the config declared it (for writing it back)."""

    lower: float | None
    upper: float | None
    written: dict

    def __new__(
        cls, init: float, lower: float | None = None, upper: float | None = None, written: dict | None = None
    ) -> Self:
        out = super().__new__(cls, init)
        out.lower, out.upper, out.written = lower, upper, dict(written or {"learn": True, "init": float(init)})
        return out

    def __reduce__(self):  # pickled (deep-copied configs, checkpoints) with its range
        return (LearnedFloat, (float(self), self.lower, self.upper, self.written))


@dataclass(frozen=True)
class Range:
    """The parameterisation of a number inside (lower, upper) by an unconstrained raw value."""

    lower: float | None
    upper: float | None

    def value(self, raw: Tensor) -> Tensor:
        lo, hi = self.lower, self.upper
        if lo is not None and hi is not None:
            return lo + (hi - lo) * torch.sigmoid(raw)
        if lo is not None:
            return lo + torch.exp(raw)
        if hi is not None:
            return hi - torch.exp(raw)
        return raw

    def raw(self, value: float) -> float:
        """The raw value of a number strictly inside the range (ValueError on or outside it)."""
        lo, hi = self.lower, self.upper
        if (lo is not None and not value > lo) or (hi is not None and not value < hi):
            raise ValueError(f"a learned number must start strictly inside its range ({lo}, {hi}); given {value}")
        if lo is not None and hi is not None:
            p = (value - lo) / (hi - lo)
            return math.log(p / (1.0 - p))
        if lo is not None:
            return math.log(value - lo)
        if hi is not None:
            return math.log(hi - value)
        return value


class Number:
    """A module attribute that holds a number: a constant as given, or a ``LearnedFloat`` turned into the learned
    parameter ``<name>_raw`` and read back through its ``Range``. Installed on a leaf class for each of its
    ``stack_fields`` (``core/gds.py::LeafRMP``), so ``self.gain = params.gain`` and every read of ``self.gain`` work
    alike for constants and learned numbers.

    A constant lives in the instance's ``__dict__`` and is read from there at plain attribute speed (a leaf's math
    reads its numbers at every evaluation, and a descriptor's Python ``__get__`` on each read cost more than the
    arithmetic of a single state): only a learned number, which has no entry there, is computed here. Assignments
    go through ``assign_number``, which the leaf's ``__setattr__`` calls."""

    def __init__(self, name: str):
        self.name = name

    def __get__(self, obj: Any, owner: type | None = None) -> Any:
        if obj is None:
            return self
        rng = obj.__dict__.get("_learned_ranges", {}).get(self.name)
        if rng is not None:
            return rng.value(getattr(obj, f"{self.name}_raw"))
        return nn.Module.__getattr__(obj, self.name)  # not a plain number: a parameter, buffer or submodule


def assign_number(obj: nn.Module, name: str, value: Any) -> bool:
    """``obj.<name> = value`` for a ``Number`` attribute: a ``LearnedFloat`` becomes the parameter ``<name>_raw``
    (True: assigned here); anything else is for ``nn.Module.__setattr__`` to store (False), except over a number
    that is already learned, which is refused by name."""
    learned = obj.__dict__.get("_learned_ranges", {})
    if isinstance(value, LearnedFloat):
        rng = Range(value.lower, value.upper)
        raw = torch.tensor(rng.raw(float(value)), dtype=torch.float64)
        obj.register_parameter(f"{name}_raw", nn.Parameter(raw))
        obj.__dict__["_learned_ranges"] = {**learned, name: rng}
        obj.__dict__.pop(name, None)
        return True
    if name in learned:
        raise AttributeError(
            f"{type(obj).__name__}.{name} is learned (from the parameter {name}_raw); set that parameter, or build "
            "the module with a constant"
        )
    return False


def install_numbers(cls: type, names: tuple[str, ...] | None) -> None:
    """Make each of ``names`` a ``Number`` attribute of ``cls`` (those it does not define otherwise)."""
    for name in names or ():
        if not isinstance(cls.__dict__.get(name), (Number, property)):
            setattr(cls, name, Number(name))


def learned_ranges(module: nn.Module) -> dict[str, Range]:
    """The module's learned numbers and their ranges (empty for a module with constants only)."""
    return dict(module.__dict__.get("_learned_ranges", {}))


def learned_values(module: nn.Module) -> dict[str, float]:
    """The current value of each of the module's learned numbers."""
    return {name: float(getattr(module, name).detach()) for name in learned_ranges(module)}
