"""Stacking: several modules of one kind evaluated as one batch (docs/math.md §9, level-batched evaluation).

A tree groups the nodes that sit under one parent group and whose map, weight and leaf are of one kind (equal
``stack_key``). A group of G members evaluates its map, its weight and its leaf once, on tensors with a leading
member dimension, ``(G, B, ...)``, instead of G times on ``(B, ...)``: the 14 joint-limit barriers of a 7-joint
arm become one 14-wide barrier, the (control point × obstacle) distances one batch.

A module takes part by declaring how its members stack (``Stackable``):

- ``stack_fields``: the names of its per-member numbers, fixed-size tensors and aux-or-constant parameters. A
  number (a Python float, or a 0-d tensor when it is learned) only ever meets per-sample scalars of shape (B,) in
  the module's math; where it must meet a vector or a matrix, the math writes ``spread(number, k)`` (k more
  trailing dimensions). Stacking makes the numbers of G members a ``(G, 1)`` tensor, a fixed-size tensor field
  (e.g. a 3-vector offset) ``(G, 1, *shape)``, and an aux-or-constant parameter (``AuxParam``) a ``StackedAux``,
  so they broadcast the same way against ``(G, B, ...)`` quantities. The members and the group run the very same
  code: nothing is written twice, and a module on its own computes with plain floats.
- ``stack_settings()``: what must be equal for modules to share a group (flags, sizes, structure).

A module whose ``stack_fields`` is None (the default, e.g. a plugin that declares nothing) is evaluated on its
own, exactly as before. A class whose members need more than replaced fields (the neural weight stacks its
layers into batched matrix products; forward kinematics computes one pass of the chain for every link) overrides
the classmethod ``stacked``.

A learned number is computed from the module's own parameters (e.g. a property ``gain = exp(log_gain)``): a group of
such modules stacks the members' parameters again at every call (``LiveStack``), so the number is computed for
every member from its own parameters and gradients reach each of them; constants are stacked once, when the tree
plans its groups.
"""

from __future__ import annotations

import copy
from collections.abc import Hashable, Sequence
from typing import TYPE_CHECKING, Any, ClassVar, TypeVar

import torch
from torch import Tensor, nn

from .auxstate import AuxParam, StackedAux
from .learnable import learned_ranges

if TYPE_CHECKING:
    from typing import Self  # Python 3.11; annotations only, which are not evaluated


M = TypeVar("M", bound=nn.Module)


def shallow_clone(module: M) -> M:
    """A new module object sharing ``module``'s submodules, parameters and buffers, whose own attributes can be
    replaced without touching ``module`` (its registries of parameters, buffers and submodules are copies)."""
    new = object.__new__(type(module))
    new.__dict__ = dict(module.__dict__)
    for registry in ("_parameters", "_buffers", "_modules", "_non_persistent_buffers_set"):
        if registry in new.__dict__:
            new.__dict__[registry] = copy.copy(module.__dict__[registry])
    return new


def spread(number: float | Tensor, trailing: int) -> float | Tensor:
    """A number next to a quantity with ``trailing`` more dimensions than a per-sample scalar: a float or 0-d tensor
    as it is, a group's ``(G, 1)`` numbers as ``(G, 1, 1, ...)``."""
    if isinstance(number, Tensor) and number.dim() > 0:
        return number.reshape(*number.shape, *(1,) * trailing)
    return number


def _replace(module: nn.Module, name: str, value: Any) -> None:
    """Set ``name`` on ``module`` as a plain attribute (a group's stacked values are not state to save)."""
    for registry in ("_parameters", "_buffers", "_modules"):
        module.__dict__[registry].pop(name, None)
    object.__setattr__(module, name, value)


def stack_values(values: Sequence[Any], like: Tensor) -> Tensor:
    """Members' numbers or fixed-size tensors (each of one shape s) as one ``(G, 1, *s)`` tensor in ``like``'s
    dtype and device (integers stay integers): broadcasting against ``(G, B, ...)`` as each member's value
    broadcasts against its own ``(B, ...)``."""
    if all(isinstance(v, (bool, int)) for v in values):
        return torch.tensor(values, dtype=torch.long, device=like.device).unsqueeze(1)
    if all(isinstance(v, (int, float)) for v in values):
        return torch.tensor(values, dtype=like.dtype, device=like.device).unsqueeze(1)
    t = torch.stack([torch.as_tensor(v) for v in values]).unsqueeze(1)
    return t.to(device=like.device, dtype=like.dtype if t.is_floating_point() else t.dtype)


def _learned(value: Any) -> bool:
    return isinstance(value, Tensor) and value.requires_grad


class Stackable(nn.Module):
    """Base of task maps, weights and leaves (all modules): how members of one kind are evaluated as one batch (see
    the module docstring). ``stack_fields`` None: not stackable (each instance runs alone)."""

    stack_fields: ClassVar[tuple[str, ...] | None] = None

    def stack_settings(self) -> tuple:
        """Settings that must be equal across a group's members besides the class (sizes, flags, structure)."""
        return ()

    def stack_key(self) -> Hashable | None:
        """Modules with equal keys can be evaluated as one group; None: this module runs alone."""
        if self.stack_fields is None:
            return None
        return (type(self), self.stack_settings(), self.learned_signature())

    def learned_signature(self) -> tuple:
        """Which numbers are learned and in which ranges: members share them or no group (a group computes every
        member's learned numbers from restacked raw parameters through the first member's ranges)."""
        return tuple(sorted(learned_ranges(self).items()))

    @classmethod
    def stacked(cls, members: Sequence[Self], like: Tensor) -> nn.Module:
        """One module evaluating every member on ``(G, B, ...)`` inputs (member g with member g's numbers), its
        stacked values in ``like``'s dtype and device (the tree's). Members must share ``stack_key``. Learned
        numbers are stacked at each call (``LiveStack``)."""
        group = shallow_clone(members[0])
        for name in cls.stack_fields or ():
            values = [getattr(m, name) for m in members]
            if all(v is None for v in values):  # an optional part none of them has (stack_settings says so)
                continue
            if isinstance(values[0], AuxParam):
                _replace(group, name, StackedAux(values))
            elif not any(_learned(v) for v in values):  # learned ones follow the members' parameters
                _replace(group, name, stack_values(values, like))
        own = list(members[0]._parameters)
        return LiveStack(group, members, own, like) if own else group


class LiveStack(nn.Module):
    """A group whose members own parameters (learned numbers): the members' parameters are stacked again before
    every evaluation, as ``(G, 1, *shape)``, so what the group computes from them is each member's and the
    gradient reaches each member's own parameters."""

    def __init__(self, group: nn.Module, members: Sequence[nn.Module], names: Sequence[str], like: Tensor):
        super().__init__()
        object.__setattr__(self, "group", group)  # not a submodule: the members own the parameters
        object.__setattr__(self, "members", list(members))
        object.__setattr__(self, "names", list(names))

    def _restack(self) -> nn.Module:
        for name in self.names:
            _replace(self.group, name, torch.stack([m._parameters[name] for m in self.members]).unsqueeze(1))
        return self.group

    def forward(self, *args, **kwargs):
        return self._restack()(*args, **kwargs)

    def force(self, *args):
        """A leaf group's natural form only (``LeafRMP.force``)."""
        return self._restack().force(*args)

    def __getattr__(self, name: str):
        if name in ("group", "members", "names"):
            return self.__dict__[name]
        return getattr(self.__dict__["group"], name)
