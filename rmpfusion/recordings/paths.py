"""Where a data block's files are: ``data.files`` entries as paths (a recording rmpfusion ships, a file, a ROS 2
bag directory) and wildcards expanded, in the order the files were recorded."""

from __future__ import annotations

import glob
import re
from pathlib import Path

from .recording import RecordingError
from .rosbag import ROS2_METADATA, is_ros2_bag

#: a ``data.files`` entry starting with this names a recording shipped with rmpfusion (rmpfusion/recordings/files/)
SHIPPED = "rmpfusion:"
SHIPPED_DIR = Path(__file__).resolve().parent / "files"


def source_file(f: str, file_format: str = "csv") -> Path:
    """One ``data.files`` entry as a path: ``rmpfusion:NAME`` is a recording shipped with the package, anything else
    a path relative to the directory the command runs in (or absolute); a ROS 2 bag is a directory."""
    if f.startswith(SHIPPED):
        path = SHIPPED_DIR / f[len(SHIPPED) :]
        if not path.is_file():
            shipped = sorted(p.name for p in SHIPPED_DIR.glob("*") if p.is_file())
            raise RecordingError(
                f"{f}: rmpfusion ships no such recording (data.files); it ships {', '.join(shipped) or 'none'}"
            )
        return path
    if is_ros2_bag(Path(f)):  # a ROS 2 bag is a directory (its metadata and storage files)
        return Path(f)
    if Path(f).is_dir() and file_format == "rosbag":
        raise RecordingError(
            f"{f}: a directory without {ROS2_METADATA}, so not a ROS 2 bag (data.files); name the bags in it (ROS 1 "
            f".bag files or ROS 2 bag directories), all of them with a pattern: 'data.files=[\"{f}/*\"]'"
        )
    if Path(f).is_dir():
        raise RecordingError(
            f"{f}: a directory (data.files); name the recorded files in it, e.g. data.files=[{f}/demo_0.csv,...], "
            f"or all of them with a pattern: 'data.files=[\"{f}/*.csv\"]'"
        )
    if not Path(f).is_file():
        raise RecordingError(
            f"{f}: no such file (data.files); give the path of a recorded file, relative to the "
            f"directory the command runs in or absolute (or {SHIPPED}NAME for one rmpfusion ships)"
        )
    return Path(f)


def _natural(name: str) -> list:
    """Sort key putting episode_2 before episode_10, as the files were recorded."""
    return [int(part) if part.isdigit() else part for part in re.split(r"(\d+)", name)]


def matching_files(pattern: str) -> list[str]:
    """The files a ``data.files`` entry with wildcards names (``episodes/*.hdf5``), in natural order; a pattern
    that matches no file is refused, not read as an empty dataset."""
    found = sorted((p for p in glob.glob(pattern) if Path(p).is_file() or is_ros2_bag(Path(p))), key=_natural)
    if not found:
        raise RecordingError(
            f"{pattern}: no file matches this pattern (data.files), relative to the directory the command runs in "
            f"({Path.cwd()}); check the path, or quote the list on the command line: 'data.files=[\"{pattern}\"]'"
        )
    return found
