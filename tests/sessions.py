"""The shipped Panda recordings as one teaching session (tools/rosbag_recordings.py's ``session``: held 2 s after
each demonstration, brought back to the next start in 3 s, held 2 s, 1 mrad of encoder noise at 100 Hz), for the
tests that cut a session into its demonstrations."""

from __future__ import annotations

import numpy as np
from conftest import ROOT

from tools.rosbag_recordings import read_csv_demonstrations, session

#: the recordings the session is made of
SHIPPED = ROOT / "rmpfusion" / "recordings" / "files" / "panda_via_points.csv"


def shipped_demonstrations() -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Each shipped demonstration's times (s) and joint angles (rad)."""
    return read_csv_demonstrations(SHIPPED)[1]


def panda_session(seed: int = 0) -> tuple[np.ndarray, np.ndarray, list[str | None]]:
    """The session's times (s, from 0), joint angles, and which demonstration each sample belongs to (None for
    the arm held or returning)."""
    return session(shipped_demonstrations(), seed)
