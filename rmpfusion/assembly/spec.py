"""The tree schema (docs/architecture.md §2): typed, generated from the registries, plus whole-tree checks.

A node's ``map``, ``weight`` and ``rmp`` are discriminated unions over the registered entries: the ``type``
key picks the entry, whose own pydantic model validates the other keys. The unions are generated from the
registries when first needed and again whenever an entry is added (plugins included), so a validated tree
holds each block as its entry's parameter model, ready for the builder. Graph checks (a tree rooted at
``root``, leaves carrying rmps) follow the schema; dimension checks need the built maps and happen in
``build_tree``. Everything reports through ConfigError, every problem at once.
"""

from __future__ import annotations

import difflib
from collections.abc import Mapping
from types import GenericAlias
from typing import Annotated, Any, Literal, Union

from pydantic import BaseModel, BeforeValidator, ConfigDict, Discriminator, Field, Tag, ValidationError, create_model
from pydantic.config import JsonDict
from pydantic_core import PydanticCustomError

from ..registry import LEAF_RMPS, TASK_MAPS, WEIGHTS, Params, Registry
from .errors import TAG_SEPARATOR, ConfigError, Issue, issues_from_pydantic


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class TypedBlock(BaseModel):
    """``{type: name, **params}`` before its entry is known: the loose form the static schemas carry."""

    model_config = ConfigDict(extra="allow", frozen=True)
    type: str


# ------------------------------------------------------------------ unions generated from a registry
_SPEC_MODELS: dict[tuple[int, str, str], type[Params]] = {}
_UNIONS: dict[tuple[int, int, str, str | None], Any] = {}

#: Marks the field a union adds to an entry's model to say which entry a block is (``type``, or ``method`` for
#: the training block): the union's tag, not one of the entry's parameters (messages never list it as one).
TAG_FIELD_MARK: JsonDict = {"registry_tag": True}


def spec_model(registry: Registry, name: str, key: str = "type") -> type[Params]:
    """The entry's parameter model with its tag field ``key`` (``type: name``): what a validated block of that
    entry is."""
    entry = registry.get(name)
    cache = (id(entry.params), name, key)
    if cache not in _SPEC_MODELS:
        _SPEC_MODELS[cache] = create_model(  # type: ignore[call-overload]  # a field named at run time (``key``)
            f"{entry.params.__name__}Spec",
            __base__=entry.params,
            **{key: (Literal[name], Field(name, json_schema_extra=TAG_FIELD_MARK))},
        )
    return _SPEC_MODELS[cache]


def registry_tag(registry: Registry, name: str) -> str:
    """The union tag of an entry; it appears in pydantic's error locations and is stripped from messages."""
    return f"{registry.kind}{TAG_SEPARATOR}{name}"


class _RegistryDiscriminator(Discriminator):
    """A discriminator whose error context carries the registry (for its did-you-mean message); compared and
    hashed by identity, since typing hashes annotations and its context dict is not hashable."""

    def __hash__(self) -> int:
        return id(self)

    def __eq__(self, other: object) -> bool:
        return self is other


def typed_union(registry: Registry, key: str = "type", default: str | None = None) -> Any:
    """``{key: name, ...}`` validated by the named entry of ``registry``: a discriminated union of every entry,
    regenerated when the registry changes. A block without ``key`` is the ``default`` entry when one is given
    (the training block: no ``method`` is behavior cloning, as every config was before methods existed). An
    unknown or missing name is a ``registry_type`` error that the error formatter turns into the registry's
    did-you-mean message."""
    registry.load_plugins()  # first, so they are part of the union and of its cache key
    cache = (id(registry), registry.version, key, default)
    if cache not in _UNIONS:
        names = registry.names()
        members = tuple(Annotated[spec_model(registry, n, key), Tag(registry_tag(registry, n))] for n in names)

        def tag_of(value: Any) -> str | None:
            t = (
                value.get(key, default)
                if isinstance(value, Mapping)
                else getattr(value, key, None)
                if isinstance(value, BaseModel)
                else None
            )
            return registry_tag(registry, t) if isinstance(t, str) and t in names else None

        # a union of members counted at run time: ``X | Y`` cannot spell it
        union = Union[members] if members else Literal["<nothing registered>"]  # noqa: UP007
        _UNIONS[cache] = Annotated[
            union,
            _RegistryDiscriminator(
                tag_of,
                custom_error_type="registry_type",
                custom_error_message=f"unknown {registry.kind}",
                # pydantic-core's stub allows numbers and strings only; the context carries any object
                custom_error_context={"registry": registry, "key": key},  # type: ignore[dict-item]
            ),
        ]
    return _UNIONS[cache]


class _LoneBlock(BaseModel):
    """The model a block validated on its own sits in; ``check_typed`` types ``block`` by the registry's union."""

    model_config = ConfigDict(frozen=True)
    block: Any


def name_keyed(values: Any) -> Any:
    """``dict[str, values]`` for a value type generated at run time (a registry's union), which no static
    annotation can name."""
    return GenericAlias(dict, (str, values))


def check_typed(spec: Any, registry: Registry, path: str) -> tuple[Any, list[Issue]]:
    """Validate one ``{type: name, **params}`` block on its own; returns (the validated block or None, issues)."""
    model = create_model("Block", __base__=_LoneBlock, block=(typed_union(registry), ...))
    try:
        return model.model_validate({"block": spec}).block, []
    except ValidationError as e:
        return None, [
            Issue(path + i.path[len("block") :], i.message)
            for i in issues_from_pydantic(e, "", model)
            if i.path.startswith("block")
        ]


# ------------------------------------------------------------------ the tree's static parts
def _constant_shorthand(value: Any) -> Any:
    """A bare number is a constant weight (``weight: 2.0``); Theorem 2 needs it strictly positive."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return value
    if not value > 0:
        raise PydanticCustomError(
            "positive_weight",
            "constant weight must be > 0 (positive weights are what keep "
            "the policy Lyapunov-stable, Theorem 2); given {value}",
            {"value": value},
        )
    return {"type": "constant", "value": float(value)}


class RootSpec(_Strict):
    name: str = "q"
    dim: int = Field(gt=0, description="configuration-space dimension")


class SharedWeightRef(_Strict):
    """Use a weight declared under ``shared_weights``; ``bind`` renames its aux inputs for this edge."""

    shared: str
    bind: dict[str, str] = Field(default_factory=dict)


def shared_ref(weight: Any) -> SharedWeightRef | None:
    """The shared-weight reference a node's weight is (``"name"`` or ``{shared: name}``), else None."""
    if isinstance(weight, str):
        return SharedWeightRef(shared=weight)
    return weight if isinstance(weight, SharedWeightRef) else None


def weight_label(weight: Any) -> str | None:
    """How messages and ``describe`` name a node's weight: its type, or ``shared:<name>``."""
    ref = shared_ref(weight)
    if ref is not None:
        return f"shared:{ref.shared}"
    return None if weight is None else weight.type


def weight_field() -> Any:
    """A node's or expert's weight: a typed block, a shared-weight reference, or a positive number."""

    typed, shared, name = (f"weight{TAG_SEPARATOR}{k}" for k in ("typed", "shared", "name"))

    def kind(value: Any) -> str:
        if isinstance(value, str):
            return name
        if isinstance(value, SharedWeightRef) or (isinstance(value, Mapping) and "shared" in value):
            return shared
        return typed

    return Annotated[
        Annotated[typed_union(WEIGHTS), Tag(typed)]
        | Annotated[SharedWeightRef, Tag(shared)]
        | Annotated[str, Tag(name)],
        Discriminator(kind),
        BeforeValidator(_constant_shorthand),
    ]


class NodeSpec(_Strict):
    parent: str
    map: TypedBlock = Field(default_factory=lambda: TypedBlock(type="identity"))
    weight: Any = None
    rmp: TypedBlock | None = None


class TreeSpec(_Strict):
    """A tree (docs/architecture.md §2). Validated through ``tree_spec_model`` its blocks are entry models."""

    root: RootSpec
    aux: dict[str, int] = Field(default_factory=dict, description="aux state names and their dimensions")
    shared_weights: dict[str, Any] = Field(default_factory=dict)
    nodes: dict[str, NodeSpec] = Field(min_length=1)
    description: str = ""
    roles: dict[str, list[str]] = Field(
        default_factory=dict,
        description="role -> the nodes and shared weights that play it (a generator declares "
        "them, e.g. arm_reach's attractor, ground and obstacle), so an expert can weight "
        "them by role whatever their number",
    )


_TREE_MODELS: dict[tuple, type[TreeSpec]] = {}


def tree_spec_model() -> type[TreeSpec]:
    """``TreeSpec`` with every block typed by the registries as they are now (regenerated when they change)."""
    for r in (TASK_MAPS, WEIGHTS, LEAF_RMPS):
        r.load_plugins()
    key = tuple((id(r), r.version) for r in (TASK_MAPS, WEIGHTS, LEAF_RMPS))
    if key not in _TREE_MODELS:
        weight, leaf_rmp = weight_field(), typed_union(LEAF_RMPS)
        node = create_model(
            "TypedNodeSpec",
            __base__=NodeSpec,
            map=(typed_union(TASK_MAPS), Field(default_factory=lambda: {"type": "identity"}, validate_default=True)),
            weight=(weight | None, None),
            rmp=(leaf_rmp | None, None),
        )
        _TREE_MODELS[key] = create_model(
            "TypedTreeSpec",
            __base__=TreeSpec,
            shared_weights=(name_keyed(typed_union(WEIGHTS)), Field(default_factory=dict)),
            nodes=(dict[str, node], Field(min_length=1)),
        )
    return _TREE_MODELS[key]


def parse_spec(spec: Mapping[str, Any] | TreeSpec, where: str = "tree") -> TreeSpec:
    """The typed tree; a spec already validated through ``tree_spec_model`` is returned as it is."""
    model = tree_spec_model()
    if isinstance(spec, model):
        return spec
    data = spec.model_dump() if isinstance(spec, BaseModel) else dict(spec)
    try:
        return model.model_validate(data)
    except ValidationError as e:
        raise ConfigError(issues_from_pydantic(e, where, model)) from None


# ------------------------------------------------------------------ whole-tree checks
def _children(ts: TreeSpec, where: str, issues: list[Issue]) -> dict[str, list[str]]:
    root = ts.root.name
    if root in ts.nodes:
        issues.append(Issue(f"{where}.nodes.{root}", f"'{root}' is the root's name; a node cannot reuse it"))
    children: dict[str, list[str]] = {root: [], **{n: [] for n in ts.nodes}}
    for name, node in ts.nodes.items():
        p = f"{where}.nodes.{name}"
        if node.parent not in children:
            close = difflib.get_close_matches(node.parent, list(children), n=3)
            hint = f"; did you mean {', '.join(map(repr, close))}?" if close else ""
            issues.append(Issue(f"{p}.parent", f"parent '{node.parent}' is not a node of this tree{hint}"))
        elif node.parent == name:
            issues.append(Issue(f"{p}.parent", "a node cannot be its own parent"))
        else:
            children[node.parent].append(name)
    return children


def _unreachable(ts: TreeSpec, children: Mapping[str, list[str]], where: str) -> list[Issue]:
    """Cycles and orphans: everything must lead back to the root."""
    root = ts.root.name
    seen, stack = {root}, [root]
    while stack:
        for c in children[stack.pop()]:
            if c not in seen:
                seen.add(c)
                stack.append(c)
    issues = []
    for name, node in ts.nodes.items():
        if name in seen or node.parent not in children:
            continue
        # walk up: a cycle returns to a node already on the path, an orphan ends at a missing parent
        path, cur = [name], node.parent
        while cur in ts.nodes and cur not in path:
            path.append(cur)
            cur = ts.nodes[cur].parent
        if cur in path:
            cyc = path[path.index(cur) :] + [cur]
            issues.append(
                Issue(
                    f"{where}.nodes.{name}.parent",
                    f"cycle: {' -> '.join(cyc)}; a tree needs every node to lead back to '{root}'",
                )
            )
        else:
            issues.append(Issue(f"{where}.nodes.{name}", f"orphan: not connected to the root '{root}'"))
    if not children[root]:
        issues.append(Issue(f"{where}.root", f"the root '{root}' has no children"))
    return issues


def _node_issues(ts: TreeSpec, children: Mapping[str, list[str]], where: str) -> list[Issue]:
    """Leaves carry rmps, inner nodes do not; shared-weight references name declared weights."""
    issues = []
    for name, node in ts.nodes.items():
        p = f"{where}.nodes.{name}"
        is_leaf = not children.get(name)
        if is_leaf and node.rmp is None:
            issues.append(Issue(f"{p}.rmp", "a leaf needs an 'rmp' (it has no children)"))
        if not is_leaf and node.rmp is not None:
            issues.append(Issue(f"{p}.rmp", f"only leaves carry an rmp; this node has children {children[name]}"))
        ref = shared_ref(node.weight)
        if ref is not None and ref.shared not in ts.shared_weights:
            known = ", ".join(ts.shared_weights) or "none declared"
            issues.append(
                Issue(
                    f"{p}.weight",
                    f"shared weight '{ref.shared}' is not declared under shared_weights (declared: {known})",
                )
            )
    return issues


def _role_issues(ts: TreeSpec, where: str) -> list[Issue]:
    """Every member of a role is a node or a shared weight, and a role's name is no other entry's."""
    issues = []
    for role, members in ts.roles.items():
        stray = [m for m in members if m not in ts.nodes and m not in ts.shared_weights]
        if stray:
            issues.append(
                Issue(f"{where}.roles.{role}", f"{', '.join(map(repr, stray))} not a node or shared weight of the tree")
            )
    return issues


def validate_tree_spec(spec: Mapping[str, Any] | TreeSpec, where: str = "tree") -> TreeSpec:
    """The typed tree, or one ConfigError with every structural and per-entry problem."""
    ts = parse_spec(spec, where)
    issues: list[Issue] = []
    children = _children(ts, where, issues)
    issues += _unreachable(ts, children, where)
    issues += _node_issues(ts, children, where)
    issues += _role_issues(ts, where)
    if issues:
        raise ConfigError(issues)
    return ts
