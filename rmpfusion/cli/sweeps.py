"""A sweep (``-m``) whose jobs fail alone.

Each job validates its own config when it starts (a sweeper such as Optuna makes jobs as it goes, so checking
every job before the first one runs cannot be the only check). A job that fails says so with its number and
overrides and returns, so the launcher goes on with the others; the sweep then ends by listing the failed jobs and
exits with status 1. Jobs leave their failures in a directory the sweep's process names in
``RMPFUSION_SWEEP_FAILURES`` (the launchers that run jobs in other processes on this machine, joblib's, inherit it).
"""

from __future__ import annotations

import contextlib
import json
import os
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path

from ..files import atomic_write_json

#: The environment variable naming the directory where a sweep's failed jobs leave their records.
FAILURES = "RMPFUSION_SWEEP_FAILURES"


def in_sweep() -> bool:
    """Whether the running Hydra job is one job of a sweep."""
    from hydra.core.hydra_config import HydraConfig
    from hydra.types import RunMode

    return HydraConfig.initialized() and HydraConfig.get().mode == RunMode.MULTIRUN


def _job() -> tuple[int, list[str]]:
    from hydra.core.hydra_config import HydraConfig

    hc = HydraConfig.get()
    return int(hc.job.num), [str(o) for o in hc.overrides.task]


def describe(num: int, overrides: list[str]) -> str:
    return f"job {num} ({' '.join(overrides) or 'no overrides'})"


def record_failure(code: int | str | None) -> None:
    """Say that this job failed (its message was printed just before) and leave its record for the sweep's end."""
    num, overrides = _job()
    print(
        f"{describe(num, overrides)} failed with exit status {code}; the sweep goes on with its other jobs",
        file=sys.stderr,
    )
    folder = os.environ.get(FAILURES)
    if folder:
        atomic_write_json(Path(folder) / f"job-{num}.json", {"num": num, "overrides": overrides, "code": code})


def _failures(folder: Path) -> list[dict]:
    return sorted((json.loads(p.read_text()) for p in folder.glob("job-*.json")), key=lambda f: f["num"])


@contextlib.contextmanager
def failures_reported() -> Iterator[None]:
    """Around a command: when jobs of its sweep failed, list them at the end and exit with status 1."""
    old = os.environ.get(FAILURES)
    with tempfile.TemporaryDirectory(prefix="rmpfusion-sweep-") as folder:
        os.environ[FAILURES] = folder
        try:
            yield
            failed = _failures(Path(folder))
        finally:
            if old is None:
                os.environ.pop(FAILURES, None)
            else:
                os.environ[FAILURES] = old
    if failed:
        listed = "; ".join(f"{describe(f['num'], f['overrides'])}: exit status {f['code']}" for f in failed)
        print(
            f"error: {len(failed)} job{'s' if len(failed) > 1 else ''} of the sweep failed ({listed}); each said why "
            "above. The others ran; fix the failed jobs' overrides and run them again",
            file=sys.stderr,
        )
        sys.exit(1)
