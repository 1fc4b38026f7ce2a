"""``rmpfusion-study``: run, store, table and check the studies of conf/study/.

    rmpfusion-study list                                   # every study, its runs and what is stored
    rmpfusion-study run franka [--only franka] [--store] [HYDRA OVERRIDES ...]
    rmpfusion-study table franka [--write]                 # its tables from results/, against the pages
    rmpfusion-study check franka --out outputs/studies/franka [--rtol 1e-6]
    rmpfusion-study compare results/franka/franka/seed0 outputs/.../0   # any two runs' metrics

``run`` runs each experiment run as one Hydra multirun below ``--out`` (default ``outputs/studies/<study>``): the
arguments after the study's name go to every job (``hydra/launcher=joblib``, ``train.iterations=20``), and with
``--store`` each finished job's metrics.json is copied to ``results/<study>/<job>/`` with how it was made.
``table`` exits 1 when a page's table differs from what the stored metrics give (``--write`` rewrites the pages).
``check`` compares every job found below ``--out`` with the stored one and exits 1 when a number differs.
"""

from __future__ import annotations

import argparse
import platform
import sys
from pathlib import Path

from ..pipeline.compose import conf_dir
from ..studies.compare import compare, metrics_path, read_metrics
from ..studies.launch import job_command_line, job_dirs, run_study
from ..studies.pages import marked_tables, replace_table
from ..studies.spec import Study, StudyError, load_study, study_names
from ..studies.store import require_stored, results_dir, store_job, stored_metrics
from ..studies.tables import TABLE_KINDS
from ._common import CONFIG_ERROR_EXIT


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="rmpfusion-study", description=__doc__.split("\n\n")[0])
    ap.add_argument("--root", type=Path, default=Path.cwd(), help="the repository (results/ and docs/); default: .")
    ap.add_argument("--config-dir", type=Path, default=None, help="the configuration directory (default: conf/)")
    sub = ap.add_subparsers(dest="verb", required=True)
    sub.add_parser("list", help="every study, its runs and what is stored")
    run = sub.add_parser("run", help="run a study's runs as Hydra multiruns")
    run.add_argument("study")
    run.add_argument("--only", nargs="+", default=[], metavar="RUN", help="these runs of the study")
    run.add_argument("--out", type=Path, default=None, help="where the runs go (default outputs/studies/<study>)")
    run.add_argument("--input", action="append", default=[], metavar="NAME=VALUE", help="a study's declared input")
    run.add_argument("--store", action="store_true", help="copy each finished job's metrics into results/")
    run.add_argument("--dry-run", action="store_true", help="print the commands, run nothing")
    table = sub.add_parser("table", help="a study's tables from its stored metrics, against the pages")
    table.add_argument("study", nargs="?", help="default: every study")
    table.add_argument("--write", action="store_true", help="rewrite the pages' tables")
    check = sub.add_parser("check", help="a fresh run of a study against the stored one")
    check.add_argument("study")
    check.add_argument("--out", type=Path, default=None, help="the fresh run (default outputs/studies/<study>)")
    check.add_argument("--rtol", type=float, default=1e-6, help="largest relative difference counted as equal")
    two = sub.add_parser("compare", help="two runs' metrics.json number by number")
    two.add_argument("first", type=Path, help="a metrics.json or the directory holding it")
    two.add_argument("second", type=Path)
    two.add_argument("--rtol", type=float, default=1e-12)
    return ap


def _list(root: Path, config: Path) -> int:
    for name in study_names(config):
        study = load_study(name, config)
        jobs = study.jobs()
        stored = sum((results_dir(root, name) / j.id / "metrics.json").is_file() for j in jobs)
        print(
            f"{name}: {study.description} ({len(study.runs)} runs, {stored} of {len(jobs)} jobs stored; {study.page})"
        )
    return 0


def _run(a: argparse.Namespace, extra: list[str], root: Path, config: Path) -> int:
    study = load_study(a.study, config)
    out = (a.out or root / "outputs" / "studies" / a.study).resolve()
    inputs = dict(item.partition("=")[::2] for item in a.input)
    status = run_study(study, out, a.only, inputs, extra, a.dry_run)
    if status or a.dry_run or not a.store:
        return status
    machine = f"{platform.node()}, {platform.processor() or platform.machine()}"
    jobs = {j.id: j for j in study.jobs()}
    for job_id, run_dir in job_dirs(study, out).items():
        job = jobs[job_id]
        if a.only and job.run not in a.only:
            continue
        replaced = (results_dir(root, a.study) / job_id / "metrics.json").is_file()
        store_job(root, a.study, job_id, run_dir, job_command_line(study, job), machine)
        print(f"stored {job_id}{' (replacing the stored one)' if replaced else ''}")
    return 0


def regenerated_tables(root: Path, name: str, study: Study) -> dict[str, str]:
    """{table id: its Markdown} of a study, from its stored metrics."""
    require_stored(root, name, sorted({j for t in study.tables.values() for j in t.rows.values()}))
    return {
        tid: TABLE_KINDS[t.kind]({label: stored_metrics(root, name, job) for label, job in t.rows.items()})
        for tid, t in study.tables.items()
    }


def _table(a: argparse.Namespace, root: Path, config: Path) -> int:
    pages = marked_tables(root)
    differ = 0
    for name in [a.study] if a.study else study_names(config):
        study = load_study(name, config)
        for tid, text in regenerated_tables(root, name, study).items():
            marked = pages.get(tid)
            if marked is None or marked.page != study.page_of(tid):
                raise StudyError(
                    f"study {name}: table {tid} belongs on {study.page_of(tid)}, but "
                    + (f"it is marked on {marked.page}" if marked else "no page marks it")
                    + f"; put '<!-- results table: {tid} -->' above it there"
                )
            if marked.text == text:
                print(f"{name}: {tid} ({marked.page}) as stored")
            elif a.write:
                replace_table(root, marked, text)
                pages = marked_tables(root)
                print(f"{name}: {tid} ({marked.page}) rewritten from the stored metrics")
            else:
                differ += 1
                print(f"{name}: {tid} ({marked.page}) DIFFERS from the stored metrics (--write rewrites it)")
    return 1 if differ else 0


def _check(a: argparse.Namespace, root: Path, config: Path) -> int:
    study = load_study(a.study, config)
    out = (a.out or root / "outputs" / "studies" / a.study).resolve()
    fresh = job_dirs(study, out)
    if not fresh:
        raise StudyError(f"no finished job of study {a.study} below {out}; run it first: rmpfusion-study run {a.study}")
    failed = 0
    for job_id, run_dir in fresh.items():
        n, worst, differ, one_sided = compare(
            stored_metrics(root, a.study, job_id), read_metrics(run_dir / "metrics.json"), a.rtol
        )
        verdict = "same" if not differ else f"{len(differ)} DIFFER"
        print(
            f"{job_id}: {n} numbers, largest relative difference {worst:.3g}: {verdict}; {len(one_sided)} keys on one side only"
        )
        for line in differ[:20]:
            print(f"  {line}")
        failed += bool(differ)
    return 1 if failed else 0


def _compare(a: argparse.Namespace) -> int:
    first, second = (read_metrics(metrics_path(p)) for p in (a.first, a.second))
    n, worst, differ, one_sided = compare(first, second, a.rtol)
    print(
        f"{n} values compared, largest relative difference {worst:.3g}; {len(differ)} differ beyond rtol={a.rtol:g}; "
        f"{len(one_sided)} keys on one side only"
    )
    for line in differ + one_sided:
        print(line)
    return 1 if differ else 0


def main(argv: list[str] | None = None) -> int:
    a, extra = _parser().parse_known_args(argv)
    if a.verb == "run":  # a Hydra override after --only RUN ... is an override, not a run's name
        extra = [*(x for x in a.only if "=" in x), *extra]
        a.only = [x for x in a.only if "=" not in x]
    if extra and a.verb != "run":
        _parser().error(f"unrecognized arguments: {' '.join(extra)}")
    root = a.root.resolve()
    config = a.config_dir.resolve() if a.config_dir else Path(conf_dir())
    try:
        if a.verb == "list":
            return _list(root, config)
        if a.verb == "run":
            return _run(a, extra, root, config)
        if a.verb == "table":
            return _table(a, root, config)
        if a.verb == "check":
            return _check(a, root, config)
        return _compare(a)
    except ValueError as e:  # StudyError, and a damaged metrics.json
        print(f"error: {e}", file=sys.stderr)
        return CONFIG_ERROR_EXIT


if __name__ == "__main__":
    sys.exit(main())
