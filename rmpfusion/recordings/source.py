"""A data block's recordings read and brought onto the step grid: the one place that turns ``data: {source:
recorded, ...}`` into demonstrations, whatever the format, so the pipeline, the tools and the tests read them the
same way.

Velocities and accelerations come from one place for the whole dataset: the Savitzky–Golay filter
(``derivatives: filter``) or the files (``derivatives: file``, refused unless every demonstration carries both).
"""

from __future__ import annotations

import dataclasses
import difflib
import hashlib
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..registry import RECORDING_FORMATS
from ..robots import RobotDescription
from .cutting import cut_at_rests
from .formats import RecordedDataConfig  # noqa: F401  (the built-in formats register their readers)
from .joints import check_joint_recordings, check_joint_speeds, check_units
from .paths import SHIPPED, SHIPPED_DIR, matching_files, source_file  # noqa: F401  (where they were first)
from .recording import Recording, RecordingError
from .signals import States, to_states


def named_files(d: Any) -> list[tuple[str, Path]]:
    """Each file the block reads with the name runs record it by: the LASA shape and its ``.mat`` file, or every
    ``data.files`` entry (wildcards expanded), each one that exists (the format's model says which)."""
    return d.named_files()


def source_files(d: Any) -> list[Path]:
    """The files a data block reads (the LASA shape's ``.mat`` file, or ``data.files``), each one that exists."""
    return [p for _, p in named_files(d)]


def file_hashes(d: Any) -> dict[str, str]:
    """sha256 of each file the block reads, by the name the block gives it: what a run directory records, so a
    rerun after a recording changed (or a pattern that now matches other files) is not taken for a resume of the
    run that learned from the old ones."""
    hashes = {}
    for name, path in named_files(d):
        h = hashlib.sha256()
        _feed(h, path)
        hashes[name] = h.hexdigest()
    return hashes


def content_hash(d: Any) -> str:
    """sha256 over the contents of every file the block reads: a cache key that changes when a recording does,
    not when a file is moved."""
    h = hashlib.sha256()
    for path in source_files(d):
        _feed(h, path)
    return h.hexdigest()


def _feed(h: Any, path: Path) -> None:
    """A file's bytes into the hash ``h``; a ROS 2 bag directory's files with their names, in sorted order."""
    if not path.is_dir():
        h.update(path.read_bytes())
        return
    for member in sorted(p for p in path.rglob("*") if p.is_file()):
        h.update(str(member.relative_to(path)).encode())
        h.update(member.read_bytes())


def read_recordings(d: Any, joints: Sequence[str] | None = None) -> list[Recording]:
    """Every demonstration the block names, in file order, positions in SI units and times in seconds, read by
    the reader its format registered (``RECORDING_FORMATS``). ``joints``: the robot's joints in its file's order,
    which a ROS bag's joint states are read by name in (a bag names each value; ``data.columns`` chooses others)."""
    reader = RECORDING_FORMATS.get(d.format).obj
    out: list[Recording] = [rec for path in source_files(d) for rec in reader(d, path, joints)]
    if not out:
        raise RecordingError(f"{', '.join(map(str, source_files(d)))}: no demonstration in the file(s)")
    if (cut := getattr(d, "cut_at_rest", None)) is not None:
        out = cut_at_rests(out, cut, d.polyorder, d.rest_fraction, d.keep_motions, d.rest_speed)
    check_durations(out, getattr(d, "time_units", "s"))
    return out


def ignored_columns(recordings: Sequence[Recording]) -> dict[str, int]:
    """Each column the readers left out (a CSV's columns beside an arm's joints: a gripper's fingers, a second
    clock) and in how many of ``recordings``: what a run says and records, so no column is dropped unseen."""
    out: dict[str, int] = {}
    for rec in recordings:
        for column in rec.ignored:
            out[column] = out.get(column, 0) + 1
    return out


def ignored_line(recordings: Sequence[Recording]) -> str | None:
    """The line saying which columns were not read (None when every column was)."""
    ignored = ignored_columns(recordings)
    if not ignored:
        return None
    read = ", ".join(recordings[0].columns)
    return (
        f"read the columns {read}, named as the robot's joints; ignored the other columns "
        f"{', '.join(ignored)} (in {max(ignored.values())} of {len(recordings)} recordings; data.columns lists the "
        "columns to read)"
    )


#: a demonstration longer than this (s) is taken for time stamps in another unit than data.time_units says
LONGEST_DEMONSTRATION = 600.0


def check_durations(recordings: Sequence[Recording], time_units: str) -> None:
    """A demonstration lasting over ten minutes is almost always milliseconds or nanoseconds read as seconds (or
    several demonstrations read as one): refused before a grid of millions of steps is made from it."""
    longest = max(recordings, key=lambda r: r.duration)
    if longest.duration > LONGEST_DEMONSTRATION:
        raise RecordingError(
            f"{longest.source}: lasts {longest.duration:.6g} s with its time stamps read in {time_units}; if they "
            "are in another unit, set data.time_units (s, ms, us, ns); if the file holds several demonstrations, "
            "name the column telling them apart in data.demo_column, or cut a recording with rests between "
            "them (data.cut_at_rest)"
        )


def check_derivatives(recordings: Sequence[Recording], derivatives: str) -> None:
    """``derivatives: file`` needs velocities and accelerations in every demonstration: a dataset never mixes the
    file's with the filter's."""
    if derivatives != "file":
        return
    lacking = [r.source for r in recordings if r.vel is None or r.acc is None]
    if lacking:
        raise RecordingError(
            f"{lacking[0]}: data.derivatives=file but this demonstration has no velocity and "
            f"acceleration columns ({len(lacking)} of {len(recordings)} lack them); use "
            "data.derivatives=filter for the whole dataset"
        )


def check_dimension(states: Sequence[States], dim: int, env: str, columns: Sequence[str] = ()) -> None:
    """The demonstrations have the environment's dimension (one coordinate per degree of freedom)."""
    if states[0].q.shape[1] != dim:
        read = f" (read from the columns {', '.join(repr(c) for c in columns)})" if columns else ""
        raise RecordingError(
            f"{states[0].source}: the demonstrations have {states[0].q.shape[1]} coordinates{read} but the "
            f"environment {env} has {dim}; choose an environment of that dimension (env=...) or the "
            "columns to read (data.columns)"
        )


def on_grid_for(
    recordings: Sequence[Recording],
    d: Any,
    dt: float,
    dim: int,
    env: str,
    robot: RobotDescription | None,
    aux_dims: Mapping[str, int],
) -> list[States]:
    """The recordings on the environment's step grid after every check that needs the environment: the units
    (angles for a joint space, lengths otherwise), an arm's joints (``robot``: its description, None for an
    environment of positions), the aux state the files give (``aux_dims``: the environment's aux names and widths)
    and the dimension. Validation and the run call this one function."""
    check_units(d.units, robot is not None)
    if robot is not None:
        check_joint_recordings(recordings, robot, named_columns=getattr(d, "columns", None) is None)
        check_joint_speeds(recordings, robot, dt, d.window, d.polyorder)
    check_aux(recordings, aux_dims, env)
    states = to_grid(recordings, d, dt)
    check_dimension(states, dim, env, recordings[0].columns)
    return states


def check_aux(recordings: Sequence[Recording], aux_dims: Mapping[str, int], env: str) -> None:
    """Aux state from the files names the environment's own aux entries with their widths: an entry the tree never
    reads would be ignored without a word, one of another width would fail deep inside a rollout."""
    known = ", ".join(f"{name} ({width})" for name, width in aux_dims.items()) or "none"
    for rec in recordings:
        for name, value in rec.aux.items():
            if name not in aux_dims:
                close = difflib.get_close_matches(name, list(aux_dims), n=1)
                fix = f"did you mean {close[0]!r}?" if close else "rename it to one of these"
                raise RecordingError(
                    f"{rec.source}: aux state {name!r} (data.aux_columns / aux_keys / aux_topics) is not read by the "
                    f"environment {env}; its aux state (name and width): {known}; {fix}"
                )
            if value.shape != (aux_dims[name],):
                raise RecordingError(
                    f"{rec.source}: aux state {name!r} has {value.size} value(s) but the environment {env} reads "
                    f"{aux_dims[name]} (data.aux_columns / aux_keys / aux_topics); list {aux_dims[name]} columns (or an array "
                    "of that width) for it"
                )


def to_grid(recordings: Sequence[Recording], d: Any, dt: float) -> list[States]:
    """Every demonstration on the step grid ``dt`` with its derivatives and goal, the rest trimmed."""
    check_derivatives(recordings, d.derivatives)
    goal = np.asarray(d.goal, np.float64) if d.goal is not None else None
    if goal is not None and goal.shape != (recordings[0].dim,):
        raise RecordingError(
            f"data.goal has {goal.size} coordinates but the demonstrations have "
            f"{recordings[0].dim} ({', '.join(recordings[0].columns)})"
        )
    out = []
    for rec in recordings:
        if d.derivatives == "filter":  # the file's derivatives are never mixed with the filter's
            rec = dataclasses.replace(rec, vel=None, acc=None)
        own = rec.aux.get("goal")  # a goal column in the configuration's own coordinates (the plane's) is the goal
        at = own if own is not None and own.shape == (rec.dim,) else goal
        out.append(
            to_states(rec, dt, d.window, d.polyorder, rest_fraction=d.rest_fraction, goal=at, rest_speed=d.rest_speed)
        )
    return out
