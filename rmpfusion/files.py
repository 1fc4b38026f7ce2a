"""Files this package writes and reads back: atomic writes (a crash or a kill leaves the old file or the new one,
never half of one), and reading a torch payload of ours so that every way it can fail (missing, truncated,
tampered, foreign) is one error naming the file and the fix, whatever kind of file (dataset, checkpoint) it is."""

from __future__ import annotations

import errno
import io
import json
import os
import re
import shutil
import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any


class DiskFullError(OSError):
    """A write failed for want of space (or quota); the message names the file, the space left and what to do."""

    def __str__(self) -> str:
        return str(self.strerror)  # the message alone, without OSError's "[Errno 28]"


def _size(n: float) -> str:
    for unit in ("B", "KiB", "MiB", "GiB"):
        if n < 1024 or unit == "GiB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024
    return f"{n:.1f} GiB"


def disk_full(path: Path, e: OSError) -> DiskFullError:
    """The error of a write to ``path`` that found no space: which file, how much is left where, and that nothing
    written before is lost (every file is replaced atomically), so a rerun after freeing space resumes."""
    try:
        usage = shutil.disk_usage(path.parent)
        space = f"{_size(usage.free)} free of {_size(usage.total)} on the file system of {path.parent}"
    except OSError:
        space = f"the file system of {path.parent} is full"
    return DiskFullError(
        e.errno,
        f"no space left to write {path} ({space}); the files written before it are intact: "
        "free some space (or point the run elsewhere) and run the same command again: it "
        "resumes from what was written",
    )


def no_space(e: BaseException) -> bool:
    return isinstance(e, OSError) and e.errno in (errno.ENOSPC, errno.EDQUOT)


@contextmanager
def atomic_path(path: str | os.PathLike, suffix: str = "") -> Iterator[Path]:
    """Yield a temporary sibling of ``path`` to write; it replaces ``path`` only if the block succeeds. A full disk
    is a ``DiskFullError`` naming ``path`` (the temporary is removed, the old file kept)."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}{suffix}")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        yield tmp
        with open(tmp, "rb") as fh:  # the data is on disk before the rename makes it visible
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except OSError as e:
        if no_space(e) and not isinstance(e, DiskFullError):
            raise disk_full(path, e) from e
        raise
    finally:
        if tmp.exists():
            tmp.unlink()


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> None:
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)


def atomic_torch_save(obj: Any, path: str | os.PathLike) -> None:
    import torch

    buf = io.BytesIO()
    torch.save(obj, buf)
    atomic_write_bytes(path, buf.getvalue())


def atomic_write_json(path: str | os.PathLike, obj: Any) -> None:
    atomic_write_bytes(path, (json.dumps(obj, indent=2, default=str) + "\n").encode())


_TMP = re.compile(r"^\..+\.tmp(\d+)")  # atomic_path's temporaries: .<name>.tmp<pid>[suffix]


def remove_stale_temporaries(directory: Path, recursive: bool = True) -> list[Path]:
    """Delete the temporaries of atomic writes (``.<name>.tmp<pid>...``) whose writer is no longer running;
    returns them.

    They only exist when a process was killed mid-write; no reader ever picks them up (readers open finished
    names only), this only frees the space. A live writer's temporary (another process on the same directory)
    is left alone, and so is anything under a ``wandb`` directory, which is not ours."""
    removed: list[Path] = []
    if not directory.is_dir():
        return removed
    found = directory.rglob(".*.tmp*") if recursive else directory.glob(".*.tmp*")
    for p in found:
        m = _TMP.match(p.name)
        if not m or not p.is_file() or "wandb" in p.relative_to(directory).parts:
            continue
        pid = int(m.group(1))
        if pid != os.getpid() and not _alive(pid):
            p.unlink(missing_ok=True)
            removed.append(p)
    return removed


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's live process
        return True
    return True


def load_error_cause(e: BaseException) -> str:
    """A one-line cause for a file torch could not load: torch's own messages run to paragraphs (and suggest
    ``weights_only=False``, which is the wrong advice for a damaged or tampered file)."""
    msg = str(e)
    if "WeightsUnpickler error:" in msg:
        msg = msg.split("WeightsUnpickler error:", 1)[1]
    lines = [ln.strip() for ln in msg.strip().splitlines() if ln.strip()]
    first = lines[0] if lines else ("the file ends early" if type(e) is EOFError else "no detail")
    for cut in (" This is an internal", ". Please use", " was not an allowed global"):
        first = first.split(cut, 1)[0]
    if len(first) > 160:
        first = first[:157] + "..."
    return f"{type(e).__name__}: {first}"


def torch_file_format(path: Path) -> str | None:
    """The ``format`` tag of a torch file this package wrote (dataset, checkpoint), None for anything else:
    tells what a file is before deciding which error, if any, to give about it."""
    import torch

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception:  # noqa: BLE001 - not a torch file we can read: no format
        return None
    return payload.get("format") if isinstance(payload, dict) else None


def read_torch_file(
    path: Path, what: str, fix: str, error: type[Exception], fmt: str | None = None, missing: str | None = None
) -> dict:
    """``torch.load`` (weights only) of a file this package wrote, every failure as ``error`` naming the file.

    ``fmt`` is the ``format`` tag the payload must carry; ``missing`` the advice when the file does not exist.
    """
    import torch

    if not path.is_file():
        raise error(f"{what} file {path} does not exist" + (f"; {missing}" if missing else ""))
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # torch's warnings about odd pickles: the error below says it all
            payload = torch.load(path, map_location="cpu", weights_only=True)
        if not isinstance(payload, dict) or (fmt is not None and payload.get("format") != fmt):
            raise ValueError(f"not a {fmt or 'rmpfusion'} file")
    except Exception as e:
        if (name := unsupported_global(e)) is not None:
            raise error(
                f"{what} file {path} is damaged or was not written by rmpfusion: it asks for the Python object "
                f"{name}, which no file of rmpfusion holds (nothing in it was loaded or run); {fix}"
            ) from e
        raise error(f"{what} file {path} is unreadable or truncated ({load_error_cause(e)}); {fix}") from e
    return payload


_GLOBAL = re.compile(r"(?:unsupported GLOBAL|Unsupported global: GLOBAL)\s+([\w.]+)")


def unsupported_global(e: BaseException) -> str | None:
    """The Python object a pickle asked torch's weights-only loader for and was refused (a hostile file's
    ``os.system``, or a damaged byte in a tensor's name), or None for other failures."""
    m = _GLOBAL.search(str(e))
    return m.group(1) if m else None
