"""From samples at a recorder's times to states on the environment's step grid: resampling, one smoothing
differentiator, and trimming the rest at either end.

* Resampling: a cubic spline through the recorded positions (not-a-knot ends), evaluated on ``t0 + k·dt``; it
  is exact on polynomials of degree ≤ 3, so irregular timestamps cost nothing on smooth motion.
* Differentiation: Savitzky–Golay (a least-squares polynomial of ``polyorder`` over a sliding ``window`` of
  samples, differentiated analytically; scipy.signal.savgol_filter), exact on polynomials of degree ≤
  ``polyorder``. It smooths as it differentiates; a larger window smooths more. The window is chosen on a
  rollout metric of the validation demonstrations: a loss against targets made with the same window would
  reward over-smoothing.
* Rest trimming: a demonstration recorded by hand starts and ends at rest, and those samples would dominate a
  dataset; samples before the first and after the last whose speed exceeds ``rest_fraction`` of the
  demonstration's peak speed (and ``rest_speed``, where given: an encoder's noise keeps a still arm's filtered
  speed above a small fraction of the peak) are dropped, and the mean of the final rest segment is the
  demonstration's goal.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .recording import Recording, RecordingError


@dataclass
class States:
    """One demonstration on a uniform grid: times ``t`` (T,) from 0, positions, velocities, accelerations (T, d),
    the goal (d,) it comes to rest at, and where it came from."""

    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    goal: np.ndarray
    source: str
    aux: dict
    #: the time of the first sample kept on the recording's own clock (s): where a report points a user in the file
    start_time: float = 0.0


def resample(t: np.ndarray, x: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """``x`` (T, d) at times ``t`` on the grid ``t[0] + k·dt`` up to ``t[-1]``, by a cubic spline."""
    from scipy.interpolate import CubicSpline

    n = int(np.floor((t[-1] - t[0]) / dt + 1e-9)) + 1
    grid = t[0] + dt * np.arange(n)
    return grid, CubicSpline(t, x, axis=0, bc_type="not-a-knot")(grid)


def savgol_derivatives(
    x: np.ndarray, dt: float, window: int, polyorder: int, source: str
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(smoothed x, ẋ, ẍ) of uniformly sampled ``x`` (T, d) by one Savitzky–Golay filter."""
    from scipy.signal import savgol_filter

    if window % 2 == 0 or window <= polyorder:
        raise RecordingError(
            f"the differentiator's window ({window}) must be odd and larger than its polyorder ({polyorder})"
        )
    if x.shape[0] < window:
        raise RecordingError(
            f"{source}: {x.shape[0]} samples after resampling at {dt} s, fewer than the "
            f"differentiator's window of {window}; the demonstration is too short for the filter "
            "(lower the window or record longer)"
        )
    f = lambda deriv: savgol_filter(x, window, polyorder, deriv=deriv, delta=dt, axis=0, mode="interp")
    return f(0), f(1), f(2)


def rest_threshold(speed: np.ndarray, rest_fraction: float, rest_speed: float | None = None) -> float:
    """The speed at or below which a demonstration is at rest: ``rest_fraction`` of its peak, or ``rest_speed``
    where that is higher."""
    return max(rest_fraction * float(speed.max()), rest_speed or 0.0)


def runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """(first, last) index, inclusive, of every run of True in ``mask``."""
    padded = np.concatenate([[False], mask, [False]]).astype(np.int8)
    edges = np.flatnonzero(np.diff(padded))
    return [(int(a), int(b) - 1) for a, b in zip(edges[::2], edges[1::2])]


def without_short_runs(mask: np.ndarray, shortest: int) -> np.ndarray:
    """``mask`` with its runs of True shorter than ``shortest`` samples set False: speed above the rest for fewer
    samples than the filter spans is noise (an encoder's, the filter's ends most of all), not a motion."""
    out = mask.copy()
    for a, b in runs(mask):
        if b - a + 1 < shortest:
            out[a : b + 1] = False
    return out


def moving_span(
    speed: np.ndarray, rest_fraction: float, rest_speed: float | None = None, shortest: int = 1
) -> tuple[int, int]:
    """First and last index (inclusive) of the part between the rest at the start and the rest at the end:
    one sample of rest is kept at each side, so the demonstration starts from rest and arrives at rest. Moments
    above the rest threshold lasting fewer than ``shortest`` samples are not motion."""
    moving = np.flatnonzero(without_short_runs(speed > rest_threshold(speed, rest_fraction, rest_speed), shortest))
    if moving.size == 0:
        return 0, speed.shape[0] - 1
    return max(int(moving[0]) - 1, 0), min(int(moving[-1]) + 1, speed.shape[0] - 1)


def to_states(
    rec: Recording,
    dt: float,
    window: int = 21,
    polyorder: int = 3,
    rest_fraction: float = 0.02,
    goal: np.ndarray | None = None,
    rest_speed: float | None = None,
) -> States:
    """``rec`` on the step grid ``dt`` with its derivatives, the rest at both ends trimmed. Velocities and
    accelerations come from the file when it gave both, else from the Savitzky–Golay filter (all of them: the
    dataset never mixes the two). The goal is ``goal`` if given, else the mean of the final rest segment."""
    if rec.vel is not None and rec.acc is not None:
        t, q = resample(rec.t, rec.pos, dt)
        qd, qdd = resample(rec.t, rec.vel, dt)[1], resample(rec.t, rec.acc, dt)[1]
    else:
        t, raw = resample(rec.t, rec.pos, dt)
        q, qd, qdd = savgol_derivatives(raw, dt, window, polyorder, rec.source)
    speed = np.linalg.norm(qd, axis=1)
    # with rest_speed (a noisy encoder) a noise spike above it must not pass for the start of the motion
    first, last = moving_span(speed, rest_fraction, rest_speed, window if rest_speed is not None else 1)
    final_rest = q[last:]
    if goal is None:
        goal = final_rest.mean(axis=0)
    keep = slice(first, last + 1)
    return States(
        t=t[keep] - t[first],
        q=q[keep],
        qd=qd[keep],
        qdd=qdd[keep],
        goal=np.asarray(goal, np.float64),
        source=rec.source,
        aux=dict(rec.aux),
        start_time=float(t[first]),
    )
