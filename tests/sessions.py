"""A teaching session logged as one recording: the shipped Panda recordings one after another on one clock, the arm
held still for 2 s after each (the driver publishing on, 1 mrad of encoder noise), brought back to the next
demonstration's start by a 3 s minimum-jerk return, and held there for 2 s, as a person resetting the arm between
demonstrations records it."""

from __future__ import annotations

import numpy as np
from conftest import ROOT

#: the recordings the session is made of
SHIPPED = ROOT / "rmpfusion" / "recordings" / "files" / "panda_via_points.csv"
RATE = 100.0


def shipped_demonstrations() -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Each shipped demonstration's times (s) and joint angles (rad)."""
    import csv

    rows: dict[str, list[list[float]]] = {}
    with open(SHIPPED, newline="") as fh:
        for row in list(csv.reader(fh))[1:]:
            rows.setdefault(row[0], []).append([float(v) for v in row[1:]])
    return {name: (np.asarray(r)[:, 0], np.asarray(r)[:, 1:]) for name, r in rows.items()}


def _still(q: np.ndarray, seconds: float, rng: np.random.Generator) -> np.ndarray:
    return q + rng.normal(0.0, 1e-3, (int(seconds * RATE), q.shape[0]))


def _return(a: np.ndarray, b: np.ndarray, seconds: float, rng: np.random.Generator) -> np.ndarray:
    s = np.linspace(0.0, 1.0, int(seconds * RATE) + 1)[1:-1, None]
    return a + (b - a) * (10 * s**3 - 15 * s**4 + 6 * s**5) + rng.normal(0.0, 1e-3, (len(s), a.shape[0]))


def panda_session(seed: int = 0) -> tuple[np.ndarray, np.ndarray, list[str | None]]:
    """The session's times (s, from 0), joint angles, and which demonstration each sample belongs to (None for
    the arm held or returning)."""
    rng = np.random.default_rng(seed)
    demos = list(shipped_demonstrations().items())
    times, angles, owner, clock = [], [], [], 0.0
    for k, (name, (t, q)) in enumerate(demos):
        parts: list[tuple[np.ndarray, str | None]] = [(q, name), (_still(q[-1], 2.0, rng), None)]
        if k + 1 < len(demos):
            start = demos[k + 1][1][1][0]
            parts += [(_return(q[-1], start, 3.0, rng), None), (_still(start, 2.0, rng), None)]
        for segment, who in parts:
            if who is None:
                stamps = clock + np.arange(1, len(segment) + 1) / RATE
            else:
                stamps = clock + (t - t[0]) + (1 / RATE if times else 0.0)
            times.append(stamps)
            angles.append(segment)
            owner += [who] * len(segment)
            clock = float(stamps[-1])
    return np.concatenate(times), np.concatenate(angles), owner
