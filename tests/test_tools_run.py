"""Every script in tools/ runs as a script: it has a ``main`` and calls it under ``if __name__ == "__main__"`` (a script
whose entry point is lost exits 0 doing nothing, which a long run's log would only show as empty)."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

TOOLS = sorted(p for p in (Path(__file__).resolve().parents[1] / "tools").glob("*.py") if p.name != "__init__.py")


def _calls_main_when_run(tree: ast.Module) -> bool:
    for node in tree.body:
        if isinstance(node, ast.If) and "__name__" in ast.unparse(node.test) and "__main__" in ast.unparse(node.test):
            return any(isinstance(n, ast.Call) and ast.unparse(n.func) == "main" for n in ast.walk(node))
    return False


@pytest.mark.parametrize("script", TOOLS, ids=lambda p: p.name)
def test_every_tool_calls_its_main_when_run(script):
    tree = ast.parse(script.read_text(encoding="utf-8"))
    assert any(isinstance(n, ast.FunctionDef) and n.name == "main" for n in tree.body), f"{script.name}: no main()"
    assert _calls_main_when_run(tree), f'{script.name}: main() is never called under if __name__ == "__main__"'
