"""Pushforward and pullback* over a tree's plan (docs/math.md §9): the evaluation of eq. 6, level-batched.

Every group's quantities carry a leading member dimension, ``(G, B, ...)``: states, Jacobians, curvature terms,
weights, and RMPs. The math is the one of ``core/algebra.py``; a group only evaluates it for all its members at
once and sums each member's term of pullback* into its parent's row.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import overload

from torch import Tensor

from .algebra import Edge, NodeRMP, edge_contribution
from .groups import ROOT, Plan, Rows, assemble


@dataclass
class Passes:
    """What the passes computed, per node group: states ``(y, ẏ)``, edges and RMPs, each ``(G, B, ...)``."""

    states: list[tuple[Tensor, Tensor]]
    edges: list[Edge]
    rmps: list[NodeRMP]
    root: NodeRMP  # (B, ...)


@overload
def _full(t: Tensor, size: int) -> Tensor: ...


@overload
def _full(t: None, size: int) -> None: ...


def _full(t: Tensor | None, size: int) -> Tensor | None:
    """A group quantity with its member dimension spelled out (a map may answer ``(1, B, ...)`` for all)."""
    if t is None or t.shape[0] == size:
        return t
    return t.expand(size, *t.shape[1:])


def _maps(plan: Plan, q: Tensor, qd: Tensor, aux) -> tuple[dict[int, Tensor], dict[int, Tensor], list]:
    """Pushforward through every node group's map, parents' groups first."""
    x = {ROOT: q.unsqueeze(0)}
    xd = {ROOT: qd.unsqueeze(0)}
    jc = []
    for i, g in enumerate(plan.groups):
        y, yd, J, c = (_full(t, g.size) for t in g.map(g.parent.gather(x), g.parent.gather(xd), aux))
        x[i], xd[i] = y, yd
        jc.append((J, c))
    return x, xd, jc


def _weights(plan: Plan, x: Mapping[int, Tensor], aux) -> tuple[dict[int, Tensor], dict[int, Tensor | None]]:
    """Every weight group evaluated at its edges' parents' configurations."""
    w: dict[int, Tensor] = {}
    gw: dict[int, Tensor | None] = {}
    for k, wg in enumerate(plan.weights):
        xs = wg.inputs.gather(x)
        value, grad = wg.fn(xs, aux)
        w[k], gw[k] = _full(value, len(wg.edges)), _full(grad, len(wg.edges))
    return w, gw


def _gradients(rows: Rows, w: Mapping[int, Tensor], gw: Mapping[int, Tensor | None]) -> Tensor | None:
    """The members' ∇w, gathered as their weights are. A weight reading only aux state has none (∇w = 0, no h_i):
    None when no member's weight has one, zeros in the place of those missing when some do."""
    grads = {s: gw[s] for s in rows.sources}
    given = [g for g in grads.values() if g is not None]
    if not given:
        return None
    dim = given[0].shape[-1]
    return rows.gather({s: w[s].new_zeros(*w[s].shape, dim) if g is None else g for s, g in grads.items()})


def pushforward(plan: Plan, q: Tensor, qd: Tensor, aux: Mapping[str, Tensor] | None):
    """Every node group's state ``(y, ẏ)`` and edge. ``q``, ``qd``: the root's (B, d)."""
    x, xd, jc = _maps(plan, q, qd, aux)
    w, gw = _weights(plan, x, aux)
    edges = []
    for i, g in enumerate(plan.groups):
        J, c = jc[i]
        wi = gwi = None
        if g.weights is not None:
            wi = g.weights.gather(w)
            gwi = None if g.constant_weights else _gradients(g.weights, w, gw)
        edges.append(Edge(J=J, c=c, yd=xd[i], w=wi, grad_w=gwi, identity=g.identity))
    return x, xd, edges


def pullback(plan: Plan, x, xd, edges, lean: bool = False) -> Passes:
    """Every group's RMP, deepest groups first: a leaf group's from its leaf, an inner group's from the summed
    terms of its child groups; then the root's. ``lean``: f and M only (``Plan.lean`` trees, unmonitored)."""
    terms: dict[int, list[tuple[int, NodeRMP]]] = {}  # per group (and the root): its members' children's terms
    rmps: list[NodeRMP] = [None] * len(plan.groups)  # type: ignore[list-item]  # every slot is filled below
    for i in reversed(range(len(plan.groups))):
        g = plan.groups[i]
        if g.leaf is None:
            rmp = _gathered(terms[i], g.size)
        else:
            rmp = g.leaf.force(x[i], xd[i]) if lean else g.leaf(x[i], xd[i])
        rmps[i] = rmp
        term = edge_contribution(g.parent.gather(xd), edges[i], rmp)
        terms.setdefault(g.parent.sources[0], []).append((g.parent.first, term.map(g.parent.summed)))
    if ROOT not in terms:
        raise ValueError("the tree has no nodes below its root: pullback* needs at least one child")
    states = [(x[i], xd[i]) for i in range(len(plan.groups))]
    root = _gathered(terms[ROOT], 1).map(_first_row)
    return Passes(states=states, edges=edges, rmps=rmps, root=root)


def _first_row(t: Tensor) -> Tensor:
    return t[0]


def _gathered(pieces: list[tuple[int, NodeRMP]], size: int) -> NodeRMP:
    """A group's RMP from its members' children's terms (``pieces``: each covering rows from its first on)."""
    if len(pieces) == 1 and pieces[0][0] == 0 and pieces[0][1].f.shape[0] == size:
        return pieces[0][1]  # one child group covering every row: its terms are the group's
    starts = [first for first, _ in pieces]
    columns = zip(*(r.values() for _, r in pieces))  # field by field, every piece's
    return NodeRMP.of(None if vs[0] is None else assemble(list(zip(starts, vs)), size) for vs in columns)


def evaluate(plan: Plan, q: Tensor, qd: Tensor, aux: Mapping[str, Tensor] | None, lean: bool = False) -> Passes:
    """Pushforward, the weights, then pullback*: the root's RMP and every group's quantities (``lean``: f and M
    only, for a ``Plan.lean`` tree's policy)."""
    x, xd, edges = pushforward(plan, q, qd, aux)
    return pullback(plan, x, xd, edges, lean)
