"""One recorded demonstration as a user's file holds it, and the one error every reader raises.

A recording is what a person measured (kinesthetic teaching, teleoperation, motion capture, a planner's output),
not what an RMP tree produced: timestamps may be irregular, velocities may be absent, and the first and last
seconds are often the arm at rest. Everything downstream (resampling, differentiation, trimming, splits) reads
this one type, whatever the file format was.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


class RecordingError(ValueError):
    """A recording that cannot be used: the message names the file, and the row and column where there is one."""


class TimeOrderError(RecordingError):
    """Time stamps that do not increase: a reader that knows why they might not (several demonstrations in one
    file) adds that to the message."""


def where(source: str, row: int | None = None, column: str | None = None, unit: str = "row") -> str:
    """``file``, ``file, row 12`` or ``file, row 12, column 'q3'``: the place a RecordingError points at.
    Rows count from 1 as a spreadsheet or an editor shows them (for a CSV, the header is row 1); a bag's places
    are its messages (``unit``)."""
    out = source
    if row is not None:
        out += f", {unit} {row}"
    if column is not None:
        out += f", column {column!r}"
    return out


@dataclass
class Recording:
    """One demonstration: positions ``pos`` (T, d) at times ``t`` (T,) in seconds, strictly increasing.

    ``vel`` and ``acc`` are (T, d) when the file gave them (else None: they are derived by one smoothing
    differentiator for the whole dataset, never mixed). ``aux`` holds per-demonstration auxiliary state (a goal,
    an obstacle pose): name -> (k,) constant over the demonstration. ``source`` names the file (and the
    demonstration inside it) for every later error; ``columns`` names the coordinates.
    """

    t: np.ndarray
    pos: np.ndarray
    source: str
    columns: tuple[str, ...]
    vel: np.ndarray | None = None
    acc: np.ndarray | None = None
    aux: dict[str, np.ndarray] = field(default_factory=dict)
    #: file rows of the samples (for messages): row_of[i] is the file row of sample i
    rows: np.ndarray | None = None
    #: what a row is called in messages: a file's row, a bag's message
    row_unit: str = "row"
    #: the file's columns read as none of these (not the robot's joints: a gripper's fingers, a second clock), which
    #: a run lists so that nothing is left out without a word
    ignored: tuple[str, ...] = ()

    def __post_init__(self):
        self.t = np.asarray(self.t, dtype=np.float64)
        self.pos = np.asarray(self.pos, dtype=np.float64)
        if self.pos.ndim == 1:
            self.pos = self.pos[:, None]
        check_recording(self)

    @property
    def dim(self) -> int:
        return self.pos.shape[1]

    @property
    def duration(self) -> float:
        return float(self.t[-1] - self.t[0])

    def row(self, i: int) -> int | None:
        return int(self.rows[i]) if self.rows is not None else None

    def at(self, i: int, column: str | None = None) -> str:
        """Where sample ``i`` (and ``column``) lies in the file, as a RecordingError names it."""
        return where(self.source, self.row(i), column, self.row_unit)


def check_recording(rec: Recording) -> None:
    """Refuse what no later step can repair, naming the file, row and column: a time column that is not
    strictly increasing, non-finite values, arrays whose lengths or widths disagree."""
    if rec.t.ndim != 1 or rec.pos.shape[0] != rec.t.shape[0]:
        raise RecordingError(
            f"{rec.source}: {rec.t.shape[0]} timestamps but {rec.pos.shape[0]} positions; every "
            "sample needs one time and one position"
        )
    if rec.pos.shape[1] != len(rec.columns):
        raise RecordingError(
            f"{rec.source}: positions have {rec.pos.shape[1]} coordinates but {len(rec.columns)} "
            f"column names were given ({', '.join(rec.columns)})"
        )
    if rec.t.shape[0] < 2:
        raise RecordingError(f"{rec.source}: {rec.t.shape[0]} sample(s); a demonstration needs at least two")
    for name, values in (("t", rec.t[:, None]), *((c, rec.pos[:, [k]]) for k, c in enumerate(rec.columns))):
        bad = np.flatnonzero(~np.isfinite(values[:, 0]))
        if bad.size:
            raise RecordingError(
                f"{rec.at(int(bad[0]), name)}: {float(values[bad[0], 0])} is not a finite "
                f"number ({bad.size} such value(s) in this column); fill or drop those samples"
            )
    for label, arr in (("velocity", rec.vel), ("acceleration", rec.acc)):
        if arr is not None and (arr.shape != rec.pos.shape or not np.isfinite(arr).all()):
            raise RecordingError(
                f"{rec.source}: the {label} columns must be finite and shaped like the positions "
                f"{rec.pos.shape}; given {arr.shape}"
            )
    step = np.diff(rec.t)
    bad = np.flatnonzero(step <= 0)
    if bad.size:
        i = int(bad[0]) + 1
        precision = (
            " (time stamps this large lose their fractions when stored as float32: store float64, or subtract "
            "the first time)"
            if abs(float(rec.t[i])) > 1e6
            else ""
        )
        raise TimeOrderError(
            f"{rec.at(i, 't')}: time {float(rec.t[i])!r} does not increase (the sample "
            f"before is at {float(rec.t[i - 1])!r}); timestamps must be strictly increasing: sort the samples "
            f"or drop the duplicate{precision}"
        )
    check_gaps(rec, step)


#: a step between samples longer than this (s) and than GAP_FACTOR times the median step is a gap, not jitter
LONGEST_GAP = 1.0
GAP_FACTOR = 50.0


def check_gaps(rec: Recording, step: np.ndarray) -> None:
    """A pause in the samples long against the recording's own rate: resampling would invent the motion across
    it (a spline through the gap), and it is most often two demonstrations read as one."""
    median = float(np.median(step))
    gap = np.flatnonzero((step > LONGEST_GAP) & (step > GAP_FACTOR * median))
    if gap.size:
        i = int(gap[0]) + 1
        raise TimeOrderError(
            f"{rec.at(i, 't')}: {float(step[i - 1]):.6g} s without a sample before this one "
            f"(the median step is {median:.3g} s); resampling would invent the motion across it: "
            "cut the recording there into two demonstrations"
        )
