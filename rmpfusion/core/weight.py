"""Weight functions on edges: w(x, aux) > 0 and its gradient w.r.t. the parent configuration x only."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import torch
from torch import Tensor, nn

from . import autodiff
from .auxstate import AuxDict, AuxParam
from .stacking import Stackable, shallow_clone


class WeightFunction(Stackable, nn.Module):
    """Base of every weight function.

    ``value(x, aux)`` returns (B,) and must be positive by construction. ``forward`` returns the value
    and ∇_x w (aux held fixed); the default gradient is autodiff, which keeps the graph so training
    reaches the parameters through the h_i terms of pullback*. ``is_constant`` weights skip h_i.
    """

    is_constant = False
    #: What w reads, for the premise check of docs/math.md §12 (``assembly/premises.py``): "nothing" (a constant),
    #: "aux" (aux state only, never the configuration), "radial" (only the distance from ``radial_center``, never
    #: decreasing with it, whatever its learned numbers) or "configuration" (anything else: the safe default).
    reads: str = "configuration"
    #: for a weight that reads "radial": the point it is radial about (numbers or an aux name)
    radial_center: AuxParam | None = None

    def __init__(self, in_dim: int, aux_dims: Mapping[str, int] | None = None):
        super().__init__()
        self.in_dim = int(in_dim)
        self.aux_dims = dict(aux_dims or {})

    def value(self, x: Tensor, aux: AuxDict | None) -> Tensor:  # pragma: no cover - abstract
        raise NotImplementedError

    def forward(self, x: Tensor, aux: AuxDict | None = None) -> tuple[Tensor, Tensor | None]:
        return self.value(x, aux), autodiff.gradient(lambda z: self.value(z, aux), x)

    def with_bind(self, bind: Mapping[str, str]) -> WeightFunction:
        """This function reading its aux inputs under other names (``bind``: its name -> the aux entry read), sharing
        its parameters: how a stacked group sees one shared weight bound differently on each edge. The default
        renames the aux entries of its ``AuxParam`` fields; a weight reading aux otherwise overrides it."""
        if not bind:
            return self
        view = shallow_clone(self)
        for name in self.stack_fields or ():
            p = getattr(self, name)
            if isinstance(p, AuxParam) and p.name is not None and p.name in bind:
                object.__setattr__(view, name, p.renamed(bind[p.name]))
                view.__dict__["_modules"].pop(name, None)
        return view


class BoundWeight(Stackable, nn.Module):
    """A (possibly shared) weight function as seen from one edge: aux inputs renamed by ``bind``."""

    def __init__(self, fn: WeightFunction, bind: Mapping[str, str] | None = None):
        super().__init__()
        self.fn = fn
        self.bind = dict(bind or {})

    @property
    def is_constant(self) -> bool:
        return bool(self.fn.is_constant)

    def forward(self, x: Tensor, aux: AuxDict | None):
        if self.bind and aux is not None:
            aux = {**aux, **{k: aux[v] for k, v in self.bind.items()}}
        return self.fn(x, aux)

    def stack_key(self):
        return self.fn.stack_key()

    @classmethod
    def stacked(cls, members: Sequence[BoundWeight], like: Tensor) -> nn.Module:
        """The members' functions, each reading its own edge's aux, stacked by their own class."""
        fns = [m.fn.with_bind(m.bind) for m in members]
        return type(fns[0]).stacked(fns, like)


def aux_features(names: Sequence[str], aux: AuxDict | None, batch: int | Sequence[int]) -> Tensor | None:
    """Concatenate the named aux tensors into (B, k) features (None when there are none); ``batch`` may be the
    leading shape, e.g. (1, B) for a group of one."""
    if not names:
        return None
    if aux is None:
        raise KeyError(f"aux state {list(names)} is required by a weight function but was not passed")
    parts = []
    for n in names:
        if n not in aux:
            raise KeyError(f"aux state '{n}' is required by a weight function but was not passed")
        parts.append(aux[n].expand(*(batch if isinstance(batch, (tuple, list)) else [batch]), -1))
    return torch.cat(parts, dim=-1)
