"""Trees declared by the generator that builds them: ``{generator: name, **parameters}``.

Some trees are too regular to write by hand and too large to commit as output: the Panda tree of Fig. 1b
has one distance node per control point and obstacle, ~400 lines of YAML that would have to be kept in
step with the code that wrote them. Such a tree is declared instead as the registered generator and its
parameters, and expanded here into the ordinary tree spec before anything else looks at it, so every
later check (structure, aux names, dimensions, expert names) sees a plain tree.

A generator is an entry of ``rmpfusion.registry.TREE_GENERATORS``: a function ``(params) -> dict``
whose pydantic ``Params`` model checks every parameter (unknown keys refused, ranges where they have a
physical meaning). A generator a plugin registers works the same way as the built-in ones: the lookup
goes through the registry only, which is also why this layer never imports ``envs/``, where the Panda's
generator lives.

Beside the parameters, a declaration may carry tree-spec keys (``nodes``, ``shared_weights``, ``aux``,
``root``, ``description``): they are merged onto the generated spec, mapping into mapping, so an
experiment can adjust a generated tree the way it adjusts a written one (e.g. every shared obstacle
weight starting at 1). Only entries the generator made can be adjusted: a name under ``nodes`` or
``shared_weights`` that it did not make is refused with the closest names, since a misspelt name would
otherwise add a half-specified node; a different tree shape is a generator parameter or a written tree.
"""

from __future__ import annotations

import copy
import difflib
from collections.abc import Mapping
from typing import Any

from pydantic import ValidationError

from ..registry import TREE_GENERATORS
from .errors import ConfigError, Issue, issues_from_pydantic

#: Top-level tree-spec keys a declaration may carry to adjust the generated spec (docs/architecture.md §2).
SPEC_KEYS = ("root", "aux", "shared_weights", "nodes", "description")
#: Named entries of a tree spec: an adjustment may only change existing ones.
_NAMED = ("nodes", "shared_weights")


def _listing(names: list[str], limit: int = 12) -> str:
    more = f", ... ({len(names) - limit} more)" if len(names) > limit else ""
    return ", ".join(names[:limit]) + more or "none"


def _merge(base: Any, over: Any) -> Any:
    if isinstance(base, Mapping) and isinstance(over, Mapping):
        out = dict(base)
        for k, v in over.items():
            out[k] = _merge(base[k], v) if k in base else copy.deepcopy(v)
        return out
    return copy.deepcopy(over)


def _adjust(spec: dict[str, Any], adjustments: Mapping[str, Any], name: str, where: str) -> dict[str, Any]:
    issues = []
    for block in _NAMED:
        given, made = adjustments.get(block), spec.get(block) or {}
        if given is None:
            continue
        if not isinstance(given, Mapping):
            issues.append(Issue(f"{where}.{block}", f"expected a mapping of names to changes, got {given!r}"))
            continue
        for n in given:
            if n not in made:
                close = difflib.get_close_matches(str(n), list(made), n=3, cutoff=0.5)
                hint = f"did you mean {', '.join(map(repr, close))}? " if close else ""
                issues.append(
                    Issue(
                        f"{where}.{block}.{n}",
                        f"generator '{name}' made no such entry, and a generated tree can only be "
                        f"adjusted, not extended; {hint}{block}: {_listing(list(made))}",
                    )
                )
    if issues:
        raise ConfigError(issues)
    return _merge(spec, {k: v for k, v in adjustments.items() if v is not None})


def expand_tree(spec: Mapping[str, Any], where: str = "tree") -> dict[str, Any]:
    """The tree spec ``spec`` declares: its generator's output (adjusted), or ``spec`` itself if written out.

    Raises ConfigError naming ``<where>.generator`` for an unknown generator and ``<where>.<key>`` for a
    parameter its ``Params`` refuses, every problem at once.
    """
    if "generator" not in spec:
        return dict(spec)
    name = spec["generator"]
    if not isinstance(name, str) or name not in TREE_GENERATORS:
        raise ConfigError([Issue(f"{where}.generator", TREE_GENERATORS.unknown_message(name))])
    entry = TREE_GENERATORS.get(name)
    fields = entry.params.model_fields
    params = {k: v for k, v in spec.items() if k != "generator" and (k in fields or k not in SPEC_KEYS)}
    adjustments = {k: v for k, v in spec.items() if k in SPEC_KEYS and k not in fields}
    try:
        validated = entry.validate(params)
    except ValidationError as e:
        # nested keys get the allowed keys of the model that refused them; top-level ones also the tree-spec keys
        issues = issues_from_pydantic(e, where, entry.params)
        raise ConfigError([_with_spec_keys(i, where, fields) for i in issues]) from None
    try:
        generated = entry.obj(validated)
    except (ValueError, KeyError, TypeError) as e:  # a generator's own check of a combination of parameters
        raise ConfigError([Issue(where, f"generator '{name}' could not build the tree: {e}")]) from None
    return _adjust(dict(generated), adjustments, name, where)


def _with_spec_keys(issue: Issue, where: str, fields: Mapping[str, Any]) -> Issue:
    """An unknown top-level key may be a misspelt parameter or a misspelt tree-spec key: offer both."""
    key = issue.path[len(where) + 1 :]
    if not issue.message.startswith("unknown key") or "." in key:  # not one said of a key inside a block
        return issue
    spec_keys = [k for k in SPEC_KEYS if k not in fields]
    close = difflib.get_close_matches(key, [*fields, *spec_keys], n=3, cutoff=0.5)
    hint = f"; did you mean {', '.join(map(repr, close))}?" if close else ""
    return Issue(
        issue.path,
        f"unknown key (misspelt?); remove it or use one of the allowed keys (allowed: "
        f"{', '.join(fields)}; tree-spec keys adjusting the generated tree: "
        f"{', '.join(spec_keys)}){hint}",
    )
