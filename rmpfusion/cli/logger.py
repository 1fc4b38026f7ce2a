"""wandb as the logger: exactly one wandb run per job, written into the job's run directory.

``logger.mode`` is ``offline`` by default (nothing touches the network; ``wandb sync <run_dir>/wandb/offline-run-*``
uploads later), ``online`` streams (and falls back to offline with a warning when wandb.ai cannot be reached or
you are not logged in), ``disabled`` logs nothing. Without wandb installed the run still writes everything locally.

A rerun of the same directory continues the same wandb run id (kept in ``wandb/run_id``), so a resumed job is
still one run on wandb.ai.
"""

from __future__ import annotations

import math
import secrets
import sys
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from ..files import atomic_write_bytes


class JobLogger:
    """What a job logs: training curves as they come (``log``), then figures and final metrics (``finish``)."""

    def __init__(self, run=None):
        self.run = run

    @property
    def enabled(self) -> bool:
        return self.run is not None

    @property
    def log(self) -> Callable[[dict[str, float]], Any] | None:
        return self.run.log if self.run is not None else None

    def finish(self, metrics: Mapping[str, Any]) -> None:
        """Every PNG listed in ``metrics["figures"]`` as a ``wandb.Image``; every scalar as the run's summary."""
        if self.run is None:
            return
        import wandb

        images = {
            f"figures/{Path(p).stem}": wandb.Image(str(p))
            for p in metrics.get("figures") or []
            if str(p).endswith(".png") and Path(p).is_file()
        }
        if images:
            self.run.log(images)
        self.run.summary.update(flat_scalars({k: v for k, v in metrics.items() if k != "figures"}))


def flat_scalars(tree: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """``{"a": {"b": 1.0}} -> {"a/b": 1.0}``: numbers, booleans and strings; lists and non-finite numbers dropped."""
    out: dict[str, Any] = {}
    for k, v in tree.items():
        key = f"{prefix}{k}"
        if isinstance(v, Mapping):
            out.update(flat_scalars(v, key + "/"))
        elif isinstance(v, (bool, str)) or isinstance(v, (int, float)) and math.isfinite(v):
            out[key] = v
    return out


def _run_id(run_dir: Path) -> str:
    path = run_dir / "wandb" / "run_id"
    if path.is_file() and (rid := path.read_text().strip()):
        return rid

    rid = secrets.token_hex(4)
    atomic_write_bytes(path, (rid + "\n").encode())
    return rid


def _finish_previous(wandb) -> Any:
    """``reinit``: a job in a reused worker process (joblib) finishes the previous job's run first."""
    try:
        new = tuple(int(x) for x in wandb.__version__.split(".")[:2]) >= (0, 20)
    except ValueError:
        new = True
    return "finish_previous" if new else True


def start(run, run_dir: Path, environment: Mapping[str, Any] | None = None) -> JobLogger:
    """``wandb.init`` for this job (config = the resolved run config + ``versions``), or a no-op logger."""
    lg = run.logger
    if lg.mode == "disabled":
        return JobLogger(None)
    try:
        import wandb
    except ImportError:
        print(
            "warning: logger.mode is not disabled but wandb is not installed; logging locally only "
            "(pip install wandb, or logger=disabled to silence this)",
            file=sys.stderr,
        )
        return JobLogger(None)
    config = {**run.model_dump(mode="json"), "versions": dict(environment or {})}
    # the source commit is in config.versions.git (read from .git); wandb's own git probing is off so no job
    # ever runs git (clusters without it, and no index lock taken in a checkout someone is working in)
    kwargs = {
        "project": lg.project,
        "entity": lg.entity,
        "tags": list(lg.tags),
        "group": lg.group or run.name,
        "name": f"{run.name}-seed{run.seed}",
        "dir": str(run_dir),
        "config": config,
        "id": _run_id(run_dir),
        "resume": "allow",
        "reinit": _finish_previous(wandb),
        "settings": wandb.Settings(disable_git=True),
    }
    try:
        return JobLogger(wandb.init(mode=lg.mode, **kwargs))
    except Exception as e:  # noqa: BLE001 - wandb raises many types for login / network problems
        if lg.mode != "online":
            print(f"warning: wandb could not start ({type(e).__name__}: {e}); logging locally only", file=sys.stderr)
            return JobLogger(None)
        print(
            f"warning: wandb online failed ({type(e).__name__}: {e}); logging offline instead, upload later with "
            f"`wandb sync {run_dir / 'wandb'}/offline-run-*`",
            file=sys.stderr,
        )
        try:
            return JobLogger(wandb.init(mode="offline", **kwargs))
        except Exception as e2:  # noqa: BLE001
            print(f"warning: wandb could not start ({type(e2).__name__}: {e2}); logging locally only", file=sys.stderr)
            return JobLogger(None)
