"""Registries: how names in YAML become classes.

One registry per kind (leaf RMP, task map, weight, env, ...). Built-ins and plugins register with the
same decorator: a built-in when its package is imported (``import rmpfusion`` imports them all), a plugin
declared under the ``rmpfusion.plugins`` entry-point group on the first lookup, never at ``import
rmpfusion``. Every entry carries a pydantic model of its parameters, so YAML is validated by the entry that
will consume it (and the run config's schema is generated from the registries, ``assembly.spec``), and the
examples it is checked on against finite differences (``examples.Example``).
"""

from __future__ import annotations

import difflib
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from importlib.metadata import entry_points
from typing import Any, Generic, TypeVar

from pydantic import BaseModel, ConfigDict, ValidationError
from pydantic_core import PydanticCustomError
from torch import Tensor

from .examples import Example

T = TypeVar("T")

PLUGIN_GROUP = "rmpfusion.plugins"


class Params(BaseModel):
    """Base of every entry's parameter model: unknown keys are errors, values are immutable, and no number
    is infinite or NaN (a gain or radius of .inf passes ``gt=0`` but means nothing)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


#: A tensor holding more numbers than this is shown by its shape in an entry's repr.
SHOWN_NUMBERS = 12


def numbers_repr(values: Mapping[str, object]) -> str:
    """``name=value, ...``: the ``extra_repr`` of a task map, leaf RMP or weight function, so that ``print(tree)``
    shows each node's numbers. Python values appear as they were given; a tensor (a buffer, or a learned number's
    current value) as its numbers to 4 significant digits (a scalar as a float, a small one as a list), or as its
    shape when it holds more than ``SHOWN_NUMBERS``."""
    return ", ".join(f"{name}={_shown(value)}" for name, value in values.items())


def _shown(value: object) -> str:
    if not isinstance(value, Tensor):
        return repr(value)
    if value.numel() > SHOWN_NUMBERS:
        return f"tensor(shape={tuple(value.shape)})"
    return repr(_rounded(value.detach().cpu().tolist()))


def _rounded(value: object) -> object:
    """Floats (nested in lists) to 4 significant digits; integers and booleans as they are."""
    if isinstance(value, list):
        return [_rounded(v) for v in value]
    if isinstance(value, float):
        return float(f"{value:.4g}")
    return value


class RegistryError(LookupError):
    """An unknown or clashing registry name."""


class PluginError(ImportError):
    """A plugin named in the ``rmpfusion.plugins`` entry points failed to import; its own error is the cause."""


@dataclass(frozen=True)
class Entry(Generic[T]):
    name: str
    obj: T
    params: type[Params]
    owner: str  # module that registered it, named in clash errors
    examples: tuple[Example, ...] = ()  # what its derivatives are checked on (tests/test_registry_derivatives.py)

    def validate(self, params: dict[str, Any]) -> Params:
        return self.params.model_validate(params)


def _owner_of(obj: Any) -> str:
    return f"{getattr(obj, '__module__', '?')}.{getattr(obj, '__qualname__', repr(obj))}"


class Registry(Generic[T]):
    """Name -> entry for one kind of building block.

    A registry is a plain instance: tests and embedding applications can build an isolated one and pass it
    where the defaults would be used. ``plugins`` is called before the first lookup (the default registries
    import the ``rmpfusion.plugins`` entry points there); an isolated registry has none unless given one.
    ``version`` counts registrations, so schemas generated from a registry know when to regenerate.
    """

    def __init__(self, kind: str, plugins: PluginLoader | None = None):
        self.kind = kind
        self.plugins = plugins
        self.version = 0
        self._entries: dict[str, Entry[T]] = {}

    def register(
        self, name: str, params: type[Params] | None = None, examples: Iterable[Example] = ()
    ) -> Callable[[T], T]:
        """Decorator: register ``obj`` under ``name``; its parameter model (a ``Params`` subclass) is ``params`` or
        ``obj.Params``.

        ``examples``: the configurations a task map, leaf RMP or weight function is checked on against finite
        differences (``rmpfusion.examples.Example``), declared here so that a plugin ships its own."""
        examples = tuple(examples)

        def deco(obj: T) -> T:
            model = params if params is not None else getattr(obj, "Params", None)
            if model is None or not (isinstance(model, type) and issubclass(model, Params)):
                raise TypeError(
                    f"{self.kind} '{name}' ({_owner_of(obj)}) needs a Params model: a subclass of "
                    f"rmpfusion.registry.Params (unknown keys are errors, numbers finite)"
                )
            wrong = [type(e).__name__ for e in examples if not isinstance(e, Example)]
            if wrong:
                raise TypeError(
                    f"{self.kind} '{name}' ({_owner_of(obj)}): examples must be "
                    f"rmpfusion.examples.Example, got {', '.join(wrong)}"
                )
            if name in self._entries:
                other = self._entries[name]
                if other.obj is obj:
                    return obj
                raise RegistryError(
                    f"{self.kind} name '{name}' is registered twice: by {other.owner} and by {_owner_of(obj)}; "
                    f"rename one of them"
                )
            self._entries[name] = Entry(name, obj, model, _owner_of(obj), examples)
            self.version += 1
            return obj

        return deco

    def load_plugins(self) -> None:
        """Import the plugins of this registry now (otherwise on its first lookup): a schema generated from the
        registry must see their entries before it is cached under the registry's version."""
        if self.plugins is not None:
            self.plugins.load()

    def entries(self) -> list[Entry[T]]:
        self.load_plugins()
        return [self._entries[n] for n in sorted(self._entries)]

    def names(self) -> list[str]:
        self.load_plugins()
        return sorted(self._entries)

    def suggest(self, name: str, n: int = 3) -> list[str]:
        return difflib.get_close_matches(str(name), self.names(), n=n, cutoff=0.5)

    def unknown_message(self, name: str) -> str:
        close = self.suggest(name)
        hint = f"did you mean {', '.join(repr(c) for c in close)}? " if close else ""
        return f"unknown {self.kind} '{name}'; {hint}registered: {', '.join(self.names())}"

    def __contains__(self, name: str) -> bool:
        self.load_plugins()
        return name in self._entries

    def get(self, name: str) -> Entry[T]:
        self.load_plugins()
        try:
            return self._entries[name]
        except KeyError:
            raise RegistryError(self.unknown_message(name)) from None

    def unregister(self, name: str) -> None:
        """Remove an entry (tests and interactive sessions that redefine a class)."""
        if self._entries.pop(name, None) is not None:
            self.version += 1


def validate_kind(registry: Registry, block: Mapping[str, Any], default: str, error_type: str) -> Params:
    """A ``{type: name, ...}`` block validated by the named entry's own model, for a field's ``BeforeValidator``
    (a robot block, a simulator block): an unknown name, or a key its model refuses, is one ``PydanticCustomError``
    of ``error_type`` whose message names the key (``type: unknown ...``, ``<key>: <reason>; ...``)."""
    kind = block.get("type", default)
    try:
        entry = registry.get(kind)
    except RegistryError as e:
        raise PydanticCustomError(error_type, "{message}", {"message": f"type: {e}"}) from None
    try:
        return entry.params.model_validate({**block, "type": kind})
    except ValidationError as e:
        reasons = "; ".join(
            (f"{'.'.join(map(str, err['loc']))}: " if err["loc"] else "") + err["msg"].removeprefix("Value error, ")
            for err in e.errors()
        )
        raise PydanticCustomError(error_type, "{message}", {"message": reasons}) from None


class PluginLoader:
    """Imports every module named in an entry-point group, once, on the first lookup of a registry using it.

    Never at ``import rmpfusion``: a broken plugin then fails the run that needs a name, naming the plugin."""

    def __init__(self, group: str = PLUGIN_GROUP):
        self.group = group
        self.loaded = False

    def load(self) -> None:
        if self.loaded:
            return
        self.loaded = True
        for ep in entry_points(group=self.group):
            try:
                ep.load()
            except RegistryError:
                raise
            except Exception as e:  # a broken plugin must say which one it is
                raise PluginError(
                    f"rmpfusion plugin '{ep.name}' ({ep.value}) failed to load: {type(e).__name__}: {e}"
                ) from e


#: The plugins of the default registries (``rmpfusion.plugins`` entry points).
PLUGINS = PluginLoader()

LEAF_RMPS: Registry = Registry("leaf RMP", PLUGINS)
TASK_MAPS: Registry = Registry("task map", PLUGINS)
WEIGHTS: Registry = Registry("weight function", PLUGINS)
ENVS: Registry = Registry("environment", PLUGINS)
LEARNERS: Registry = Registry("learner", PLUGINS)
OBJECTIVES: Registry = Registry("objective", PLUGINS)
OPTIMIZERS: Registry = Registry("optimizer", PLUGINS)
TREE_GENERATORS: Registry = Registry("tree generator", PLUGINS)
ROBOTS: Registry = Registry("robot kind", PLUGINS)
TRAIN_METHODS: Registry = Registry("training method", PLUGINS)
SIMULATORS: Registry = Registry("simulator", PLUGINS)
RECORDING_FORMATS: Registry = Registry("recording format", PLUGINS)
