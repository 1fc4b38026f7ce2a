"""Cutting one long recording into demonstrations at the rests between them.

A robot's own log (a ROS bag, a controller's CSV) often holds a whole teaching session: the arm moved, was held
still while the operator reset, moved again. Its samples never pause (the driver keeps publishing at rest), so
nothing in the time stamps tells the demonstrations apart; the rests do. With ``data.cut_at_rest`` set, a recording
is cut in the middle of every rest lasting at least that long between two motions, and each piece is a
demonstration (trimmed, given its goal and split like any other). Rest is what trimming calls rest: speed below
``data.rest_fraction`` of the recording's peak (or ``data.rest_speed``), here from a Savitzky–Golay filter
(``data.polyorder``) spanning about half of ``data.cut_at_rest`` on a grid at the recording's own median sample
step, so that an encoder's noise at rest stays well below it; speed above it for fewer samples than the filter
spans is noise, not a motion.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from .recording import Recording, RecordingError
from .signals import resample, rest_threshold, runs, savgol_derivatives, without_short_runs


def cut_times(
    rec: Recording, min_rest: float, polyorder: int, rest_fraction: float, rest_speed: float | None = None
) -> list[float]:
    """The times at which ``rec`` is cut: the middle of every rest of at least ``min_rest`` seconds that has motion
    on both sides (the rests at either end are trimmed later, not cut)."""
    step = float(np.median(np.diff(rec.t)))
    window = max(2 * int(0.25 * min_rest / step) + 1, polyorder + 2 + polyorder % 2)  # odd, about min_rest / 2
    t, raw = resample(rec.t, rec.pos, step)
    if len(t) < window:
        return []  # shorter than half the rest asked for: it holds no such rest between two motions
    _, qd, _ = savgol_derivatives(raw, step, window, polyorder, rec.source)
    speed = np.linalg.norm(qd, axis=1)
    moving = without_short_runs(speed > rest_threshold(speed, rest_fraction, rest_speed), window)
    rests = runs(~moving)
    return [0.5 * (t[a] + t[b]) for a, b in rests if a > 0 and b < len(t) - 1 and t[b] - t[a] >= min_rest]


def _piece(rec: Recording, keep: np.ndarray, k: int, n: int) -> Recording:
    """The samples ``keep`` of ``rec`` as its motion ``k`` of ``n``, named so in every later message (with the
    file's rows or the bag's message numbers kept, so those messages still point into the file)."""
    if n == 1:
        return rec  # nothing to cut: the recording as it was, named as before
    rows = rec.rows[keep] if rec.rows is not None else None
    return dataclasses.replace(
        rec,
        t=rec.t[keep],
        pos=rec.pos[keep],
        vel=rec.vel[keep] if rec.vel is not None else None,
        acc=rec.acc[keep] if rec.acc is not None else None,
        rows=rows,
        source=f"{rec.source} (motion {k} of {n}, from t={rec.t[keep][0] - rec.t[0]:.3f} s)",
    )


#: which motions (numbered from 1) each choice of ``data.keep_motions`` keeps
KEPT = {"all": lambda k: True, "odd": lambda k: k % 2 == 1, "even": lambda k: k % 2 == 0}


def cut_at_rests(
    recordings: Sequence[Recording],
    min_rest: float,
    polyorder: int,
    rest_fraction: float,
    keep: str = "all",
    rest_speed: float | None = None,
) -> list[Recording]:
    """Every recording cut into its motions (a recording with no rest that long between motions stays whole, as
    its motion 1), of which ``keep`` are demonstrations: all, or the odd or even ones (a session that recorded the
    arm's return to the start between demonstrations alternates the two)."""
    out: list[Recording] = []
    for rec in recordings:
        cuts = cut_times(rec, min_rest, polyorder, rest_fraction, rest_speed)
        piece = np.searchsorted(cuts, rec.t, side="right")  # which piece each sample falls in
        n = len(cuts) + 1
        out += [_piece(rec, piece == k - 1, k, n) for k in range(1, n + 1) if KEPT[keep](k)]
    if not out:
        raise RecordingError(
            f"data.keep_motions={keep}: no recording has a motion {2 if keep == 'even' else 1}, as every one rests "
            f"less than data.cut_at_rest={min_rest:g} s between motions; lower it, or keep all motions"
        )
    return out
