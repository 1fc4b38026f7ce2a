"""Collected configuration errors: every problem at once, each with its path, what was given and the fix."""

from __future__ import annotations

import difflib
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from types import UnionType
from typing import Annotated, Any, Literal, Union, get_args, get_origin

from pydantic import BaseModel, Tag, ValidationError


@dataclass(frozen=True)
class Issue:
    path: str
    message: str

    def __str__(self) -> str:
        return f"{self.path}: {self.message}"


class ConfigError(ValueError):
    """One or more configuration problems; ``issues`` lists them all."""

    def __init__(self, issues: Iterable[Issue], source: str | None = None):
        self.issues = list(issues)
        self.source = source
        head = f"invalid configuration{f' ({source})' if source else ''}: {len(self.issues)} problem(s)"
        super().__init__("\n".join([head, *(f"  - {i}" for i in self.issues)]))


def _show(value: Any) -> str:
    s = repr(value)
    return s if len(s) <= 80 else s[:77] + "..."


#: Joins a union's tag (``task map`` + ``sphere_distance``) in pydantic's error locations; parts holding it are
#: the schema's bookkeeping, not YAML keys, and never appear in a message.
TAG_SEPARATOR = "\x1f"


def _strip_annotated(ann: Any) -> tuple[Any, tuple]:
    meta: tuple = ()
    while get_origin(ann) is Annotated:
        meta += ann.__metadata__
        ann = get_args(ann)[0]
    return ann, meta


def _step(ann: Any, part: Any) -> Any:
    """The annotation one location part below ``ann`` (a model field, a dict value, a list item, a union member)."""
    ann, _ = _strip_annotated(ann)
    origin = get_origin(ann)
    if origin in (Union, UnionType):
        members = get_args(ann)
        for m in members:
            if any(isinstance(x, Tag) and x.tag == part for x in _strip_annotated(m)[1]):
                return m
        found = [r for m in members if m is not type(None) and (r := _step(m, part)) is not None]
        return found[0] if found else None
    if isinstance(ann, type) and issubclass(ann, BaseModel):
        field = ann.model_fields.get(part) if isinstance(part, str) else None
        return None if field is None else field.annotation
    if origin in (dict, Mapping) or ann is dict:
        args = get_args(ann)
        return args[1] if args else None
    if origin in (list, tuple, Sequence) and isinstance(part, int):
        args = get_args(ann)
        return args[0] if args else None
    return None


def model_at(model: type | None, loc: Sequence[Any]) -> type[BaseModel] | None:
    """The pydantic model that validated location ``loc`` of ``model``'s input, or None if not a model."""
    ann: Any = model
    for part in loc:
        if ann is None:
            return None
        ann = _step(ann, part)
    while True:  # a location can end on a tagged member or an Optional: unwrap to the model
        ann, _ = _strip_annotated(ann)
        if get_origin(ann) in (Union, UnionType):
            models = [
                m
                for m in get_args(ann)
                if isinstance(_strip_annotated(m)[0], type) and issubclass(_strip_annotated(m)[0], BaseModel)
            ]
            if len(models) != 1:
                return None
            ann = models[0]
            continue
        return ann if isinstance(ann, type) and issubclass(ann, BaseModel) else None


def _is_tag(key: str, field: Any) -> bool:
    """The ``type`` (or ``method``) of a registry-typed block: the union's tag, said by the block, not one of its
    parameters (``build.spec.spec_model`` marks it)."""
    extra = field.json_schema_extra if isinstance(field.json_schema_extra, Mapping) else {}
    return bool(extra.get("registry_tag")) and get_origin(field.annotation) is Literal


#: What users write for a key or value out of habit (other libraries' names), and what rmpfusion calls it: offered
#: before the names that are merely spelt alike.
HABITS = {
    "learning_rate": "lr",
    "learningrate": "lr",
    "step_size": "lr",
    "epochs": "iterations",
    "steps": "iterations",
    "num_iterations": "iterations",
    "n_iterations": "iterations",
    "batch": "batch_size",
    "batchsize": "batch_size",
    "gpu": "cuda",
    "optim": "optimizer",
}


def closest(name: str, options: Sequence[str], n: int = 3) -> list[str]:
    """The options a misspelt or habitual ``name`` most likely meant: its usual rmpfusion name first (``HABITS``),
    then those spelt alike."""
    usual = HABITS.get(name.lower())
    offered = [usual] if usual is not None and usual in options else []
    alike = difflib.get_close_matches(name, list(dict.fromkeys(options)), n=n, cutoff=0.5)
    return offered + [o for o in alike if o != usual][: n - len(offered)]


def _unknown_key(e: Mapping[str, Any], model: type | None) -> str:
    """'unknown key', with the allowed keys of the model that refused it and the closest of them."""
    owner = model_at(model, e["loc"][:-1]) if model is not None else None
    msg = "unknown key (misspelt?); remove it or use one of the allowed keys"
    if owner is None:
        return msg
    allowed = [k for k, f in owner.model_fields.items() if not _is_tag(k, f)]
    msg += f" (allowed: {', '.join(allowed) or 'none'})"
    close = closest(str(e["loc"][-1]), allowed)
    return msg + (f"; did you mean {', '.join(map(repr, close))}?" if close else "")


def _unknown_type(e: Mapping[str, Any]) -> tuple[str, str]:
    """(path suffix, message) for a block whose ``type`` (the union's key) names no entry of its registry, or
    has none."""
    registry, key, given = e["ctx"]["registry"], e["ctx"].get("key", "type"), e.get("input")
    if not isinstance(given, Mapping):
        return "", f"expected a mapping with a '{key}' key, got {_show(given)}"
    if key not in given:
        return f".{key}", f"required key is missing; one of: {', '.join(registry.names())}"
    return f".{key}", registry.unknown_message(given[key])


def _message(e: Mapping[str, Any], model: type | None) -> tuple[str, str]:
    """(path suffix, message) of one pydantic error, said the way a YAML author needs it."""
    kind = e["type"]
    if kind == "extra_forbidden":
        return "", _unknown_key(e, model)
    if kind == "missing":
        return "", "required key is missing"
    if kind == "registry_type":
        return _unknown_type(e)
    msg = e["msg"]
    if kind == "value_error" and msg.startswith("Value error, "):
        msg = msg[len("Value error, ") :]
    if "given" in msg or "input" not in e or (isinstance(e["input"], str) and f"'{e['input']}'" in msg):
        return "", msg  # the message already says what was given
    return "", f"{msg} (given: {_show(e['input'])})"


def issues_from_pydantic(err: ValidationError, prefix: str, model: type | None = None) -> list[Issue]:
    """Turn a pydantic error into path-named issues (``prefix.key.sub``), with the value given.

    ``model`` (the model that was validated) lets an unknown key list the keys allowed where it was found."""
    out = []
    for e in err.errors():
        loc = ".".join(str(p) for p in e["loc"] if not (isinstance(p, str) and TAG_SEPARATOR in p))
        suffix, msg = _message(e, model)
        path = (f"{prefix}.{loc}" if prefix else loc) if loc else prefix
        out.append(Issue((path + suffix).lstrip(".") or "<config>", msg))
    return out


def allowed_keys_hint(model: type[BaseModel], path: str, issues: list[Issue]) -> list[Issue]:
    """Append the model's allowed keys to its 'unknown key' issues that do not list them yet."""
    allowed = ", ".join(model.model_fields)
    return [
        Issue(i.path, f"{i.message} (allowed: {allowed or 'none'})")
        if "unknown key" in i.message and "(allowed:" not in i.message
        else i
        for i in issues
    ]
