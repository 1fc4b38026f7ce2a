"""Collected configuration errors: every problem at once, each with its path, what was given and the fix."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Iterable

from pydantic import ValidationError


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


def issues_from_pydantic(err: ValidationError, prefix: str) -> list[Issue]:
    """Turn a pydantic error into path-named issues (``prefix.key.sub``), with the value given."""
    out = []
    for e in err.errors():
        loc = ".".join(str(p) for p in e["loc"])
        path = f"{prefix}.{loc}" if loc else prefix
        msg = e["msg"]
        if e["type"] == "extra_forbidden":
            msg = "unknown key (misspelt?); remove it or use one of the allowed keys"
        elif e["type"] == "missing":
            msg = "required key is missing"
        elif "input" in e and e["type"] not in ("missing",):
            msg = f"{msg} (given: {_show(e['input'])})"
        out.append(Issue(path, msg))
    return out


def allowed_keys_hint(model: type, path: str, issues: list[Issue]) -> list[Issue]:
    """Append the model's allowed keys to its 'unknown key' issues."""
    allowed = ", ".join(model.model_fields)
    return [
        Issue(i.path, f"{i.message} (allowed: {allowed or 'none'})") if "unknown key" in i.message else i for i in issues
    ]
