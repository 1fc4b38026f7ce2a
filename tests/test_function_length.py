"""No function of the package or of tools/ runs over 80 lines (from its ``def`` to its last line, decorators not
counted): a longer one is split into functions whose names say what each part does."""

from __future__ import annotations

import ast
import pathlib

ROOT = pathlib.Path(__file__).resolve().parents[1]
LIMIT = 80


def long_functions(source: str, where: str, limit: int = LIMIT) -> list[str]:
    """Every function (methods and nested functions included) of ``source`` longer than ``limit`` lines, one line
    each: ``where:line name (n lines)``."""
    return [
        f"{where}:{node.lineno} {node.name} ({node.end_lineno - node.lineno + 1} lines)"
        for node in ast.walk(ast.parse(source))
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef)
        and (node.end_lineno or node.lineno) - node.lineno + 1 > limit
    ]


def test_no_function_of_the_package_or_the_tools_is_over_80_lines():
    paths = sorted((ROOT / "rmpfusion").rglob("*.py")) + sorted((ROOT / "tools").rglob("*.py"))
    found = [v for p in paths for v in long_functions(p.read_text(encoding="utf-8"), str(p.relative_to(ROOT)))]
    assert not found, f"functions over {LIMIT} lines (split them):\n" + "\n".join(found)


def test_the_length_check_counts_from_def_to_the_last_line_without_decorators():
    def body(n: int, indent: str = "    ") -> str:
        return "".join(f"{indent}x{i} = {i}\n" for i in range(n))

    fits = f"@decorator\n@another\ndef fits():\n{body(79)}"  # def and 79 lines: 80, the decorators not counted
    assert long_functions(fits, "m.py") == []
    method = f"class A:\n    def over(self):\n{body(80, ' ' * 8)}"  # a method of 81 lines
    assert long_functions(method, "m.py") == ["m.py:2 over (81 lines)"]
