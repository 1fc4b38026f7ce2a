"""Whether a tree's goal is its only equilibrium for any parameters: the five premises of docs/math.md §12, read
off the tree's structure and what its parts declare, never from rollouts.

Theorem 2 (V_r never increases) holds for every tree of GDS leaves; convergence to the goal needs more. Each
premise holds *by construction* when the parts it concerns declare it whatever their (learned) numbers:

1. every map from the root down to the attractor is a diffeomorphism of ℝⁿ onto ℝⁿ (``TaskMap.bijective``);
2. there is an attractor whose potential is radially unbounded with one minimum (``LeafRMP.potential_kind``
   "attractor");
3. no weight on the attractor's path creates an equilibrium (``WeightFunction.reads``): a constant, a weight of aux
   state only, or a radial weight about the attractor's own centre (the maps between them identities, the centre
   its origin);
4. a damper whose damping is positive definite (``LeafRMP.damps``) on a space the root maps onto bijectively;
5. no leaf besides the attractor has a potential (``potential_kind`` "none"), and every leaf is a GDS.

A premise that cannot be shown so is reported as broken, naming the node, edge or leaf: the tree still runs, and
Theorem 2 still holds, but rollouts may come to rest away from the goal.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from ..core.gds import GDS, LeafRMP
from ..core.tree import RMPTree
from ..core.weight import BoundWeight

#: what each premise says, as docs/math.md §12 states it
STATEMENTS = {
    1: "the maps from the root to the attractor are diffeomorphisms onto R^n",
    2: "an attractor whose potential is radially unbounded with one minimum",
    3: "the attractor's weights create no equilibrium",
    4: "a damper: B_r positive definite",
    5: "no other potential leaves (and every leaf a GDS)",
}


@dataclass
class Premise:
    """One premise of §12: whether the tree meets it by construction, and if not, what breaks it."""

    number: int
    statement: str
    broken_by: list[str] = field(default_factory=list)

    @property
    def holds(self) -> bool:
        return not self.broken_by


@dataclass
class PremiseReport:
    """The five premises for one tree; ``holds``: the goal is its only equilibrium for any parameters."""

    premises: list[Premise]

    @property
    def holds(self) -> bool:
        return all(p.holds for p in self.premises)

    @property
    def broken(self) -> list[int]:
        return [p.number for p in self.premises if not p.holds]

    def line(self) -> str:
        """One sentence for a run's log and ``rmpfusion-validate``."""
        if self.holds:
            return (
                "the goal is the only equilibrium for any parameters (docs/math.md §12: premises 1-5 hold by "
                "construction)"
            )
        why = "; ".join(f"premise {p.number} broken by {_some(p.broken_by)}" for p in self.premises if p.broken_by)
        return f"equilibria other than the goal are possible ({why}; docs/math.md §12)"

    def as_dict(self) -> dict:
        """What metrics.json records."""
        return {
            "goal_only_equilibrium": self.holds,
            "broken": self.broken,
            "premises": {
                str(p.number): {"statement": p.statement, "holds": p.holds, "broken_by": list(p.broken_by)}
                for p in self.premises
            },
        }


#: at most this many culprits of one premise are named in the one-line report (metrics.json keeps them all)
NAMED = 3


def _some(items: list[str]) -> str:
    more = len(items) - NAMED
    return ", ".join(items[:NAMED]) + (f" and {more} more" if more > 0 else "")


def _path(tree: RMPTree, node: str) -> list[str]:
    """The nodes from the root's child down to ``node`` (the edges on its path, by their child node)."""
    out = []
    while node != tree.root_name:
        out.append(node)
        node = tree.parent_of[node]
    return out[::-1]


def _label(tree: RMPTree, node: str) -> str:
    return tree.layout.labels[node].map


def _leaf_label(tree: RMPTree, node: str) -> str:
    return tree.layout.labels[node].rmp or type(tree.rmps[node]).__name__


def _weight_label(tree: RMPTree, node: str) -> str:
    return tree.layout.labels[node].weight or type(_bound(tree, node).fn).__name__


def _bound(tree: RMPTree, node: str) -> BoundWeight:
    module = tree.weights[node]
    assert isinstance(module, BoundWeight), f"edge '{node}' holds a {type(module).__name__}"
    return module


def _non_bijective(tree: RMPTree, nodes: list[str]) -> list[str]:
    return [f"the map '{_label(tree, n)}' of node '{n}'" for n in nodes if not bool(tree.maps[n].bijective)]


def _radial_about_attractor(tree: RMPTree, edge: str, path: list[str]) -> bool:
    """A radial weight on ``edge`` is radial about the attractor's centre: the maps from the edge's parent down to
    the attractor are identities and the centre is the origin there (the attractor's goal)."""
    below = path[path.index(edge) :]
    if any(_label(tree, n) != "identity" for n in below):
        return False
    center = _bound(tree, edge).fn.radial_center
    if center is None or center.name is not None or center.values is None:
        return False
    return all(float(v) == 0.0 for v in _flat(center.values))


def _flat(values) -> list:
    return [x for v in values for x in _flat(v)] if isinstance(values, (list, tuple)) else [values]


def _weight_problems(tree: RMPTree, path: list[str]) -> list[str]:
    out = []
    for n in path:
        if n not in tree.weights:
            continue
        reads = _bound(tree, n).fn.reads
        what = f"the weight '{_weight_label(tree, n)}' on edge '{n}'"
        if reads == "configuration":
            out.append(f"{what}, which reads the configuration")
        elif reads == "radial" and not _radial_about_attractor(tree, n, path):
            out.append(f"{what}, radial about a point that is not the attractor's centre")
        elif reads not in ("nothing", "aux", "radial"):
            out.append(f"{what}, which declares that it reads '{reads}'")
    return out


def _damped(tree: RMPTree, leaves: dict[str, LeafRMP]) -> list[str]:
    """The leaves whose damping is positive definite on a space the root maps onto bijectively."""
    return [n for n, leaf in leaves.items() if leaf.damps() and not _non_bijective(tree, _path(tree, n))]


def _other_potentials(tree: RMPTree, leaves: dict[str, LeafRMP], attractor: str | None) -> list[str]:
    """Premise 5's culprits, one entry per leaf type: the leaves besides ``attractor`` that have a potential or are
    not GDSs."""
    found: dict[tuple[str, str], list[str]] = {}
    for n, leaf in leaves.items():
        if n == attractor:
            continue
        if not isinstance(leaf, GDS):
            found.setdefault((_leaf_label(tree, n), "not a GDS"), []).append(n)
        elif leaf.potential_kind == "attractor":
            found.setdefault((_leaf_label(tree, n), "another attractor"), []).append(n)
        elif leaf.potential_kind != "none":
            found.setdefault((_leaf_label(tree, n), "a potential"), []).append(n)
    return [
        f"the leaf '{kind}' on node '{nodes[0]}' ({why})"
        if len(nodes) == 1
        else f"{len(nodes)} '{kind}' leaves (nodes {_some([repr(n) for n in nodes])}: {why})"
        for (kind, why), nodes in found.items()
    ]


def check_premises(tree: RMPTree) -> PremiseReport:
    """The premises of docs/math.md §12 for ``tree``, each decided by construction (see the module docstring).
    Premises 1 and 3 are checked for every attractor; the first (breadth-first) is the one premise 5 keeps."""
    leaves = {n: leaf for n in tree.order if n in tree.rmps and isinstance(leaf := tree.rmps[n], LeafRMP)}
    attractors = [n for n, leaf in leaves.items() if leaf.potential_kind == "attractor"]
    premises = {k: Premise(k, s) for k, s in STATEMENTS.items()}
    if not attractors:
        premises[2].broken_by.append("the tree's leaves: none is an attractor with one minimum (goal_attractor)")
    for attractor in attractors:
        path = _path(tree, attractor)
        premises[1].broken_by += [b for b in _non_bijective(tree, path) if b not in premises[1].broken_by]
        premises[3].broken_by += [b for b in _weight_problems(tree, path) if b not in premises[3].broken_by]
    if not _damped(tree, leaves):
        premises[4].broken_by.append(
            "the tree's leaves: none damps with positive definite B on a space the root maps onto bijectively"
        )
    premises[5].broken_by += _other_potentials(tree, leaves, attractors[0] if attractors else None)
    return PremiseReport(list(premises.values()))
