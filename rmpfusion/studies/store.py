"""Where a study's results live in the repository and how a job's metrics are kept there.

``results/<study>/<job>/metrics.json`` is the metrics.json the job wrote, unchanged; ``results/<study>/runs.yaml``
says, per job, the command that made it, the commit, the date, the machine, the seed and the wall time.
"""

from __future__ import annotations

import subprocess
from datetime import date
from pathlib import Path

import yaml

from ..files import atomic_write_bytes
from .compare import read_metrics
from .spec import StudyError

RESULTS = "results"
PROVENANCE = "runs.yaml"
#: what every job's provenance records
PROVENANCE_KEYS = ("command", "commit", "date", "machine", "seed", "wall_time_s")


def results_dir(root: Path, study: str) -> Path:
    return root / RESULTS / study


def stored_metrics(root: Path, study: str, job: str) -> dict:
    """A stored job's metrics; a ValueError naming the file when it is missing or damaged."""
    return read_metrics(results_dir(root, study) / job / "metrics.json")


def provenance(root: Path, study: str) -> dict[str, dict]:
    """{job: how it was made} of a study's stored jobs (empty when none is stored)."""
    path = results_dir(root, study) / PROVENANCE
    if not path.is_file():
        return {}
    return yaml.safe_load(path.read_text(encoding="utf-8")) or {}


def provenance_header(study: str) -> str:
    """The comment that opens a study's runs.yaml (YAML drops comments on reading, so each write puts it back)."""
    return (
        f"# Every stored job of the study conf/study/{study}.yaml: the command as it ran, the commit, the date, the "
        "machine,\n# the seed and the run's own timing.total_s.\n"
    )


def head_commit(root: Path) -> str:
    out = subprocess.run(["git", "rev-parse", "HEAD"], cwd=root, capture_output=True, text=True, check=False)
    return out.stdout.strip() if out.returncode == 0 else "unknown"


def store_job(root: Path, study: str, job: str, run_dir: Path, command: str, machine: str) -> Path:
    """Copy a finished job's metrics.json into results/ and record how it was made; an existing stored job is
    replaced only where the caller asked to store it."""
    metrics = read_metrics(run_dir / "metrics.json")
    target = results_dir(root, study) / job / "metrics.json"
    target.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(target, (run_dir / "metrics.json").read_bytes())
    record = provenance(root, study)
    record[job] = {
        "command": command,
        "commit": head_commit(root),
        "date": date.today().isoformat(),
        "machine": machine,
        "seed": metrics.get("seed"),
        "wall_time_s": round(float(metrics.get("timing", {}).get("total_s", float("nan"))), 1),
    }
    text = provenance_header(study) + yaml.safe_dump(
        dict(sorted(record.items())), sort_keys=False, allow_unicode=True, width=120
    )
    atomic_write_bytes(results_dir(root, study) / PROVENANCE, text.encode("utf-8"))
    return target


def require_stored(root: Path, study: str, jobs: list[str]) -> None:
    missing = [j for j in jobs if not (results_dir(root, study) / j / "metrics.json").is_file()]
    if missing:
        raise StudyError(
            f"study {study}: {len(missing)} job(s) not stored under {results_dir(root, study)} "
            f"({', '.join(missing[:4])}{' ...' if len(missing) > 4 else ''}); run them with "
            f"rmpfusion-study run {study} --store"
        )
