"""The run directory of one job: claimed by one process at a time, tied to one configuration, with the
versions that produced it and a copy of everything the job printed.

A rerun in the same directory (``hydra.run.dir=outputs/x``, a requeued SLURM job, a rerun of a sweep with a
fixed ``hydra.sweep.dir``) resumes it: the datasets are reused and training continues from the last
checkpoint. A rerun whose configuration differs from the one saved there is refused before anything is
written, so no run ever overwrites another run's files.
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import errno
import json
import logging
import math
import os
import platform
import re
import shutil
import socket
import sys
from collections.abc import Iterator, Mapping
from importlib import metadata
from pathlib import Path
from typing import Any

from ..files import atomic_write_json
from ..pipeline.config import upgrade_run_config
from ..recordings.source import file_hashes

#: the resolved, validated configuration of the run that owns a directory (written by save_resolved)
RESOLVED = "config.resolved.yaml"
VERSIONS = "versions.json"
CONSOLE = "console.log"
LOCK = ".lock"
#: keys a rerun may change without changing results: where and whether the logger writes
MAY_DIFFER = ("logger",)
#: distributions whose versions decide a run's numbers or its files
DISTRIBUTIONS = (
    "rmpfusion",
    "torch",
    "numpy",
    "hydra-core",
    "omegaconf",
    "pydantic",
    "wandb",
    "pybullet",
    "matplotlib",
    "submitit",
    "hydra-submitit-launcher",
    "hydra-joblib-launcher",
    "joblib",
)


class RunDirError(RuntimeError):
    """The run directory cannot be used by this job (it belongs to another configuration, or is busy)."""


# ----------------------------------------------------------------------------------- configuration guard
def config_diff(old: Any, new: Any, path: str = "") -> list[tuple[str, Any, Any]]:
    """``(dotted path, old, new)`` for every leaf that differs between two plain containers."""
    if isinstance(old, Mapping) and isinstance(new, Mapping):
        out: list[tuple[str, Any, Any]] = []
        for k in sorted(set(old) | set(new), key=str):
            sub = f"{path}.{k}" if path else str(k)
            if k not in old:
                out.append((sub, "<absent>", new[k]))
            elif k not in new:
                out.append((sub, old[k], "<absent>"))
            else:
                out += config_diff(old[k], new[k], sub)
        return out
    same = old == new or (isinstance(old, float) and isinstance(new, float) and math.isnan(old) and math.isnan(new))
    return [] if same else [(path, old, new)]


def check_same_config(resolved: Mapping[str, Any], run_dir: Path) -> None:
    """Refuse ``run_dir`` if it holds a run made with another configuration (``logger`` may differ)."""
    import yaml

    saved = run_dir / RESOLVED
    if not saved.is_file():
        return
    fix = (
        f"Rerun with the configuration saved in {saved} to resume that run, or give this run its own "
        f"directory (a new hydra.run.dir=..., or no hydra.run.dir for a fresh timestamped one)."
    )
    try:
        old = yaml.safe_load(saved.read_text())
        if not isinstance(old, Mapping):
            raise TypeError("not a mapping")
    except Exception as e:
        raise RunDirError(
            f"{run_dir} holds a run whose saved configuration {saved} is unreadable "
            f"({type(e).__name__}: {e}); nothing was changed. {fix}"
        ) from e

    old = upgrade_run_config(old)  # a run saved before a key was renamed (train.lr_final) still resumes
    strip = lambda c: {k: v for k, v in c.items() if k not in MAY_DIFFER}
    diffs = config_diff(strip(old), strip(dict(resolved)))
    if diffs:
        shown = "\n".join(f"  - {p}: {o!r} (saved) vs {n!r} (now)" for p, o, n in diffs[:12])
        more = f"\n  - ... and {len(diffs) - 12} more" if len(diffs) > 12 else ""
        raise RunDirError(
            f"{run_dir} already holds a run with a different configuration (saved in {saved}):\n"
            f"{shown}{more}\nNothing was changed. {fix}"
        )


RECORDINGS = "recordings.json"


def recorded_file_hashes(run: Any) -> dict[str, str] | None:
    """sha256 of every recorded file a run learns from (None for a run on an expert's demonstrations)."""
    if run.data.source != "recorded":
        return None
    return file_hashes(run.data)


def check_same_recordings(hashes: dict[str, str] | None, run_dir: Path) -> None:
    """Refuse ``run_dir`` if a recorded file changed since the run there read it: the configuration is the same,
    but resuming would evaluate the model trained on the old recording against the new one."""
    saved = run_dir / RECORDINGS
    if hashes is None or not saved.is_file():
        return
    old = json.loads(saved.read_text())
    changed = [name for name in hashes if name in old and old[name] != hashes[name]]
    if changed:
        raise RunDirError(
            f"{run_dir} holds a run that learned from another version of {', '.join(changed)} (sha256 "
            f"{old[changed[0]][:12]}... then, {hashes[changed[0]][:12]}... now; {saved}). Nothing was changed. "
            "Give this run its own directory (a new hydra.run.dir=..., or none for a fresh timestamped one), or put "
            "the recording back to resume that run."
        )


def save_recordings(hashes: dict[str, str] | None, run_dir: Path) -> None:
    if hashes is not None:
        atomic_write_json(run_dir / RECORDINGS, hashes)


class HydraFiles:
    """Hydra writes ``.hydra/*.yaml`` into the job directory before the job starts, so a refused rerun would
    replace the owner's copies. The accepted copies are kept in ``.hydra/accepted/`` and put back on refusal."""

    def __init__(self, run_dir: Path):
        from hydra.core.hydra_config import HydraConfig

        sub = HydraConfig.get().output_subdir if HydraConfig.initialized() else None
        self.dir = run_dir / sub if sub else None

    def _files(self) -> list[Path]:
        return sorted(self.dir.glob("*.yaml")) if self.dir is not None and self.dir.is_dir() else []

    def accept(self) -> None:
        if self.dir is None:
            return
        keep = self.dir / "accepted"
        keep.mkdir(parents=True, exist_ok=True)
        for f in self._files():
            shutil.copy2(f, keep / f.name)

    def restore(self) -> bool:
        if self.dir is None:
            return False
        keep = self.dir / "accepted"
        if not keep.is_dir():
            return False
        for f in self._files():
            if not (keep / f.name).exists():
                f.unlink()
        for f in keep.glob("*.yaml"):
            shutil.copy2(f, self.dir / f.name)
        return True


# ------------------------------------------------------------------------------------------------ lock
@contextlib.contextmanager
def exclusive(run_dir: Path) -> Iterator[None]:
    """Hold ``run_dir/.lock`` for the job: a second process in the same directory is refused at once.

    The lock is the kernel's (flock), so it is released however the holder ends, SIGKILL included.
    On filesystems without locking the job runs unlocked."""
    try:
        import fcntl
    except ImportError:  # pragma: no cover - Windows
        yield
        return
    run_dir.mkdir(parents=True, exist_ok=True)
    path = run_dir / LOCK
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as e:
            if e.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                holder = os.pread(fd, 200, 0).decode(errors="replace").strip() or "another process"
                raise RunDirError(
                    f"{run_dir} is in use by {holder} ({path}); wait for it to finish, or give this "
                    "run its own directory (hydra.run.dir=...)"
                ) from None
            yield  # locking unsupported here (some network filesystems): run without it
            return
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"pid {os.getpid()} on {socket.gethostname()}\n".encode(), 0)
        yield
    finally:
        os.close(fd)  # releases the lock


# ----------------------------------------------------------------------------------------- versions
def git_commit(start: Path | None = None) -> dict[str, Any] | None:
    """The commit of the source checkout rmpfusion is imported from, read from ``.git`` (no git process)."""
    here = (start or Path(__file__)).resolve()
    for root in here.parents:
        dot = root / ".git"
        if dot.is_file():  # a worktree: "gitdir: <path>"
            m = re.match(r"gitdir:\s*(.+)", dot.read_text().strip())
            dot = (root / m.group(1)).resolve() if m else dot
        if not dot.is_dir():
            continue
        try:
            head = (dot / "HEAD").read_text().strip()
            common = dot
            if (dot / "commondir").is_file():
                common = (dot / (dot / "commondir").read_text().strip()).resolve()
            if not head.startswith("ref:"):
                return {"commit": head, "branch": None, "repo": str(root)}
            ref = head.split(":", 1)[1].strip()
            for base in (dot, common):
                if (base / ref).is_file():
                    return {
                        "commit": (base / ref).read_text().strip(),
                        "branch": ref.rsplit("/", 1)[-1],
                        "repo": str(root),
                    }
            packed = common / "packed-refs"
            if packed.is_file():
                for line in packed.read_text().splitlines():
                    parts = line.split()
                    if len(parts) == 2 and parts[1] == ref:
                        return {"commit": parts[0], "branch": ref.rsplit("/", 1)[-1], "repo": str(root)}
            return {"commit": None, "branch": ref.rsplit("/", 1)[-1], "repo": str(root)}  # no commits yet
        except OSError:
            return None
    return None


def environment(threads: int | None = None) -> dict[str, Any]:
    """What produced a run: interpreter, package versions, source commit, machine and threads."""
    import torch

    packages: dict[str, str | None] = {}
    for name in DISTRIBUTIONS:
        try:
            packages[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            packages[name] = None
    env_keys = (
        "OMP_NUM_THREADS",
        "MKL_NUM_THREADS",
        "CUDA_VISIBLE_DEVICES",
        "SLURM_JOB_ID",
        "SLURM_ARRAY_JOB_ID",
        "SLURM_ARRAY_TASK_ID",
        "SUBMITIT_EXECUTOR",
    )
    return {
        "python": platform.python_version(),
        "implementation": platform.python_implementation(),
        "executable": sys.executable,
        "packages": packages,
        "torch_build": {"cuda": torch.version.cuda, "debug": torch.version.debug},
        "git": git_commit(),
        "platform": platform.platform(),
        "machine": platform.machine(),
        "hostname": socket.gethostname(),
        "cpu_count": os.cpu_count(),
        "torch_threads": threads if threads is not None else torch.get_num_threads(),
        "environment": {k: os.environ[k] for k in env_keys if k in os.environ},
        "argv": list(sys.argv),
        "started": _dt.datetime.now().astimezone().isoformat(timespec="seconds"),
    }


def record_environment(run_dir: Path, threads: int | None = None) -> dict[str, Any]:
    """Write ``versions.json``; a resumed run keeps the earlier invocations' records under ``history`` and
    warns when the packages changed in between (the numbers may then differ from an uninterrupted run)."""
    rec = environment(threads)
    path = run_dir / VERSIONS
    history: list = []
    if path.is_file():
        try:
            old = json.loads(path.read_text())
            history = list(old.pop("history", [])) + [old]
            changed = {
                k: (old.get("packages", {}).get(k), v)
                for k, v in rec["packages"].items()
                if old.get("packages", {}).get(k) != v
            }
            if changed:
                print(
                    "warning: this run was started with other package versions ("
                    + ", ".join(f"{k} {a} -> {b}" for k, (a, b) in changed.items())
                    + f"); see {path}",
                    file=sys.stderr,
                )
        except (OSError, ValueError):
            history = []
    atomic_write_json(path, {**rec, "history": history} if history else rec)
    return rec


# --------------------------------------------------------------------------------------------- console
class JobLog:
    """The job's lines in Hydra's log file (``run.log`` for ``rmpfusion-run``; Hydra's job logging writes
    ``<run dir>/<job name>.log``): every line the job prints, as a record of the logger ``rmpfusion`` (stdout
    INFO, stderr WARNING), beside whatever libraries log through Python's ``logging``.

    The job's messages are printed, not logged (progress bars redraw a terminal line), so without this the file
    stays empty. Records go straight to the file handlers Hydra attached to the root logger for this run
    directory, not through a logger, so the console does not show each line twice; with Hydra's job logging
    disabled (``hydra/job_logging=disabled``) there is no such handler and nothing is written."""

    NAME = "rmpfusion"

    def __init__(self, run_dir: Path):
        self.handlers = job_log_handlers(run_dir)
        self._busy = False

    def record(self, level: int, msg: str, exc_info=None) -> None:
        if self._busy or not self.handlers:
            return
        self._busy = True  # a handler that fails reports on stderr, which comes back here: not again
        raising, logging.raiseExceptions = logging.raiseExceptions, False  # a full disk: the copy stops, no block
        try:
            rec = logging.LogRecord(self.NAME, level, __file__, 0, msg, None, exc_info)
            for h in self.handlers:
                if rec.levelno >= h.level:
                    h.handle(rec)
        finally:
            self._busy = False
            logging.raiseExceptions = raising

    def sink(self, level: int):
        return lambda line: self.record(level, line) if line.strip() else None


def job_log_handlers(run_dir: Path) -> list[logging.Handler]:
    """The file handlers of the root logger that write into ``run_dir`` (Hydra's job logging)."""
    out: list[logging.Handler] = []
    here = Path(run_dir).resolve()
    for h in logging.getLogger().handlers:
        if isinstance(h, logging.FileHandler) and Path(h.baseFilename).resolve().parent == here:
            out.append(h)
    return out


class _Tee:
    """A text stream that also appends what it is given to a log file, one clean line per line: terminal
    redraws (``\\r`` and erase-line codes of progress bars) keep only their final state in the file. Each
    finished line is also given to ``sink`` (the job's log)."""

    _ANSI = re.compile(r"\x1b\[[0-9;]*[A-Za-z]")

    def __init__(self, stream, fh, sink=None):
        self._stream, self._fh, self._partial, self._sink = stream, fh, "", sink

    def _line(self, line: str) -> None:
        self._fh.write(line + "\n")
        if self._sink is not None:
            self._sink(line)

    def write(self, s: str) -> int:
        n = self._stream.write(s)
        text = self._partial + s
        *lines, self._partial = text.split("\n")
        for line in lines:
            self._line(self._ANSI.sub("", line.rsplit("\r", 1)[-1]))
        self._partial = self._partial.rsplit("\r", 1)[-1]
        if lines:
            self._fh.flush()
        return n

    def flush(self) -> None:
        self._stream.flush()
        self._fh.flush()

    def close_file(self) -> None:
        if self._partial:
            self._line(self._ANSI.sub("", self._partial))
            self._partial = ""
        self._fh.flush()

    def isatty(self) -> bool:
        return bool(getattr(self._stream, "isatty", lambda: False)())

    def __getattr__(self, name):
        return getattr(self._stream, name)


class _Quiet:
    """A file whose writes and close never raise for a full disk (the console copy is a copy: the job goes on)."""

    def __init__(self, fh):
        self._fh = fh

    def write(self, s: str) -> None:
        with contextlib.suppress(OSError):
            self._fh.write(s)

    def flush(self) -> None:
        with contextlib.suppress(OSError):
            self._fh.flush()

    def close(self) -> None:
        with contextlib.suppress(OSError):
            self._fh.close()


@contextlib.contextmanager
def console_log(run_dir: Path) -> Iterator[None]:
    """Copy everything the job prints (stdout and stderr, progress included) into ``run_dir/console.log``, and
    the same lines, time-stamped, into Hydra's log file there (``JobLog``), which also says how the job ended."""
    run_dir.mkdir(parents=True, exist_ok=True)
    log = JobLog(run_dir)
    with contextlib.closing(_Quiet(open(run_dir / CONSOLE, "a", encoding="utf-8", errors="replace"))) as fh:
        fh.write(
            f"==== {_dt.datetime.now().astimezone().isoformat(timespec='seconds')} pid {os.getpid()}: "
            f"{' '.join(sys.argv)}\n"
        )
        log.record(logging.INFO, f"job started in {run_dir} (pid {os.getpid()}): {' '.join(sys.argv)}")
        old_out, old_err = sys.stdout, sys.stderr
        out, err = _Tee(old_out, fh, log.sink(logging.INFO)), _Tee(old_err, fh, log.sink(logging.WARNING))
        sys.stdout, sys.stderr = out, err
        ending: tuple = (logging.INFO, "job finished", None)
        try:
            yield
        except SystemExit as e:
            if e.code not in (None, 0):
                ending = (logging.ERROR, f"job stopped with exit status {e.code}", None)
            raise
        except BaseException as e:
            ending = (logging.ERROR, f"job stopped by {type(e).__name__}: {e}", sys.exc_info())
            raise
        finally:
            sys.stdout, sys.stderr = old_out, old_err
            out.close_file()
            err.close_file()
            log.record(*ending)
