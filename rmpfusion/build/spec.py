"""The tree schema (docs/architecture.md §2) and its whole-tree checks.

Validation here is structural and per-entry: every ``type`` must name a registered entry, its other keys
are validated by that entry's own pydantic model, and the graph must be a tree rooted at ``root``.
Dimension checks need the built maps and happen in ``build_tree``; both report through ConfigError.
"""
from __future__ import annotations

from typing import Any, Mapping, Union

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from ..registry import LEAF_RMPS, TASK_MAPS, WEIGHTS, Registry
from .errors import ConfigError, Issue, allowed_keys_hint, issues_from_pydantic


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class RootSpec(_Strict):
    name: str = "q"
    dim: int = Field(gt=0)


class SharedWeightRef(_Strict):
    """Use a weight declared under ``shared_weights``; ``bind`` renames its aux inputs for this edge."""

    shared: str
    bind: dict[str, str] = Field(default_factory=dict)


class NodeSpec(_Strict):
    parent: str
    map: dict[str, Any] = Field(default_factory=lambda: {"type": "identity"})
    weight: Union[dict[str, Any], str, None] = None
    rmp: Union[dict[str, Any], None] = None


class TreeSpec(_Strict):
    root: RootSpec
    aux: dict[str, int] = Field(default_factory=dict, description="aux state names and their dimensions")
    shared_weights: dict[str, dict[str, Any]] = Field(default_factory=dict)
    nodes: dict[str, NodeSpec] = Field(min_length=1)
    description: str = ""


def check_typed(spec: Any, registry: Registry, path: str) -> tuple[Any, list[Issue]]:
    """Validate ``{type: name, **params}`` against the named entry; returns (entry, issues)."""
    if not isinstance(spec, Mapping):
        return None, [Issue(path, f"expected a mapping with a 'type' key, got {spec!r}")]
    if "type" not in spec:
        return None, [Issue(f"{path}.type", f"required key is missing; one of: {', '.join(registry.names())}")]
    name = spec["type"]
    if name not in registry:
        return None, [Issue(f"{path}.type", registry.unknown_message(name))]
    entry = registry.get(name)
    params = {k: v for k, v in spec.items() if k != "type"}
    try:
        entry.validate(params)
    except ValidationError as e:
        return entry, allowed_keys_hint(entry.params, path, issues_from_pydantic(e, path))
    return entry, []


def parse_spec(spec: Mapping[str, Any] | TreeSpec, where: str = "tree") -> TreeSpec:
    if isinstance(spec, TreeSpec):
        return spec
    try:
        return TreeSpec.model_validate(dict(spec))
    except ValidationError as e:
        raise ConfigError(issues_from_pydantic(e, where)) from None


def validate_tree_spec(spec: Mapping[str, Any] | TreeSpec, where: str = "tree") -> TreeSpec:
    """Every structural and per-entry problem of a tree spec, raised together as one ConfigError."""
    ts = parse_spec(spec, where)
    issues: list[Issue] = []
    root = ts.root.name
    if root in ts.nodes:
        issues.append(Issue(f"{where}.nodes.{root}", f"'{root}' is the root's name; a node cannot reuse it"))
    children: dict[str, list[str]] = {root: [], **{n: [] for n in ts.nodes}}
    for name, node in ts.nodes.items():
        p = f"{where}.nodes.{name}"
        if node.parent not in children:
            from difflib import get_close_matches

            close = get_close_matches(node.parent, list(children), n=3)
            hint = f"; did you mean {', '.join(map(repr, close))}?" if close else ""
            issues.append(Issue(f"{p}.parent", f"parent '{node.parent}' is not a node of this tree{hint}"))
        elif node.parent == name:
            issues.append(Issue(f"{p}.parent", "a node cannot be its own parent"))
        else:
            children[node.parent].append(name)
    # cycles and orphans: everything must be reachable from the root
    seen, stack = {root}, [root]
    while stack:
        for c in children[stack.pop()]:
            if c not in seen:
                seen.add(c)
                stack.append(c)
    for name, node in ts.nodes.items():
        if name in seen or node.parent not in children:
            continue
        # walk up: a cycle returns to a node already on the path, an orphan ends at a missing parent
        path, cur = [name], node.parent
        while cur in ts.nodes and cur not in path:
            path.append(cur)
            cur = ts.nodes[cur].parent
        if cur in path:
            cyc = path[path.index(cur):] + [cur]
            issues.append(Issue(f"{where}.nodes.{name}.parent", f"cycle: {' -> '.join(cyc)}; a tree needs every node to lead back to '{root}'"))
        else:
            issues.append(Issue(f"{where}.nodes.{name}", f"orphan: not connected to the root '{root}'"))
    if not children[root]:
        issues.append(Issue(f"{where}.root", f"the root '{root}' has no children"))
    for name, node in ts.nodes.items():
        p = f"{where}.nodes.{name}"
        is_leaf = not children.get(name)
        if is_leaf and node.rmp is None:
            issues.append(Issue(f"{p}.rmp", "a leaf needs an 'rmp' (it has no children)"))
        if not is_leaf and node.rmp is not None:
            issues.append(Issue(f"{p}.rmp", f"only leaves carry an rmp; this node has children {children[name]}"))
        issues += check_typed(node.map, TASK_MAPS, f"{p}.map")[1]
        if node.rmp is not None:
            issues += check_typed(node.rmp, LEAF_RMPS, f"{p}.rmp")[1]
        if isinstance(node.weight, str) or (isinstance(node.weight, Mapping) and "shared" in node.weight):
            ref = node.weight if isinstance(node.weight, str) else node.weight.get("shared")
            if isinstance(node.weight, Mapping):
                try:
                    SharedWeightRef.model_validate(dict(node.weight))
                except ValidationError as e:
                    issues += issues_from_pydantic(e, f"{p}.weight")
            if ref not in ts.shared_weights:
                known = ", ".join(ts.shared_weights) or "none declared"
                issues.append(Issue(f"{p}.weight", f"shared weight '{ref}' is not declared under shared_weights (declared: {known})"))
        elif node.weight is not None:
            issues += check_typed(node.weight, WEIGHTS, f"{p}.weight")[1]
    for name, w in ts.shared_weights.items():
        issues += check_typed(w, WEIGHTS, f"{where}.shared_weights.{name}")[1]
    if issues:
        raise ConfigError(issues)
    return ts
