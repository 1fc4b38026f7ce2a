"""How a study's runs are run: each experiment run as one Hydra multirun of ``rmpfusion-run`` (its seeds and sweep
axes the multirun's axes, so a launcher such as joblib or SLURM runs it unchanged), each tool run as its command;
and where each job's run directory is afterwards."""

from __future__ import annotations

import shlex
import subprocess
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path

import yaml

from .spec import PLACEHOLDER, Job, Study, StudyError, StudyRun


def _filled(text: str, out: Path, inputs: Mapping[str, str]) -> str:
    """``text`` with ``{out}`` and each ``{<input>}`` filled in; other braces (a Hydra dict value) kept."""
    values = {"out": str(out), **inputs}
    return PLACEHOLDER.sub(lambda m: values.get(m.group(1), m.group(0)), text)


def _tool_argv(argv: list[str]) -> list[str]:
    """A tool's command as written (``python tools/x.py ...``) run by this interpreter."""
    return [sys.executable, *argv[1:]] if argv and argv[0] in ("python", "python3") else argv


def experiment_command(run: StudyRun, run_dir: Path, inputs: Mapping[str, str], extra: Sequence[str]) -> list[str]:
    """One ``rmpfusion-run --multirun`` over every job of an experiment run, its jobs under ``run_dir``."""
    assert run.experiment is not None
    axes = [f"{key}={','.join(values)}" for key, values in run.sweep.items()]
    return [
        sys.executable,
        "-m",
        "rmpfusion.cli.run",
        "--multirun",
        f"experiment={run.experiment}",
        *(_filled(o, run_dir, inputs) for o in run.overrides),
        f"seed={','.join(str(s) for s in run.seeds)}",
        *axes,
        "logger=disabled",
        f"hydra.sweep.dir={run_dir}",
        # a job's directory named by its number and name alone: a run's overrides can pass the file system's 255
        # bytes in Hydra's default name, and job_dirs finds each job by its .hydra/overrides.yaml anyway
        "hydra.sweep.subdir=${hydra.job.num}_${name}",
        *extra,
    ]


def tool_command(run: StudyRun, job: Job, job_dir: Path, inputs: Mapping[str, str]) -> list[str]:
    """A tool run's command for one job: its command line, its overrides, then the job's sweep settings."""
    assert run.command is not None
    argv = shlex.split(_filled(run.command, job_dir, inputs))
    return _tool_argv([*argv, *(_filled(o, job_dir, inputs) for o in run.overrides), *job.settings])


def job_command_line(study: Study, job: Job) -> str:
    """The command that makes one job, as a user would type it (what results/<study>/runs.yaml records)."""
    run = study.runs[job.run]
    if run.command is not None:
        return " ".join([run.command, *run.overrides, *job.settings]).replace("{out}", "<job dir>")
    words = [f"experiment={run.experiment}", *run.overrides, f"seed={job.seed}", *job.settings, "logger=disabled"]
    return "rmpfusion-run " + " ".join(shlex.quote(w) for w in words)


def run_study(
    study: Study, out: Path, only: Sequence[str], inputs: Mapping[str, str], extra: Sequence[str], dry_run: bool
) -> int:
    """Run the study's runs (``only`` those, when given) below ``out``; the exit status of the first that failed."""
    missing = sorted(set(study.inputs) - set(inputs))
    if missing:
        wanted = "; ".join(f"{k}: {study.inputs[k]}" for k in missing)
        raise StudyError(f"this study needs --input {' --input '.join(f'{k}=...' for k in missing)} ({wanted})")
    unknown = [r for r in only if r not in study.runs]
    if unknown:
        raise StudyError(f"no run {unknown[0]} in this study; its runs: {', '.join(study.runs)}")
    for name, run in study.runs.items():
        if only and name not in only:
            continue
        for prepare in run.prepare:
            status = _call(_tool_argv(shlex.split(_filled(prepare, out / name, inputs))), dry_run)
            if status:
                return status
        commands = (
            [experiment_command(run, out / name, inputs, extra)]
            if run.experiment is not None
            else [tool_command(run, job, out / job.id, inputs) for job in run.jobs(name)]
        )
        for argv in commands:
            status = _call(argv, dry_run)
            if status:
                return status
    return 0


def _call(argv: list[str], dry_run: bool) -> int:
    print(("would run: " if dry_run else "running: ") + shlex.join(argv), flush=True)
    return 0 if dry_run else subprocess.call(argv)


def job_dirs(study: Study, out: Path) -> dict[str, Path]:
    """{job id: its run directory below ``out``} of every finished job there: a tool job's own directory, an
    experiment job's multirun directory found by the overrides Hydra recorded for it."""
    found: dict[str, Path] = {}
    for name, run in study.runs.items():
        jobs = run.jobs(name)
        if run.command is not None:
            found.update({j.id: out / j.id for j in jobs if (out / j.id / "metrics.json").is_file()})
            continue
        for overrides_file in sorted((out / name).glob("*/.hydra/overrides.yaml")):
            given = set(yaml.safe_load(overrides_file.read_text(encoding="utf-8")) or [])
            for j in jobs:
                if {f"seed={j.seed}", *j.settings} <= given and (overrides_file.parents[1] / "metrics.json").is_file():
                    found[j.id] = overrides_file.parents[1]
    return found
