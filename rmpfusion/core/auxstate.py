"""Parameters that are either constants or named auxiliary state (docs/math.md §10).

A YAML value like ``center: [0, 0]`` is a constant; ``center: obstacle_center`` names a per-sample aux
tensor of shape (B, k) passed at call time. Both resolve to something broadcastable against (B, k).

Constants are built in float64 (``constant``), the precision of the Python numbers they come from, whatever
torch's default dtype is; ``build_tree`` then casts the whole tree to its dtype (float64 unless asked), so a
YAML number is rounded at most once, to the dtype the tree computes in.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Protocol

import torch
from torch import Tensor, nn

AuxOrValue = str | float | Sequence[float]
AuxDict = Mapping[str, Tensor]

CONSTANT_DTYPE = torch.float64  # what every registered class builds its constants in (build_tree casts after)


def constant(value) -> Tensor:
    """A Python number, or nested lists of them, as an exact float64 tensor: the one way a registered map, leaf
    or weight turns a parameter into a tensor (a buffer the tree's ``.to(dtype)`` then casts)."""
    return torch.as_tensor(value, dtype=CONSTANT_DTYPE)


class AuxSource(Protocol):
    """Makes the aux entries a tree reads from fewer, larger inputs, inside the tree's evaluation (so inside its
    compiled code): e.g. run-time obstacle sets, passed as one ``(B, N_max, k)`` tensor per field and made into one
    entry per member (``scenes/sets.py::SetsSource``). A compiled call costs about a microsecond per input tensor
    before any arithmetic, so hundreds of per-member entries passed from outside would cost more than the tree."""

    #: what the caller passes beside the tree's other aux: name -> per-sample shape
    inputs: Mapping[str, tuple[int, ...]]

    def __call__(self, q: Tensor, given: AuxDict) -> dict[str, Tensor]:
        """The entries made from ``given`` at configurations ``q`` (B, d), each (B, k)."""
        ...


class AuxParam(nn.Module):
    """A constant buffer or a reference to an aux entry; ``dim`` is known at build time."""

    const: Tensor | None  # the constant's buffer; None exactly when ``name`` reads an aux entry

    def __init__(self, value: AuxOrValue, aux_dims: Mapping[str, int], what: str):
        super().__init__()
        if isinstance(value, str):
            if value not in aux_dims:
                known = ", ".join(sorted(aux_dims)) or "none declared"
                raise ValueError(f"{what}: aux name '{value}' is not declared (declared aux: {known})")
            self.name: str | None = value
            self.dim = int(aux_dims[value])
            self.register_buffer("const", None)
        else:
            t = constant(value).reshape(-1)
            self.name = None
            self.dim = t.numel()
            self.register_buffer("const", t)
        self.values = None if self.name is not None else tuple(t.tolist())  # the numbers as written

    def forward(self, aux: AuxDict | None) -> Tensor:
        """(B, k) for aux, (k,) for a constant: both broadcast against a (B, k) coordinate."""
        if self.name is None:
            assert self.const is not None, "a parameter without an aux name is a constant"
            return self.const
        if aux is None or self.name not in aux:
            raise KeyError(f"aux state '{self.name}' is required by this tree but was not passed")
        return aux[self.name]

    #: read in every evaluation of its map and never hooked: a call is its ``forward``, without nn.Module's call
    #: machinery (which costs more than the read itself)
    __call__ = forward

    def renamed(self, name: str) -> AuxParam:
        """The same parameter reading the aux entry ``name`` (a shared weight bound to one edge's entries)."""
        if self.name is None:
            return self
        other = AuxParam.__new__(AuxParam)
        nn.Module.__init__(other)
        other.name, other.dim, other.values = name, self.dim, None
        other.register_buffer("const", None)
        return other

    def extra_repr(self) -> str:
        return f"aux={self.name!r}" if self.const is None else f"const={self.const.tolist()}"


class StackedAux(nn.Module):
    """The ``AuxParam`` s of a group's members as one tensor: ``(G, B, k)`` rows, member g reading its own aux entry
    or constant (docs/math.md §9). Where every member reads the same entry it stays ``(1, B, k)``, and where every
    member has a constant it is ``(G, 1, k)`` (``(1, 1, k)`` if they are all equal): both broadcast against
    ``(G, B, k)`` without copies. The aux entries a group reads are gathered with one ``stack`` and one index."""

    consts: Tensor | None  # the members' constants, stacked; None when every member reads an aux entry
    index: Tensor | None  # member g's row among [aux entries, constants]; None when the rows are already in order

    def __init__(self, params: Sequence[AuxParam]):
        super().__init__()
        dims = {p.dim for p in params}
        if len(dims) != 1:
            raise ValueError(f"stacked aux parameters must share one dimension, got {sorted(dims)}")
        self.dim = dims.pop()
        self.size = len(params)
        names = [p.name for p in params]
        self.names = list(dict.fromkeys(n for n in names if n is not None))  # each entry read once, in order
        consts = [p.const for p in params if p.const is not None]  # the members without an aux name
        self.register_buffer("consts", torch.stack(consts) if consts else None, persistent=False)
        if consts and len(consts) == len(params) and len({p.values for p in params}) == 1:
            self.register_buffer("consts", consts[0].unsqueeze(0), persistent=False)
        # member g's row in cat([stacked aux entries, constants]): read when members mix entries and constants
        order, k = [], 0
        for n in names:
            if n is None:
                order.append(len(self.names) + k)
                k += 1
            else:
                order.append(self.names.index(n))
        identity = order == list(range(len(params))) and not consts
        self.register_buffer("index", None if identity or not self.names else torch.tensor(order), persistent=False)

    def forward(self, aux: AuxDict | None) -> Tensor:
        if not self.names:  # constants only: (G or 1, 1, k)
            assert self.consts is not None, "members without aux names all have constants"
            return self.consts.unsqueeze(1)
        if aux is None or any(n not in aux for n in self.names):
            missing = [n for n in self.names if aux is None or n not in aux]
            raise KeyError(f"aux state {missing} is required by this tree but was not passed")
        if len(self.names) == 1 and self.consts is None:
            return aux[self.names[0]].unsqueeze(0)  # one entry for every member: (1, B, k)
        rows = torch.stack([aux[n] for n in self.names])
        if self.consts is not None:
            rows = torch.cat([rows, self.consts.unsqueeze(1).expand(-1, rows.shape[1], -1).to(rows)])
        return rows if self.index is None else rows.index_select(0, self.index)

    __call__ = forward  # as AuxParam's
