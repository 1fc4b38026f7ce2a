"""What every entry point shares: the Hydra app over conf/ (found by ``pipeline/compose.py::conf_dir``), the run
directory, and turning config errors into exit codes."""

from __future__ import annotations

import contextlib
import functools
import os
import sys
import traceback
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import hydra

from ..assembly.errors import ConfigError
from ..core.diagnosis import NumericalError
from ..envs.common import SamplingError
from ..envs.demonstrations import DatasetError
from ..files import DiskFullError, atomic_write_bytes, remove_stale_temporaries
from ..learn.checkpoints import CheckpointError
from ..learn.loop import TrainingDivergedError
from ..pipeline.collect import ExpertDivergedError
from ..pipeline.compose import conf_dir
from ..pipeline.fit import NotTrainedError
from ..pipeline.validate import resolve_and_validate
from ..recordings.recording import RecordingError
from ..registry import PluginError, RegistryError
from . import logger as wandb_logger
from . import sweeps
from .preflight import CommandLineError, check_command_line, check_output_dir
from .rundir import (
    RESOLVED,
    HydraFiles,
    RunDirError,
    check_same_config,
    check_same_recordings,
    console_log,
    exclusive,
    record_environment,
    recorded_file_hashes,
    save_recordings,
)

#: Exit code of a command whose configuration is invalid (nothing was run).
CONFIG_ERROR_EXIT = 2


#: Exit code of a run stopped by Ctrl-C (128 + SIGINT, what a shell reports for it).
INTERRUPTED_EXIT = 130


def debug_enabled() -> bool:
    """``RMPFUSION_DEBUG=1``: full tracebacks instead of the one- or two-line answers, for someone debugging
    rmpfusion or a plugin (it also sets Hydra's ``HYDRA_FULL_ERROR=1`` for Hydra's own errors)."""
    return os.environ.get("RMPFUSION_DEBUG", "") not in ("", "0")


def fail(message: str, code: int = CONFIG_ERROR_EXIT) -> None:
    """Say what went wrong in the user's terms and exit; under ``RMPFUSION_DEBUG=1`` the caller's exception
    propagates instead (see ``debug_enabled``)."""
    if debug_enabled():
        raise  # noqa: PLE0704 - fail is only called while an exception is handled: that one propagates
    print(f"error: {message}", file=sys.stderr)
    sys.exit(code)


def one_line(e: BaseException) -> str:
    """An error as one line: a pydantic validation error's entries joined (``field: message``), any other error's
    text with its line breaks folded."""
    from pydantic import ValidationError

    if isinstance(e, ValidationError):
        return "; ".join(
            (f"{'.'.join(map(str, err['loc']))}: " if err["loc"] else "") + err["msg"].removeprefix("Value error, ")
            for err in e.errors()
        )
    if isinstance(e, KeyError) and e.args:
        return " ".join(str(e.args[0]).split())
    return " ".join(str(e).split())


def hydra_app(task: Callable[[Any], Any]) -> Callable[[], Any]:
    """A console script running ``task(cfg)`` as a Hydra app over conf/. The directory is looked up when the
    command runs, never on import; the command line is composed once first (``preflight``) so a misspelt group,
    a missing file, a YAML error or an unwritable output directory is said in a line or two (exit 2).

    Inside the job every error of ``USER_ERRORS`` is one line (``user_errors_exit``), never Hydra's "Error executing
    job" and its traceback. A job that stops before it owns its directory leaves none behind (``discard_unclaimed``).
    In a sweep (``-m``) a failing job fails alone: it says its number and overrides, the other jobs run, and the
    sweep ends by listing the failed jobs with a non-zero exit status (``sweeps.py``)."""

    @functools.wraps(task)
    def job_task(cfg: Any) -> Any:
        try:
            with user_errors_exit():
                return task(cfg)
        except SystemExit as e:
            if e.code in (None, 0):
                raise
            discard_unclaimed(hydra_run_dir())
            if not sweeps.in_sweep() or e.code == INTERRUPTED_EXIT:  # Ctrl-C stops the whole sweep
                raise
            sweeps.record_failure(e.code)
            return float("nan")  # a sweeper that minimises (Optuna) records the trial as failed and goes on

    @functools.wraps(task)
    def entry() -> Any:
        try:
            path = conf_dir()
            check_command_line(path, sys.argv[1:])
            check_output_dir(sys.argv[1:])
        except (FileNotFoundError, CommandLineError) as e:
            fail(str(e))
        if debug_enabled():
            os.environ["HYDRA_FULL_ERROR"] = "1"
        with sweeps.failures_reported():
            return hydra.main(version_base="1.3", config_path=path, config_name="config")(job_task)()

    return entry


def plugin_report(e: PluginError) -> str:
    """The plugin's own error and its own frames (where the plugin author must look), not rmpfusion's."""
    cause = e.__cause__
    assert cause is not None  # the registry raises PluginError from the plugin's own error
    ours = (str(Path(__file__).resolve().parents[1]), "<frozen importlib", os.sep + "importlib" + os.sep)
    frames = [f for f in traceback.extract_tb(cause.__traceback__) if not any(o in f.filename for o in ours)]
    shown = "\n".join(
        f'  File "{f.filename}", line {f.lineno}, in {f.name}' + (f"\n    {f.line}" if f.line else "") for f in frames
    )
    return f"{e}" + (f"\n{shown}" if shown else "") + "\n(RMPFUSION_DEBUG=1 shows the whole traceback)"


#: Errors whose message is already complete (what failed, the file, key or node, and what to do), with the exit
#: status each ends a command with: 2 when nothing ran (a config, a file given on the command line), 1 when a run
#: stopped. Anything else is a bug in rmpfusion or a plugin and keeps its traceback.
USER_ERRORS: tuple[tuple[type[BaseException], int], ...] = (
    (ConfigError, CONFIG_ERROR_EXIT),
    (RegistryError, CONFIG_ERROR_EXIT),
    (RunDirError, CONFIG_ERROR_EXIT),
    (CheckpointError, CONFIG_ERROR_EXIT),
    (DatasetError, CONFIG_ERROR_EXIT),
    (SamplingError, CONFIG_ERROR_EXIT),
    (RecordingError, CONFIG_ERROR_EXIT),
    (ExpertDivergedError, 1),
    (NotTrainedError, 1),
    (DiskFullError, 1),
    (TrainingDivergedError, 1),
    (NumericalError, 1),
)


def user_error_code(e: BaseException) -> int | None:
    """The exit status of a user error (see ``USER_ERRORS``); None for anything else."""
    return next((code for kind, code in USER_ERRORS if isinstance(e, kind)), None)


@contextlib.contextmanager
def user_errors_exit() -> Iterator[None]:
    """Print the problems a user can fix as they should read them (paths and fixes), no traceback: the one place
    every command turns an error into its message and exit status (``RMPFUSION_DEBUG=1`` re-raises)."""

    try:
        yield
    except PluginError as e:
        fail(plugin_report(e))
    except Exception as e:
        code = user_error_code(e)
        if code is None:
            raise
        fail(str(e), code)


def discard_unclaimed(run_dir: Path) -> None:
    """Remove what Hydra made for a job that stopped before it owned ``run_dir`` (an invalid config, a busy or
    foreign directory): its ``.hydra/`` copies and log, and the directory (and its parent, ``outputs/<name>``) if
    that leaves it empty. Only those files are touched, so a directory holding anything else (a run's, a user's)
    is kept as it was."""
    if (run_dir / RESOLVED).exists() or (run_dir / ".hydra" / "accepted").exists():
        return
    from hydra.core.hydra_config import HydraConfig

    for name in ("config.yaml", "hydra.yaml", "overrides.yaml"):
        (run_dir / ".hydra" / name).unlink(missing_ok=True)
    if HydraConfig.initialized():  # Hydra's job log, <job name>.log
        (run_dir / f"{HydraConfig.get().job.name}.log").unlink(missing_ok=True)
    for d in (run_dir / ".hydra", run_dir, *([run_dir.parent] if run_dir.parent.name != "outputs" else [])):
        with contextlib.suppress(OSError):
            d.rmdir()  # only ever an empty directory


def hydra_run_dir() -> Path:
    from hydra.core.hydra_config import HydraConfig

    return Path(HydraConfig.get().runtime.output_dir)


def save_resolved(run, run_dir: Path) -> Path:
    """The resolved, validated config beside Hydra's unresolved copy: what actually ran (and what a rerun in
    the same directory must match, see rundir.check_same_config)."""
    import yaml

    path = run_dir / RESOLVED
    atomic_write_bytes(path, yaml.safe_dump(run.model_dump(mode="json"), sort_keys=False).encode())
    return path


@dataclass
class Job:
    """One Hydra job: its validated config, run directory, logger and the environment that ran it."""

    run: Any
    dir: Path
    logger: Any
    environment: dict


@contextlib.contextmanager
def job(cfg, threads: int = 1, log: bool = True) -> Iterator[Job]:
    """Everything a job does before and after its work, in this order:

    validate the config (exit 2 listing every problem); claim the run directory (exit 2 if another process
    holds it, or if it holds a run of a different configuration, with Hydra's ``.hydra/`` files put back);
    save the resolved config, ``versions.json`` and a copy of the console (``console.log``); remove
    temporaries left by a killed process; start the one wandb run of this job (``log``); limit torch to
    ``threads`` intra-op threads; then yield, and finish the wandb run with the job's exit status.
    """
    import torch

    run_dir = hydra_run_dir()
    hydra_files = HydraFiles(run_dir)
    with contextlib.ExitStack() as stack:
        try:
            with user_errors_exit():
                run = resolve_and_validate(cfg)
            stack.enter_context(exclusive(run_dir))
            check_same_config(run.model_dump(mode="json"), run_dir)
            recordings = recorded_file_hashes(run)
            check_same_recordings(recordings, run_dir)
        except RunDirError as e:
            hydra_files.restore()
            print(f"error: {e}", file=sys.stderr)
            sys.exit(CONFIG_ERROR_EXIT)
        except SystemExit:
            hydra_files.restore()
            raise
        hydra_files.accept()
        save_resolved(run, run_dir)
        save_recordings(recordings, run_dir)
        stack.enter_context(console_log(run_dir))
        environment = record_environment(run_dir, threads)
        for p in remove_stale_temporaries(run_dir):
            print(f"removed {p}: a temporary left by a process killed while writing (never read)")
        old_threads = torch.get_num_threads()
        torch.set_num_threads(threads)
        stack.callback(torch.set_num_threads, old_threads)
        lg = wandb_logger.start(run, run_dir, environment) if log else wandb_logger.JobLogger(None)
        code = 1
        try:
            yield Job(run=run, dir=run_dir, logger=lg, environment=environment)
            code = 0
        except KeyboardInterrupt:
            code = INTERRUPTED_EXIT
            if debug_enabled():
                raise
            print(
                f"interrupted (Ctrl-C): what was finished is kept in {run_dir} (datasets, the last checkpoint); "
                f"rerun the same command with hydra.run.dir={run_dir} to resume",
                file=sys.stderr,
            )
            sys.exit(INTERRUPTED_EXIT)
        except SystemExit as e:
            code = 0 if e.code is None else e.code if isinstance(e.code, int) else 1
            raise
        finally:
            if lg.run is not None:
                lg.run.finish(exit_code=code)
