"""Which parts of a tree are evaluated together: the plan of level-batched evaluation (docs/math.md §9).

- **Node groups.** Nodes at one depth whose parents lie in one group, and whose maps and leaves have equal
  ``stack_key`` s (``core/stacking.py``), evaluate their maps, their leaves (or the pullback* of their children)
  once, on tensors with a leading member dimension ``(G, B, ...)``. In the Franka tree the 15 kinematic points are
  one group, the 14 joint-limit barriers another, and every (control point × obstacle) distance a third.
- **Weight groups.** A weight reads only its parent's configuration and aux state, and is needed only by
  pullback*, so every weight of one kind in the whole tree evaluates as one batch after pushforward, whatever the
  node groups: the four weight networks of the 2d2level learner run as one batched matrix product per layer.
  Members using one weight function (a control point's obstacle weight, bound to each obstacle) are contiguous
  and equally many, so a stacked neural weight runs one product per layer for all its functions.

Where a group's inputs come from is a ``Rows``: rows of one earlier group, or of several concatenated.
"""

from __future__ import annotations

from collections.abc import Callable, Hashable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Generic, Protocol, TypeVar

import torch
from torch import Tensor, nn

from .algebra import NodeRMP
from .gds import LeafRMP
from .layout import TreeLayout, levels
from .stacking import Stackable
from .taskmap import TaskMap
from .weight import BoundWeight

ROOT = -1  # the source id of the root's state

M = TypeVar("M", bound=nn.Module)
S = TypeVar("S", bound=Stackable)


def _member_dim(t: Tensor) -> Tensor:
    return t.unsqueeze(0)


def _unsqueezed(out: Any) -> Any:
    """Outputs of one module as a group of one: a leading member dimension of 1 on every tensor."""
    if isinstance(out, Tensor):
        return out.unsqueeze(0)
    if isinstance(out, NodeRMP):
        return out.map(_member_dim)  # a lean one stays lean
    if isinstance(out, tuple):
        return tuple(_unsqueezed(o) for o in out)
    return out


class Alone(Generic[M]):
    """A module that runs on its own, seen as a group of one: inputs ``(1, B, ...)`` go in as ``(B, ...)`` and
    its outputs come back ``(1, B, ...)``. Not an ``nn.Module``: the tree already owns the module."""

    def __init__(self, module: M):
        self.module = module

    def __call__(self, *args: Any) -> Any:
        return _unsqueezed(self.module(*(a[0] if isinstance(a, Tensor) else a for a in args)))

    def force(self: Alone[LeafRMP], y: Tensor, yd: Tensor) -> NodeRMP:
        """A leaf's natural form only (``LeafRMP.force``)."""
        return _unsqueezed(self.module.force(y[0], yd[0]))


class LeafGroup(Protocol):
    """What pullback* calls on a node group's leaves, each ``(G, B, ...)``: their RMPs, or only their natural
    forms (``LeafRMP.force``)."""

    def __call__(self, y: Tensor, yd: Tensor) -> NodeRMP: ...

    def force(self, y: Tensor, yd: Tensor) -> NodeRMP: ...


def stacked(modules: Sequence[S], like: Tensor) -> Alone[S] | S | nn.Module:
    """One callable evaluating every module on ``(G, B, ...)`` inputs (stacked values in ``like``'s dtype and
    device). A single module that stacks takes such inputs itself (its numbers broadcast against any leading
    dimensions); one that does not runs ``Alone``."""
    if modules[0].stack_key() is None:
        return Alone(modules[0])
    if len(modules) == 1:
        return modules[0]
    return type(modules[0]).stacked(modules, like)


def direct(fn: Callable) -> Callable:
    """What a group calls: a module's ``forward`` itself (the tree's own modules take no hooks, and nn.Module's call
    machinery costs more than a map's arithmetic on one state), any other callable as it is."""
    return fn.forward if isinstance(fn, nn.Module) else fn


def stacked_leaves(leaves: Sequence[LeafRMP], like: Tensor) -> LeafGroup:
    """``stacked`` for leaves, whose groups also answer ``force``: a leaf, a leaf ``Alone``, or a class's group."""
    return stacked(leaves, like)  # type: ignore[return-value]  # a class's group is a bare nn.Module to mypy


@dataclass
class Rows:
    """Where a group's members find a value: in the ``(P, B, ...)`` tensors of the ``sources`` (group ids, or
    ``ROOT``), concatenated in that order (``size`` rows). ``index`` None: the one source's rows as they are (or its
    single row, broadcast); an int: that one row for every member (kept ``(1, B, ...)``); else a (G,) index.
    ``span`` (start, stop): the members read rows start..stop-1 of one source in order, each the same number of
    times in a row (a control point's obstacles, say), so their terms sum back by one segment sum."""

    sources: list[int]
    index: int | Tensor | None
    size: int
    span: tuple[int, int] | None = None

    @classmethod
    def of(cls, places: Sequence[tuple[int, int]], sizes: Mapping[int, int], device) -> Rows:
        """``places``: each member's (source, row); ``sizes``: each source's number of rows."""
        sources = list(dict.fromkeys(s for s, _ in places))
        start, offset = {}, 0
        for s in sources:
            start[s], offset = offset, offset + sizes[s]
        rows = [start[s] + r for s, r in places]
        span = _span(rows) if len(sources) == 1 else None
        if len(sources) == 1 and (offset == 1 or rows == list(range(offset))):
            return cls(sources, None, offset, span)
        if len(set(rows)) == 1:
            return cls(sources, rows[0], offset, span)
        return cls(sources, torch.tensor(rows, dtype=torch.long, device=device), offset, span)

    def gather(self, tensors: Mapping[int, Tensor]) -> Tensor:
        """The members' values: ``(G, B, ...)``, or ``(1, B, ...)`` when they all read one row."""
        t = tensors[self.sources[0]] if len(self.sources) == 1 else torch.cat([tensors[s] for s in self.sources])
        if self.index is None:
            return t
        if isinstance(self.index, int):
            return t[self.index : self.index + 1]
        if self.span is not None and self.span[1] - self.span[0] == self.index.shape[0]:
            return t[self.span[0] : self.span[1]]
        return t.index_select(0, self.index)

    @property
    def first(self) -> int:
        """The first row of the source that the members' summed terms (``summed``) begin at."""
        return self.span[0] if self.span is not None and self.size != 1 else 0

    def summed(self, t: Tensor) -> Tensor:
        """The members' ``(G, B, ...)`` terms summed into the rows they were gathered from (one source), from row
        ``first`` on."""
        if self.size == 1:
            return t if t.shape[0] == 1 else t.sum(0, keepdim=True)
        if self.span is not None:
            first, stop = self.span
            return t if t.shape[0] == stop - first else t.reshape(stop - first, -1, *t.shape[1:]).sum(1)
        index = torch.as_tensor(self.index, device=t.device).expand(t.shape[0])
        return t.new_zeros(self.size, *t.shape[1:]).index_add(0, index, t)


def _span(rows: list[int]) -> tuple[int, int] | None:
    """(start, stop) when ``rows`` is start, start, ..., start+1, start+1, ..., stop-1: every row equally often."""
    first, stop = rows[0], rows[-1] + 1
    if (stop - first) <= 0 or len(rows) % (stop - first):
        return None
    k = len(rows) // (stop - first)
    return (first, stop) if rows == [r for r in range(first, stop) for _ in range(k)] else None


def assemble(pieces: Sequence[tuple[int, Tensor]], size: int) -> Tensor:
    """A group's ``(size, B, ...)`` tensor from terms each covering rows [first, first + n): terms over the same rows
    are added; terms that tile the rows are concatenated, others added where they fall."""
    spans: dict[tuple[int, int], Tensor] = {}
    for first, t in pieces:
        key = (first, t.shape[0])
        spans[key] = t if key not in spans else spans[key] + t
    keys = sorted(spans)
    ends = [first + n for first, n in keys]
    if keys[0][0] == 0 and ends[-1] == size and all(e == k[0] for e, k in zip(ends, keys[1:])):
        return spans[keys[0]] if len(keys) == 1 else torch.cat([spans[k] for k in keys])
    t = next(iter(spans.values()))
    out = t.new_zeros(size, *t.shape[1:])
    for (first, n), part in spans.items():
        out = out.index_add(0, torch.arange(first, first + n, device=t.device), part)
    return out


@dataclass
class Group:
    """Nodes of one kind under one parent group: their maps and leaves evaluated as one batch."""

    nodes: list[str]
    parent: Rows  # the members' parents' states (one source: the parent group, or the root)
    map: Callable  # (x, ẋ, aux) -> (y, ẏ, J, J̇ẋ), each (G, B, ...)
    leaf: LeafGroup | None  # (y, ẏ) -> NodeRMP (G, B, ...); None: inner nodes, whose RMP is their children's
    identity: bool  # J = I: pullback* skips its products
    weights: Rows | None  # the members' weights, in the weight groups' outputs; None: unweighted
    constant_weights: bool  # every member's weight is constant: no ∇w, no h_i

    @property
    def size(self) -> int:
        return len(self.nodes)

    @property
    def slots(self) -> dict[str, int]:
        return {n: row for row, n in enumerate(self.nodes)}


@dataclass
class WeightGroup:
    """Weights of one kind anywhere in the tree, evaluated as one batch: ``(x, aux) -> (w (G, B), ∇w or None)``."""

    edges: list[str]  # the nodes whose incoming edges they weigh
    inputs: Rows  # the edges' parents' configurations, in the node groups' states
    fn: Callable


@dataclass
class Plan:
    groups: list[Group]  # depth by depth: parents' groups before their children's
    weights: list[WeightGroup]
    #: No weight varies with the configuration: no h_i asks for a child's L and G, so a policy that is not monitored
    #: needs only f and M from every leaf (decided once, from ``groups``: a policy asks at every call).
    lean: bool = field(init=False)

    def __post_init__(self) -> None:
        self.lean = all(g.weights is None or g.constant_weights for g in self.groups)


def _key(module: Any, node: str) -> Hashable:
    """A module's stacking key; a module that does not stack gets one of its own (a group of one)."""
    key = module.stack_key()
    return ("alone", node) if key is None else key


def plan(
    layout: TreeLayout,
    maps: Mapping[str, TaskMap],
    weights: Mapping[str, BoundWeight],
    rmps: Mapping[str, LeafRMP],
    like: Tensor,
) -> Plan:
    """The tree's node groups, depth by depth, and its weight groups; ``like``: a tensor of the tree's dtype and
    device, which stacked values and index tensors take."""
    device = like.device
    children = layout.children()
    where: dict[str, tuple[int, int]] = {layout.root: (ROOT, 0)}  # node -> (group, row)
    sizes: dict[int, int] = {ROOT: 1}
    runs: list[list[str]] = []
    for level in levels(children, layout.root):
        buckets: dict[Hashable, list[str]] = {}
        for n in level:
            leaf = ("inner",) if children[n] else _key(rmps[n], n)
            weight = None if n not in weights else bool(weights[n].is_constant)
            key = (where[layout.parents[n]][0], maps[n].in_dim, maps[n].out_dim, _key(maps[n], n), leaf, weight)
            buckets.setdefault(key, []).append(n)
        for run in buckets.values():
            sizes[len(runs)] = len(run)
            where.update({n: (len(runs), row) for row, n in enumerate(run)})
            runs.append(run)
    wgroups = _weight_groups(layout, weights, where, sizes, like)
    at = {n: (k, row) for k, wg in enumerate(wgroups) for row, n in enumerate(wg.edges)}
    wsizes = {k: len(wg.edges) for k, wg in enumerate(wgroups)}
    groups = []
    for run in runs:
        parent = Rows.of([where[layout.parents[n]] for n in run], sizes, device)
        weighted = run[0] in weights
        groups.append(
            Group(
                nodes=run,
                parent=parent,
                map=direct(stacked([maps[n] for n in run], like)),
                leaf=None if children[run[0]] else stacked_leaves([rmps[n] for n in run], like),
                identity=bool(maps[run[0]].identity_jacobian),
                weights=Rows.of([at[n] for n in run], wsizes, device) if weighted else None,
                constant_weights=weighted and bool(weights[run[0]].is_constant),
            )
        )
    return Plan(groups, wgroups)


def _weight_groups(layout: TreeLayout, weights: Mapping[str, BoundWeight], where, sizes, like) -> list[WeightGroup]:
    buckets: dict[Hashable, list[str]] = {}
    for n in sorted(weights, key=lambda n: where[n]):  # pushforward order
        buckets.setdefault((weights[n].fn.in_dim, _key(weights[n], n)), []).append(n)
    out = []
    for members in buckets.values():
        for run in _by_shared_function(members, weights):
            inputs = Rows.of([where[layout.parents[n]] for n in run], sizes, like.device)
            out.append(WeightGroup(edges=run, inputs=inputs, fn=direct(stacked([weights[n] for n in run], like))))
    return out


def _by_shared_function(nodes: list[str], weights: Mapping[str, Any]) -> list[list[str]]:
    """``nodes`` ordered so that edges using one weight function are contiguous, split into runs in which every
    function is used equally often."""
    fn_of = {n: id(weights[n].fn) for n in nodes}
    first = {f: i for i, f in reversed(list(enumerate(fn_of[n] for n in nodes)))}
    count = {f: sum(1 for n in nodes if fn_of[n] == f) for f in first}
    runs: dict[int, list[str]] = {}
    for n in sorted(nodes, key=lambda n: first[fn_of[n]]):
        runs.setdefault(count[fn_of[n]], []).append(n)
    return list(runs.values())
