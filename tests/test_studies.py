"""Studies (conf/study/): every study validates and every run of it composes into a valid run config (each stored
result is made by a command a user can type); every results table of the documentation belongs to one study, is on
that study's page and regenerates from results/ exactly; every stored job says how it was made and is read by a
table; and a study runs, stores, tables and checks end to end at smoke size."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from conftest import DOC_PAGES, ROOT, page_name

from rmpfusion.cli import study as study_cli
from rmpfusion.pipeline.compose import compose_config
from rmpfusion.pipeline.validate import resolve_and_validate
from rmpfusion.studies.compare import compare, metrics_path
from rmpfusion.studies.launch import job_command_line
from rmpfusion.studies.pages import marked_tables
from rmpfusion.studies.spec import StudyError, load_study, study_names
from rmpfusion.studies.store import PROVENANCE_KEYS, provenance, provenance_header, results_dir, stored_metrics

CONF = ROOT / "conf"
STUDIES = {name: load_study(name, CONF) for name in study_names(CONF)}
EXPERIMENT_RUNS = [
    (name, run_name) for name, s in STUDIES.items() for run_name, run in s.runs.items() if run.experiment is not None
]


def test_the_studies_are_the_ones_the_results_pages_are_made_of():
    assert set(STUDIES) >= {"paper_2d", "franka", "arms", "world", "training_methods", "lasa", "recorded_arm"}


@pytest.mark.parametrize(("study", "run"), EXPERIMENT_RUNS, ids=[f"{s}:{r}" for s, r in EXPERIMENT_RUNS])
def test_every_run_of_a_study_composes_into_a_valid_run_config(study, run, tmp_path):
    """The first job of every experiment run, as ``rmpfusion-study run`` gives it to rmpfusion-run, composes and
    validates (the data a run reads may be made by its ``prepare`` commands: those are not run here)."""
    spec = STUDIES[study].runs[run]
    job = spec.jobs(run)[0]
    if spec.prepare:
        pytest.skip("its data are made by its prepare commands when it runs")
    overrides = [f"experiment={spec.experiment}", *spec.overrides, f"seed={job.seed}", *job.settings, "logger=disabled"]
    resolve_and_validate(compose_config(overrides))


def test_every_marked_table_belongs_to_one_study_and_is_on_its_page():
    marked = marked_tables(ROOT)
    owners: dict[str, str] = {}
    for name, s in STUDIES.items():
        for tid in s.tables:
            assert tid not in owners, f"table {tid} is listed by studies {owners.get(tid)} and {name}"
            owners[tid] = name
            assert tid in marked, f"study {name} lists table {tid}, which no page marks"
            assert marked[tid].page == s.page_of(tid), (
                f"{tid}: on {marked[tid].page}, study {name} says {s.page_of(tid)}"
            )
    assert set(marked) <= set(owners), f"marked tables no study makes: {sorted(set(marked) - set(owners))}"


def test_every_results_table_of_the_documentation_is_marked():
    """Every table with a success, reached or collisions column carries a marker, so none is missed."""
    starts = {(t.page, t.start) for t in marked_tables(ROOT).values()}
    for page in DOC_PAGES:
        lines = page.read_text(encoding="utf-8").splitlines()
        for i, line in enumerate(lines):
            first = line.startswith("| ") and (i == 0 or not lines[i - 1].startswith("|"))
            if first and re.search(r"\b(success|reached|collisions)\b", line):
                where = f"{page_name(page)} line {i + 1}"
                assert (page_name(page), i) in starts, f"{where} starts a results table without a marker: {line[:80]}"


@pytest.mark.parametrize("study", sorted(STUDIES))
def test_a_studys_tables_regenerate_from_results_exactly(study):
    marked = marked_tables(ROOT)
    for tid, text in study_cli.regenerated_tables(ROOT, study, STUDIES[study]).items():
        assert text == marked[tid].text, f"{tid} on {marked[tid].page} differs from what results/{study} gives"


@pytest.mark.parametrize("study", sorted(STUDIES))
def test_every_stored_job_says_how_it_was_made_and_is_read_by_a_table(study):
    s, made = STUDIES[study], provenance(ROOT, study)
    jobs = {j.id for j in s.jobs()}
    used = {job for t in s.tables.values() for job in t.rows.values()}
    stored = {
        str(p.parent.relative_to(results_dir(ROOT, study))) for p in results_dir(ROOT, study).rglob("metrics.json")
    }
    assert stored <= jobs, f"results/{study} holds jobs the study does not make: {sorted(stored - jobs)[:5]}"
    assert stored == set(made), (
        f"results/{study}/runs.yaml and the stored jobs differ: {sorted(stored ^ set(made))[:5]}"
    )
    assert stored == used, f"stored but read by no table, or read but not stored: {sorted(stored ^ used)[:5]}"
    for job, info in made.items():
        assert set(PROVENANCE_KEYS) <= set(info), job
        m = stored_metrics(ROOT, study, job)
        assert m["seed"] == info["seed"] and m["timing"]["total_s"] == pytest.approx(info["wall_time_s"], abs=1), job
        assert re.fullmatch(r"[0-9a-f]{40}", info["commit"]), job
        known = subprocess.run(["git", "cat-file", "-e", f"{info['commit']}^{{commit}}"], cwd=ROOT, capture_output=True)
        if known.returncode != 0:  # a shallow clone may lack it; a full one must have it
            shallow = subprocess.run(
                ["git", "rev-parse", "--is-shallow-repository"], cwd=ROOT, capture_output=True, text=True
            ).stdout.strip()
            assert shallow == "true", f"{study}/{job}: commit {info['commit']} is not in this repository"


def test_a_jobs_command_is_one_a_user_can_type():
    s = STUDIES["franka"]
    job = next(j for j in s.jobs() if j.id == "franka/seed1")
    assert job_command_line(s, job) == "rmpfusion-run experiment=franka eval.unit_weights=true seed=1 logger=disabled"
    lasa = STUDIES["lasa"]
    job = next(j for j in lasa.jobs() if j.id == "both/Sshape")
    assert job_command_line(lasa, job).endswith("seed=0 data.shape=Sshape logger=disabled")


def test_compare_finds_a_stored_run_by_its_directory():
    job = ROOT / "results" / "paper_2d" / "2d1level"
    assert metrics_path(job) == job / "metrics.json"
    m = stored_metrics(ROOT, "paper_2d", "2d1level")
    n, worst, differ, one_sided = compare(m, m, rtol=0.0)
    assert n > 50 and worst == 0 and not differ and not one_sided


# ---------------------------------------------------------------------------------------------- bad study files
def _study_dir(tmp_path: Path, text: str) -> Path:
    (tmp_path / "study").mkdir()
    (tmp_path / "study" / "bad.yaml").write_text(text)
    return tmp_path


@pytest.mark.parametrize(
    ("text", "said"),
    [
        ("description: x\npage: p.md\nruns: {a: {experiment: franka, seeds: [1, 1]}}\n", "runs.a.seeds"),
        ("description: x\npage: p.md\nruns: {a: {experiment: franka, command: ls}}\n", "either experiment"),
        ("description: x\npage: p.md\nruns: {a: {experiment: franka, overides: []}}\n", "runs.a.overides"),
        (
            "description: x\npage: p.md\nruns: {a: {experiment: franka}}\ntables: {t: {kind: tasks, rows: {r: a}}}\n",
            "unknown table kind 'tasks'",
        ),
        (
            "description: x\npage: p.md\nruns: {a: {experiment: franka}}\ntables: {t: {kind: task, rows: {r: b}}}\n",
            "which no run of the study makes",
        ),
        ("description: x\npage: p.md\nruns: {a: {command: 'python t.py {ckpt}'}}\n", "inputs do not declare"),
    ],
)
def test_a_bad_study_file_is_one_line_naming_the_file_and_key(tmp_path, text, said):
    with pytest.raises(StudyError) as e:
        load_study("bad", _study_dir(tmp_path, text))
    assert "bad.yaml" in str(e.value) and said in str(e.value) and "\n" not in str(e.value)


def test_an_unknown_study_names_the_known_ones(capsys):
    assert study_cli.main(["table", "franca"]) == 2
    err = capsys.readouterr().err
    assert "no study 'franca'" in err and "franka" in err and "Traceback" not in err


# --------------------------------------------------------------------------------------------- end to end, tiny
SMOKE = """description: the 2D experiment at smoke size, two seeds
page: docs/smoke.md
runs:
  tiny:
    experiment: 2d1level
    overrides: [data=tiny, train=tiny, eval=fast, eval.figures=false]
    seeds: [0, 1]
tables:
  smoke-2d:
    kind: paper_2d
    rows: {2d1level: tiny/seed0, 2d1level seed 1: tiny/seed1}
"""


def test_a_study_runs_stores_tables_and_checks_end_to_end(tmp_path):
    """``rmpfusion-study run --store`` makes both seeds as one multirun and stores them with how they were made;
    ``table --write`` puts the table on its page, ``table`` then finds it as stored; ``check`` finds a second run
    equal to the stored one, and a changed stored number is reported."""
    root, config = tmp_path / "repo", tmp_path / "conf"
    (root / "docs").mkdir(parents=True)
    (root / "README.md").write_text("# smoke\n")
    (root / "docs" / "smoke.md").write_text("# smoke\n\n<!-- results table: smoke-2d -->\n\n| old |\n|---|\n\nafter\n")
    (config / "study").mkdir(parents=True)
    (config / "study" / "smoke.yaml").write_text(SMOKE)
    study = [sys.executable, "-m", "rmpfusion.cli.study", "--root", str(root), "--config-dir", str(config)]

    def call(*args: str) -> subprocess.CompletedProcess:
        return subprocess.run([*study, *args], capture_output=True, text=True, timeout=900, cwd=root)

    r = call("run", "smoke", "--store", "--out", str(tmp_path / "first"))
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-3000:]
    provenance_text = (root / "results" / "smoke" / "runs.yaml").read_text()
    assert provenance_text.startswith(provenance_header("smoke"))  # each write keeps the file's opening comment
    made = yaml.safe_load(provenance_text)
    assert set(made) == {"tiny/seed0", "tiny/seed1"} and made["tiny/seed1"]["seed"] == 1
    assert made["tiny/seed1"]["command"].startswith("rmpfusion-run experiment=2d1level data=tiny")
    assert call("table", "smoke").returncode == 1  # the page still shows the old table
    assert call("table", "smoke", "--write").returncode == 0
    page = (root / "docs" / "smoke.md").read_text()
    assert "| 2d1level seed 1 | expert |" in page and page.endswith("after\n")
    r = call("table", "smoke")
    assert r.returncode == 0 and "as stored" in r.stdout
    r = call("run", "smoke", "--out", str(tmp_path / "second"))
    assert r.returncode == 0, r.stderr[-3000:]
    r = call("check", "smoke", "--out", str(tmp_path / "second"))
    assert r.returncode == 0 and r.stdout.count(": same") == 2, r.stdout
    stored = root / "results" / "smoke" / "tiny" / "seed1" / "metrics.json"
    metrics = json.loads(stored.read_text())
    metrics["learners"]["rmp"]["batch_loss"] *= 1.01
    stored.write_text(json.dumps(metrics))
    r = call("check", "smoke", "--out", str(tmp_path / "second"))
    assert r.returncode == 1 and "tiny/seed1" in r.stdout and "1 DIFFER" in r.stdout, r.stdout
    assert "learners.rmp.batch_loss" in r.stdout
