"""Build a tree: a validated spec (docs/architecture.md) made into an ``RMPTree`` through the registries."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any, TypeVar

import torch
from torch import nn

from ..core.taskmap import TaskMap
from ..core.tree import BoundWeight, NodeLabel, RMPTree, TreeLayout, breadth_first
from ..core.weight import WeightFunction
from ..registry import LEAF_RMPS, TASK_MAPS, WEIGHTS, Registry
from .errors import ConfigError, Issue
from .leaf_check import leaf_contract_message, leaf_problem
from .spec import TreeSpec, shared_ref, validate_tree_spec, weight_label

Built = TypeVar("Built")


def _build(registry: Registry[Callable[..., Built]], block: Any, *args: Any) -> Built:
    """The module of a validated block: its entry's class called with the block (its parameter model)."""
    return registry.get(block.type).obj(block, *args)


def _coordinates_mismatch(leaf: str, reads: str | None, given: str | None) -> str:
    """Why a leaf cannot read its node's map (TaskMap.coordinates / LeafRMP.coordinates), and the fix."""
    if reads is None:
        return (
            f"'{leaf}' reads plain coordinates but the map gives the output of a '{given}' map; put a leaf that "
            f"reads it here, or change the map"
        )
    gives = "plain coordinates" if given is None else f"the output of a '{given}' map"
    return f"'{leaf}' reads the output of a '{reads}' map, but the map here gives {gives}; put it under a {reads} map"


class _Builder:
    """Builds one tree's modules in pushforward order, collecting every problem with its YAML path."""

    def __init__(self, ts: TreeSpec, where: str, weight_paths: Mapping[str, str], check_leaves: bool = True):
        self.ts, self.where, self.weight_paths = ts, where, dict(weight_paths)
        self.check_leaves = check_leaves
        self.leaves_checked: dict[tuple[str, int], str | None] = {}  # (leaf spec, dim) -> its problem, once each
        self.aux = dict(ts.aux)
        self.dims = {ts.root.name: ts.root.dim}
        self.maps: dict[str, TaskMap] = {}
        self.weights: dict[str, BoundWeight] = {}
        self.rmps: dict[str, nn.Module] = {}
        self.shared: dict[str, tuple[WeightFunction, int]] = {}  # built shared weights and their parent dimension
        self.issues: list[Issue] = []

    def unused_shared(self) -> None:
        used = {ref.shared for nd in self.ts.nodes.values() if (ref := shared_ref(nd.weight)) is not None}
        for name in self.ts.shared_weights:
            if name not in used:
                self.issues.append(
                    Issue(f"{self.where}.shared_weights.{name}", "declared but used by no edge; remove it")
                )

    def node(self, n: str) -> None:
        nd, p = self.ts.nodes[n], f"{self.where}.nodes.{n}"
        in_dim = self.dims[nd.parent]
        try:
            self.maps[n] = _build(TASK_MAPS, nd.map, in_dim, self.aux)
            self.dims[n] = self.maps[n].out_dim
        except Exception as e:  # noqa: BLE001 - reported with its path
            self.issues.append(Issue(f"{p}.map", str(e)))
            return
        if nd.weight is not None:
            try:
                self.weights[n] = self.weight(nd.weight, in_dim)
            except Exception as e:  # noqa: BLE001
                self.issues.append(self.weight_issue(n, str(e)))
        if nd.rmp is not None:
            self.leaf(n, nd.rmp, p)

    def weight_issue(self, n: str, message: str) -> Issue:
        """A weight's problem at the config path it was written at: the node's, or the expert's or learner's
        block that put it there (``weight_paths``), naming the edge when that path does not."""
        path = self.weight_paths.get(n, f"{self.where}.nodes.{n}.weight")
        return Issue(path, message if n in path.split(".") else f"on edge '{n}': {message}")

    def weight(self, spec, in_dim: int) -> BoundWeight:
        ref = shared_ref(spec)
        if ref is None:
            return BoundWeight(_build(WEIGHTS, spec, in_dim, self.aux))
        bad = [v for v in ref.bind.values() if v not in self.aux]
        if bad:
            raise ValueError(f"bind refers to undeclared aux {bad} (declared: {sorted(self.aux)})")
        if ref.shared not in self.shared:  # a shared weight's parent dimension is that of the first edge using it
            self.shared[ref.shared] = (_build(WEIGHTS, self.ts.shared_weights[ref.shared], in_dim, self.aux), in_dim)
        fn, d = self.shared[ref.shared]
        if d != in_dim:
            raise ValueError(f"shared weight '{ref.shared}' is used on parents of dimension {d} and {in_dim}")
        return BoundWeight(fn, ref.bind)

    def leaf(self, n: str, spec, p: str) -> None:
        leaf = LEAF_RMPS.get(spec.type).obj
        fixed = leaf.dim
        if fixed is not None and fixed != self.dims[n]:
            self.issues.append(
                Issue(
                    f"{p}.rmp",
                    f"'{spec.type}' is {fixed}-dimensional but the map gives dimension "
                    f"{self.dims[n]}; change the map or the rmp",
                )
            )
            return
        given = self.maps[n].coordinates
        if leaf.coordinates != given:
            self.issues.append(Issue(f"{p}.rmp", _coordinates_mismatch(spec.type, leaf.coordinates, given)))
            return
        try:
            self.rmps[n] = _build(LEAF_RMPS, spec, self.dims[n])
        except Exception as e:  # noqa: BLE001
            self.issues.append(Issue(f"{p}.rmp", str(e)))
            return
        if self.check_leaves and (why := self.contract(spec, self.rmps[n], self.dims[n])) is not None:
            self.issues.append(Issue(f"{p}.rmp", leaf_contract_message(spec.type, why)))

    def contract(self, spec, leaf: nn.Module, dim: int) -> str | None:
        """The leaf's breach of the leaf contract (``leaf_check.py``), checked once per distinct leaf."""
        key = (spec.model_dump_json(), dim)
        if key not in self.leaves_checked:
            try:
                self.leaves_checked[key] = leaf_problem(leaf, dim)
            except Exception as e:  # noqa: BLE001 - reported with the leaf's path
                self.leaves_checked[key] = f"it raised {type(e).__name__}: {e}"
        return self.leaves_checked[key]

    def layout(self) -> TreeLayout:
        ts = self.ts
        labels = {
            n: NodeLabel(nd.map.type, weight_label(nd.weight), None if nd.rmp is None else nd.rmp.type)
            for n, nd in ts.nodes.items()
        }
        return TreeLayout(ts.root.name, ts.root.dim, dict(ts.aux), {n: nd.parent for n, nd in ts.nodes.items()}, labels)


def build_tree(
    spec: Mapping[str, Any] | TreeSpec,
    aux_dims: Mapping[str, int] | None = None,
    dtype: torch.dtype | None = torch.float64,
    where: str = "tree",
    resolve_method: str = "solve",
    check_finite: bool = True,
    weight_paths: Mapping[str, str] | None = None,
    check_leaves: bool = True,
) -> RMPTree:
    """Validate a tree spec (docs/architecture.md §2) and assemble its modules through the registries.

    ``aux_dims`` adds to (or overrides) the spec's ``aux`` declarations, e.g. from the environment.
    All problems are reported together in one ConfigError whose lines name YAML paths.

    ``dtype`` is the one floating dtype of the tree's constants and parameters (None: torch's current default).
    Every registered class builds its constants in float64 from the spec's Python numbers
    (``rmpfusion.core.auxstate.constant``); the built tree is then cast to ``dtype``, so a constant is rounded
    at most once, to the dtype the tree computes in.

    ``weight_paths`` names where the weight of a node was written when that is not the tree's own node (the
    expert's ``expert.<node>``, a learner's ``learners.<name>.weights``), so its problems are reported there.

    ``check_leaves`` tries every leaf on sample states (``leaf_check.py``) and refuses one that breaks the leaf
    contract; only a test of what a tree does with a broken leaf turns it off.
    """
    ts = validate_tree_spec(spec, where)
    if aux_dims:
        ts = ts.model_copy(update={"aux": {**ts.aux, **dict(aux_dims)}})
    b = _Builder(ts, where, weight_paths or {}, check_leaves)
    b.unused_shared()
    children: dict[str, list[str]] = {}
    for n, nd in ts.nodes.items():
        children.setdefault(nd.parent, []).append(n)
    for n in breadth_first(children, ts.root.name):
        b.node(n)
    if b.issues:
        raise ConfigError(b.issues)
    shared = {k: v[0] for k, v in b.shared.items()}
    tree = RMPTree(b.layout(), b.maps, b.weights, b.rmps, shared, resolve_method, check_finite)
    return tree.to(torch.get_default_dtype() if dtype is None else dtype)
