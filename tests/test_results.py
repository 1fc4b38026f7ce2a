"""The documentation's results tables are what the stored runs say: each table backed by results/ is regenerated
from the metrics.json files there with the table tool that made it and must equal the page's text (README.md or a page
of docs/); every other results table is listed in results/tables.yaml as not yet backed, with the commands that would
back it."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from conftest import DOC_PAGES, page_name

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "results"
sys.path.insert(0, str(ROOT / "tools"))
import apg_table
import camera_run
import compare_metrics
import dagger_table
import expert_design_table
import lasa_methods_table
import lasa_table
import leaves_table
import recorded_arm_table
import reproduce_2d
import task_table

MARKER = re.compile(r"^<!-- results table: (\S+) -->$")
TABLES = yaml.safe_load((RESULTS / "tables.yaml").read_text(encoding="utf-8"))
RUNS = yaml.safe_load((RESULTS / "runs.yaml").read_text(encoding="utf-8"))

#: the table tools, by the name tables.yaml gives them: {row label: metrics} -> the table's markdown
TOOLS = {
    "reproduce_2d": reproduce_2d.table,
    "lasa_table": lasa_table.table_of,
    "lasa_choice": lasa_table.choice_table,
    "task_table": task_table.table,
    "leaves_table": leaves_table.table,
    "dagger_table": dagger_table.markdown_table,
    "expert_design_table": expert_design_table.table,
    "recorded_arm_table": recorded_arm_table.table,
    "lasa_methods_table": lasa_methods_table.table,
    "apg_table": apg_table.table_of,
    "camera_run": camera_run.table,
}


def _marked() -> dict[str, tuple[str, int, str]]:
    """{id: (page, first line's index, the table's text)} for every table of the documentation that a
    ``<!-- results table: ID -->`` line precedes (blank or prose lines may come between)."""
    out: dict[str, tuple[str, int, str]] = {}
    for page in DOC_PAGES:
        lines = page.read_text(encoding="utf-8").splitlines()
        for i, line in enumerate(lines):
            m = MARKER.match(line)
            if m:
                j = i + 1
                while j < len(lines) and not lines[j].startswith("|"):
                    j += 1
                k = j
                while k < len(lines) and lines[k].startswith("|"):
                    k += 1
                assert m.group(1) not in out, (
                    f"two tables are marked {m.group(1)}: {page_name(page)} and {out[m.group(1)][0]}"
                )
                out[m.group(1)] = (page_name(page), j, "\n".join(lines[j:k]) + "\n")
    return out


def readme_tables() -> dict[str, str]:
    """{id: the table's text} of every marked table of the documentation."""
    return {name: text for name, (_, _, text) in _marked().items()}


def stored(run: str) -> dict:
    return json.loads((RESULTS / run / "metrics.json").read_text(encoding="utf-8"))


def test_every_marked_readme_table_is_listed_and_every_listed_table_is_in_the_readme():
    assert set(readme_tables()) == set(TABLES)
    for name, entry in TABLES.items():
        assert ("tool" in entry) != ("pending" in entry), f"{name}: either a tool with its runs, or pending commands"
        if "pending" in entry:
            assert entry["pending"] and all(isinstance(c, str) and c for c in entry["pending"]), name


def test_every_results_table_of_the_documentation_is_marked():
    """Every table with a success, reached or collisions column carries a marker, so none is missed."""
    starts = {(page, start) for page, start, _ in _marked().values()}
    for page in DOC_PAGES:
        lines = page.read_text(encoding="utf-8").splitlines()
        for i, line in enumerate(lines):
            first = line.startswith("| ") and (i == 0 or not lines[i - 1].startswith("|"))
            if first and re.search(r"\b(success|reached|collisions)\b", line):
                where = f"{page_name(page)} line {i + 1}"
                assert (page_name(page), i) in starts, f"{where} starts a results table without a marker: {line[:80]}"


@pytest.mark.parametrize("name", [n for n, e in TABLES.items() if "tool" in e])
def test_a_backed_table_is_regenerated_from_results_exactly(name):
    entry = TABLES[name]
    runs = {label: stored(run) for label, run in entry["runs"].items()}
    assert TOOLS[entry["tool"]](runs) == readme_tables()[name]


def test_every_stored_run_says_how_it_was_made_and_is_used_by_a_table():
    used = {run for e in TABLES.values() if "runs" in e for run in e["runs"].values()}
    assert used <= set(RUNS), sorted(used - set(RUNS))
    for run, info in RUNS.items():
        assert {"command", "commit", "seed", "wall_time_s"} <= set(info), run
        m = stored(run)
        assert m["seed"] == info["seed"] and m["timing"]["total_s"] == pytest.approx(info["wall_time_s"], abs=1)
        assert re.fullmatch(r"[0-9a-f]{40}", info["commit"]), run
        known = subprocess.run(["git", "cat-file", "-e", f"{info['commit']}^{{commit}}"], cwd=ROOT, capture_output=True)
        if known.returncode != 0:  # a shallow clone may lack it; a full one must have it
            shallow = subprocess.run(
                ["git", "rev-parse", "--is-shallow-repository"], cwd=ROOT, capture_output=True, text=True
            ).stdout.strip()
            assert shallow == "true", f"{run}: commit {info['commit']} is not in this repository"
        assert run in used, f"results/{run} is stored but no table of the documentation reads it"


def test_compare_metrics_finds_a_stored_run_by_its_name():
    run = next(iter(RUNS))
    assert compare_metrics.metrics_path(RESULTS / run) == RESULTS / run / "metrics.json"
    assert compare_metrics.metrics_path(RESULTS / run / "metrics.json") == RESULTS / run / "metrics.json"
    n, worst, differ, one_sided = compare_metrics.compare(stored(run), stored(run), rtol=0.0)
    assert n > 50 and worst == 0 and not differ and not one_sided
