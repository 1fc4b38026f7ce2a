"""The results tables of the documentation's pages: each follows a ``<!-- results table: ID -->`` line (blank or
prose lines may come between) and is regenerated from stored metrics by the study that lists it."""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

MARKER = re.compile(r"^<!-- results table: (\S+) -->$")


@dataclass(frozen=True)
class MarkedTable:
    """Where a marked table is: its page (from the repository root), its first and past-last line, its text."""

    page: str
    start: int
    end: int
    text: str


def doc_pages(root: Path) -> list[Path]:
    """README.md and every Markdown page of docs/ but the generated reference and the build."""
    docs = root / "docs"
    skipped = ("reference", "_build", "_ext")
    return [root / "README.md", *sorted(p for p in docs.rglob("*.md") if p.relative_to(docs).parts[0] not in skipped)]


def marked_tables(root: Path) -> dict[str, MarkedTable]:
    """{id: the table} of every marked table of the documentation; a ValueError when an id is marked twice."""
    out: dict[str, MarkedTable] = {}
    for path in doc_pages(root):
        page = str(path.relative_to(root))
        lines = path.read_text(encoding="utf-8").splitlines()
        for i, line in enumerate(lines):
            m = MARKER.match(line)
            if not m:
                continue
            start = next((j for j in range(i + 1, len(lines)) if lines[j].startswith("|")), len(lines))
            end = next((k for k in range(start, len(lines)) if not lines[k].startswith("|")), len(lines))
            if m.group(1) in out:
                raise ValueError(f"two tables are marked {m.group(1)}: {page} and {out[m.group(1)].page}")
            out[m.group(1)] = MarkedTable(page, start, end, "\n".join(lines[start:end]) + "\n")
    return out


def replace_table(root: Path, table: MarkedTable, text: str) -> None:
    """Write ``text`` (a Markdown table with its trailing newline) in the place of ``table`` on its page."""
    path = root / table.page
    lines = path.read_text(encoding="utf-8").splitlines()
    new = [*lines[: table.start], *text.rstrip("\n").split("\n"), *lines[table.end :]]
    path.write_text("\n".join(new) + "\n", encoding="utf-8")
