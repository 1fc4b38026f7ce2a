"""Put weight functions on the edges of a tree spec: the expert and learner-rmp are the same tree with
different weights, so both are derived from one weightless spec rather than written twice."""

from __future__ import annotations

import copy
from collections.abc import Mapping
from typing import Any

from pydantic import BaseModel

from .errors import ConfigError, Issue

#: A tree spec as the functions here take it: plain data, or validated (a pydantic model, e.g. ``TreeSpec``).
SpecData = Mapping[str, Any] | BaseModel


def plain_data(value: Any) -> Any:
    """A deep, plain-data copy of a spec or block, validated (a pydantic model) or not."""
    if isinstance(value, BaseModel):
        return value.model_dump()
    return copy.deepcopy(dict(value) if isinstance(value, Mapping) else value)


def tree_with_weights(tree_spec: SpecData, weights: Mapping[str, Any], where: str = "weights") -> dict:
    """A deep copy of ``tree_spec`` with the named weights in place.

    A name is a node (its incoming edge gets that weight spec; ``None`` removes the weight) or an entry of
    ``shared_weights`` (the shared function is replaced, so one entry covers every edge that uses it, e.g.
    all obstacles on a Franka control point), or one of the tree's ``roles`` (every member gets it, unless named on
    its own: ``weights_by_name``). All unknown names are reported together.
    """
    spec = plain_data(tree_spec)
    weights = weights_by_name(spec, weights)
    nodes = spec.get("nodes") or {}
    shared = dict(spec.get("shared_weights") or {})
    unknown = [n for n in weights if n not in nodes and n not in shared]
    if unknown:
        root = (spec.get("root") or {}).get("name", "q")
        issues = []
        for n in unknown:
            why = (
                "is the root, which has no incoming edge to weight"
                if n == root
                else "is not a node or shared weight of the tree"
            )
            issues.append(Issue(f"{where}.{n}", f"'{n}' {why}; nodes: {', '.join(nodes)}"))
        raise ConfigError(issues)
    for n, w in weights.items():
        w = plain_data(w)
        if n in nodes:
            node = dict(nodes[n])
            node.pop("weight", None)
            nodes[n] = node if w is None else {**node, "weight": w}
        else:
            shared[n] = w
    spec["nodes"] = nodes
    if shared:
        spec["shared_weights"] = shared
    return spec


def weights_by_name(tree_spec: SpecData, weights: Mapping[str, Any]) -> dict[str, Any]:
    """``weights`` (an expert's) with every key that names one of the tree's ``roles`` replaced by the role's members,
    each getting that key's spec; a member also given by its own name keeps that one. Keys that are neither names nor
    roles stay as they are (validation reports them)."""
    spec = plain_data(tree_spec)
    roles = spec.get("roles") or {}
    named = set(spec.get("nodes") or {}) | set(spec.get("shared_weights") or {})
    out: dict[str, Any] = {}
    for key, w in weights.items():
        if key in roles and key not in named:
            for member in roles[key]:
                out.setdefault(member, w)  # a member named on its own keeps its own spec, before or after
        else:
            out[key] = w
    return out


def own_weights(tree_spec: SpecData) -> list[str]:
    """The nodes and shared weights that carry a weight in the tree spec itself (a generator's learnable ones): an
    expert must replace every one, else its tree would keep a randomly initialised network there."""
    spec = plain_data(tree_spec)
    nodes = [
        n
        for n, nd in (spec.get("nodes") or {}).items()
        if nd.get("weight") is not None and not _is_shared_ref(nd.get("weight"))
    ]
    return [*nodes, *(spec.get("shared_weights") or {})]


def _is_shared_ref(w: Any) -> bool:
    return isinstance(w, str) or (isinstance(w, Mapping) and "shared" in w)


def expand_aux(weight_spec: Mapping[str, Any], aux_dims: Mapping[str, int]) -> dict:
    """Resolve ``aux: all`` in a weight spec to every declared aux name (sorted, so the input order is fixed)."""
    w = dict(weight_spec)
    if w.get("aux") == "all":
        w["aux"] = sorted(aux_dims)
    return w
