"""The registry reference, generated from the code when the site is built.

Every ``Registry`` object in ``rmpfusion.registry`` (those added later included: they are found by type, never by a
list kept here) becomes one page of ``docs/reference/``; every entry becomes a section with the class or function
that implements it, the first paragraph of its docstring, and a table of its parameters read from its pydantic
model: name, type, allowed range, default and description. Plugins installed in the environment that builds the site
appear with the built-ins, so a new entry needs no page written by hand.

``reference_pages()`` is what the Sphinx hook writes and what ``tests/test_docs.py`` compares with the registries.
"""

from __future__ import annotations

import importlib
import inspect
import re
import types
import typing
from pathlib import Path
from typing import Any

import annotated_types
from pydantic import BaseModel
from pydantic_core import PydanticUndefined

#: The packages whose import registers the built-in entries (the registries themselves know no modules).
REGISTERING_PACKAGES = (
    "rmpfusion.assembly",
    "rmpfusion.envs",
    "rmpfusion.learn",
    "rmpfusion.recordings",
    "rmpfusion.robots",
)

_BOUNDS = {"gt": ">", "ge": "≥", "lt": "<", "le": "≤"}  # annotated_types' Gt, Ge, Lt, Le, by their attribute


def registries() -> dict[str, Any]:
    """{attribute name in rmpfusion.registry: Registry}, built-ins and installed plugins registered."""
    for package in REGISTERING_PACKAGES:
        importlib.import_module(package)
    registry = importlib.import_module("rmpfusion.registry")
    found = {name: obj for name, obj in vars(registry).items() if isinstance(obj, registry.Registry)}
    for reg in found.values():
        reg.load_plugins()
    return found


def page_name(attribute: str) -> str:
    """``TASK_MAPS`` -> ``task-maps``: the page's file name (without .md) under docs/reference/."""
    return attribute.lower().replace("_", "-")


def _type_name(annotation: Any) -> str:
    if annotation is None or annotation is type(None):
        return "None"
    origin = typing.get_origin(annotation)
    if origin is typing.Literal:
        return " | ".join(repr(a) for a in typing.get_args(annotation))
    if origin is typing.Annotated:
        return _type_name(typing.get_args(annotation)[0])
    if origin is not None:
        args = [_type_name(a) for a in typing.get_args(annotation)]
        if origin in (typing.Union, types.UnionType):
            return " | ".join(args)
        name = getattr(origin, "__name__", str(origin))
        return f"{name}[{', '.join(args)}]" if args else name
    if isinstance(annotation, type):
        return annotation.__name__
    return str(annotation).replace("typing.", "")


def _range(metadata: list[Any]) -> str:
    parts = []
    for m in metadata:
        for attribute, symbol in _BOUNDS.items():
            if isinstance(m, annotated_types.BaseMetadata) and hasattr(m, attribute):
                parts.append(f"{symbol} {getattr(m, attribute)}")
        if isinstance(m, annotated_types.MinLen):
            parts.append(f"length ≥ {m.min_length}")
        if isinstance(m, annotated_types.MaxLen):
            parts.append(f"length ≤ {m.max_length}")
        if isinstance(m, annotated_types.MultipleOf):
            parts.append(f"multiple of {m.multiple_of}")
    return ", ".join(parts)


def _default(field: Any) -> str:
    if field.default is PydanticUndefined:
        return "required" if field.default_factory is None else f"`{field.default_factory()!r}`"
    value = field.default.model_dump() if isinstance(field.default, BaseModel) else field.default
    return f"`{value!r}`"


def _cell(text: str) -> str:
    return " ".join(str(text).split()).replace("|", "\\|")


def parameter_rows(params: type[BaseModel]) -> list[tuple[str, str, str, str, str]]:
    """(name, type, range, default, description) of every field of an entry's parameter model."""
    return [
        (name, _type_name(field.annotation), _range(field.metadata), _default(field), field.description or "")
        for name, field in params.model_fields.items()
    ]


def _summary(obj: Any) -> str:
    """The first paragraph of the docstring of what the entry registers, as one line."""
    doc = inspect.getdoc(obj) or ""
    return " ".join(doc.split("\n\n")[0].split())


def registry_page(attribute: str, registry: Any) -> str:
    lines = [
        f"# {registry.kind[0].upper()}{registry.kind[1:]}s (`{attribute}`)",
        "",
        f"Generated from `rmpfusion.registry.{attribute}` when the site is built: {len(registry.names())} entries.",
        "A config names an entry by its name and gives the parameters below; a key not listed is refused.",
        "",
    ]
    for entry in sorted(registry.entries(), key=lambda e: e.name):
        lines += [f"## {entry.name}", "", f"`{entry.owner}`.", ""]  # the class or function the name registers
        summary = _summary(entry.obj)
        if summary:
            lines += [_cell(summary), ""]
        rows = parameter_rows(entry.params)
        if not rows:
            lines += ["No parameters.", ""]
            continue
        lines += ["| parameter | type | range | default | description |", "|---|---|---|---|---|"]
        lines += ["| " + " | ".join(_cell(c) if k else f"`{c}`" for k, c in enumerate(row)) + " |" for row in rows]
        lines.append("")
    return "\n".join(lines).rstrip() + "\n"


def index_page(found: dict[str, Any]) -> str:
    lines = [
        "# Registry reference",
        "",
        "Every building block a config can name, by registry, with its parameters: generated from",
        "`rmpfusion.registry` when the site is built, plugins installed in the building environment included.",
        "",
        "| registry | kind | entries |",
        "|---|---|---|",
    ]
    lines += [
        f"| [{attr}]({page_name(attr)}.md) | {reg.kind} | {len(reg.names())} |" for attr, reg in sorted(found.items())
    ]
    lines += ["", "```{toctree}", ":hidden:", ""]
    lines += [page_name(attr) for attr in sorted(found)]
    lines += ["```", ""]
    return "\n".join(lines)


def reference_pages() -> dict[str, str]:
    """{file name under docs/reference/: page text}."""
    found = registries()
    pages = {f"{page_name(attr)}.md": registry_page(attr, reg) for attr, reg in found.items()}
    pages["index.md"] = index_page(found)
    return pages


def write_reference(out: Path) -> None:
    """Write the pages, replacing only files whose text changed (Sphinx then rebuilds only those)."""
    out.mkdir(parents=True, exist_ok=True)
    pages = reference_pages()
    for stale in {p.name for p in out.glob("*.md")} - set(pages):
        (out / stale).unlink()
    for name, text in pages.items():
        path = out / name
        if not path.exists() or path.read_text() != text:
            path.write_text(text)


def _on_builder_inited(app: Any) -> None:
    write_reference(Path(app.srcdir) / "reference")


def setup(app: Any) -> dict[str, Any]:
    app.connect("builder-inited", _on_builder_inited)
    return {"parallel_read_safe": True, "parallel_write_safe": True}


if __name__ == "__main__":  # python docs/_ext/registry_reference.py: the pages, written without Sphinx
    write_reference(Path(__file__).resolve().parents[1] / "reference")
    print(re.sub(r"\n+", "\n", "\n".join(sorted(reference_pages()))))
