"""Registries: how names in YAML become classes.

One registry per kind (leaf RMP, task map, weight, env, ...). Built-ins and plugins register with the
same decorator; plugins declared under the ``rmpfusion.plugins`` entry-point group are imported on the
first lookup, never at ``import rmpfusion``. Every entry carries a pydantic model of its parameters so
YAML is validated by the entry that will consume it.
"""
from __future__ import annotations

import difflib
import importlib
from dataclasses import dataclass
from importlib.metadata import entry_points
from typing import Any, Callable, Generic, TypeVar

from pydantic import BaseModel, ConfigDict

T = TypeVar("T")

PLUGIN_GROUP = "rmpfusion.plugins"


class Params(BaseModel):
    """Base of every entry's parameter model: unknown keys are errors, values are immutable."""

    model_config = ConfigDict(extra="forbid", frozen=True)


class RegistryError(LookupError):
    """An unknown or clashing registry name."""


@dataclass(frozen=True)
class Entry(Generic[T]):
    name: str
    obj: T
    params: type[Params]
    owner: str  # module that registered it, named in clash errors

    def validate(self, params: dict[str, Any]) -> Params:
        return self.params.model_validate(params)


def _owner_of(obj: Any) -> str:
    return f"{getattr(obj, '__module__', '?')}.{getattr(obj, '__qualname__', repr(obj))}"


class Registry(Generic[T]):
    """Name -> entry for one kind of building block."""

    def __init__(self, kind: str):
        self.kind = kind
        self._entries: dict[str, Entry[T]] = {}

    def register(self, name: str, params: type[Params] | None = None) -> Callable[[T], T]:
        """Decorator: register ``obj`` under ``name``; its parameter model is ``params`` or ``obj.Params``."""

        def deco(obj: T) -> T:
            model = params if params is not None else getattr(obj, "Params", None)
            if model is None or not (isinstance(model, type) and issubclass(model, BaseModel)):
                raise TypeError(f"{self.kind} '{name}' ({_owner_of(obj)}) needs a pydantic Params model")
            if name in self._entries:
                other = self._entries[name]
                if other.obj is obj:
                    return obj
                raise RegistryError(
                    f"{self.kind} name '{name}' is registered twice: by {other.owner} and by {_owner_of(obj)}; "
                    f"rename one of them"
                )
            self._entries[name] = Entry(name, obj, model, _owner_of(obj))
            return obj

        return deco

    def names(self) -> list[str]:
        load_plugins()
        return sorted(self._entries)

    def suggest(self, name: str, n: int = 3) -> list[str]:
        return difflib.get_close_matches(str(name), self.names(), n=n, cutoff=0.5)

    def unknown_message(self, name: str) -> str:
        close = self.suggest(name)
        hint = f"did you mean {', '.join(repr(c) for c in close)}? " if close else ""
        return f"unknown {self.kind} '{name}'; {hint}registered: {', '.join(self.names())}"

    def __contains__(self, name: str) -> bool:
        load_plugins()
        return name in self._entries

    def get(self, name: str) -> Entry[T]:
        load_plugins()
        try:
            return self._entries[name]
        except KeyError:
            raise RegistryError(self.unknown_message(name)) from None

    def unregister(self, name: str) -> None:
        """Remove an entry (tests and interactive sessions that redefine a class)."""
        self._entries.pop(name, None)


LEAF_RMPS: Registry = Registry("leaf RMP")
TASK_MAPS: Registry = Registry("task map")
WEIGHTS: Registry = Registry("weight function")
ENVS: Registry = Registry("environment")
LEARNERS: Registry = Registry("learner")

_plugins_loaded = False
_builtins_loaded = False


def load_builtins() -> None:
    """Import the modules that register rmpfusion's own entries."""
    global _builtins_loaded
    if _builtins_loaded:
        return
    _builtins_loaded = True
    for mod in ("rmpfusion.maps", "rmpfusion.rmps", "rmpfusion.weights"):
        importlib.import_module(mod)
    for mod in ("rmpfusion.envs", "rmpfusion.learn"):
        try:
            importlib.import_module(mod)
        except ModuleNotFoundError as e:  # optional layers may be absent in a minimal install
            if e.name is None or not e.name.startswith("rmpfusion"):
                raise


def load_plugins() -> None:
    """Import every module named in the ``rmpfusion.plugins`` entry-point group, once."""
    global _plugins_loaded
    if _plugins_loaded:
        return
    _plugins_loaded = True
    load_builtins()
    for ep in entry_points(group=PLUGIN_GROUP):
        try:
            ep.load()
        except RegistryError:
            raise
        except Exception as e:  # a broken plugin must say which one it is
            raise ImportError(f"rmpfusion plugin '{ep.name}' ({ep.value}) failed to load: {e}") from e
