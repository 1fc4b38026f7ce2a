"""The shape of a tree, apart from its modules: root, aux state, each node's parent, what each node is made of."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass


@dataclass(frozen=True)
class NodeLabel:
    """What a node is made of, by registered name, for messages and ``describe``: map, weight, leaf RMP."""

    map: str
    weight: str | None = None  # a weight type, or ``shared:<name>`` for a shared weight
    rmp: str | None = None


@dataclass(frozen=True)
class TreeLayout:
    """The shape of a tree: root name and dimension, the aux state it reads, each node's parent (in declaration
    order) and what it is made of."""

    root: str
    dim: int
    aux_dims: Mapping[str, int]
    parents: Mapping[str, str]
    labels: Mapping[str, NodeLabel]

    def children(self) -> dict[str, list[str]]:
        """Each node's children (the root's too), in declaration order."""
        out: dict[str, list[str]] = {self.root: [], **{n: [] for n in self.parents}}
        for n, parent in self.parents.items():
            out[parent].append(n)
        return out


def breadth_first(children: Mapping[str, list[str]], root: str) -> list[str]:
    """Every node below ``root``, parents before children: the pushforward order (reversed: pullback*)."""
    order: list[str] = []
    frontier = [root]
    while frontier:
        frontier = [c for p in frontier for c in children.get(p, [])]
        order += frontier
    return order


def levels(children: Mapping[str, list[str]], root: str) -> list[list[str]]:
    """The nodes at depth 1, 2, ... below ``root``, each level in breadth-first order."""
    out: list[list[str]] = []
    frontier = [root]
    while True:
        frontier = [c for p in frontier for c in children.get(p, [])]
        if not frontier:
            return out
        out.append(frontier)
