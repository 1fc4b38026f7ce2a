"""The derivative-check examples a registry entry declares where it is registered.

Every task map, leaf RMP and weight function is checked against finite differences (its J and J̇ẋ, its M and f
against the GDS definitions, its ∇w) by tests/test_registry_derivatives.py, which builds each entry from the
examples it carries, never from a table of rmpfusion's own. A built-in and a plugin declare them the same way, at
the register call, so a plugin brings its own checks without editing rmpfusion::

    @LEAF_RMPS.register("spring", examples=[Example({"gain": 3.0}, dim=2)])

An entry without examples fails that test, naming itself and this way of adding them.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import torch
from torch import Tensor

#: ``state(gen, n, dim) -> (x, ẋ)``: n states of a dim-dimensional space, drawn with the generator ``gen``.
StateSampler = Callable[[torch.Generator, int, int], tuple[Tensor, Tensor]]
#: ``sample(gen, n, dim) -> value``: n values of one aux input of dimension dim.
AuxSampler = Callable[[torch.Generator, int, int], Tensor]


def standard_normal(gen: torch.Generator, n: int, dim: int) -> Tensor:
    return torch.randn(n, dim, generator=gen)


def radius_like(gen: torch.Generator, n: int, dim: int) -> Tensor:
    """Values in [0.5, 1.5): a radius, or any input that must stay positive and away from 0."""
    return 0.5 + torch.rand(n, dim, generator=gen)


def presence_like(gen: torch.Generator, n: int, dim: int) -> Tensor:
    """1 or 0 at random, the first value 1 and the second 0: an obstacle set member present or absent."""
    v = (torch.rand(n, dim, generator=gen) < 0.5).to(torch.get_default_dtype())
    v[0], v[min(1, n - 1)] = 1.0, 0.0
    return v


@dataclass(frozen=True)
class AuxInput:
    """One aux input an example reads (a centre, a radius, a goal): its dimension and how its values are drawn."""

    dim: int
    sample: AuxSampler = standard_normal

    @classmethod
    def normal(cls, dim: int) -> AuxInput:
        """Drawn from N(0, I): a centre, a goal, a velocity, a direction."""
        return cls(dim, standard_normal)

    @classmethod
    def radius(cls, dim: int = 1) -> AuxInput:
        """Drawn from [0.5, 1.5): a radius."""
        return cls(dim, radius_like)

    @classmethod
    def presence(cls) -> AuxInput:
        """1 or 0: whether a member of an obstacle set is present."""
        return cls(1, presence_like)


@dataclass(frozen=True)
class Example:
    """One configuration of a registry entry and the states it is checked at.

    ``params``: the entry's YAML parameters, validated by its own Params model. ``dim``: the parent space's
    dimension (task maps, weights) or the leaf's own dimension (leaf RMPs). ``state``: where the entry is checked,
    ``state(gen, n, dim) -> (x, ẋ)``; by default x ~ scale·N(0, I), ẋ ~ N(0, I). Give one when the entry is not
    differentiable everywhere (a barrier outside its support, a robot outside its joint limits). ``aux``: the aux
    inputs the parameters name (task maps and weights), name → ``AuxInput``; the entry is built with exactly these
    dimensions and called with exactly these values, so an input it reads but the example does not declare fails.
    """

    params: Mapping[str, Any] = field(default_factory=dict)
    dim: int = 2
    state: StateSampler | None = None
    scale: float = 1.0
    aux: Mapping[str, AuxInput] = field(default_factory=dict)

    def states(self, gen: torch.Generator, n: int) -> tuple[Tensor, Tensor]:
        if self.state is not None:
            return self.state(gen, n, self.dim)
        return self.scale * torch.randn(n, self.dim, generator=gen), torch.randn(n, self.dim, generator=gen)

    def aux_dims(self) -> dict[str, int]:
        return {name: spec.dim for name, spec in self.aux.items()}

    def sample_aux(self, gen: torch.Generator, n: int) -> dict[str, Tensor]:
        return {name: spec.sample(gen, n, spec.dim) for name, spec in self.aux.items()}
