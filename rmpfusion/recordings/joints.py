"""Joint-space recordings checked against the robot they were recorded on: a file of another arm, with the
joints in another order, or with an angle past a limit would train a policy on states the robot cannot be in;
each is refused naming the file, row and column."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..robots import RobotDescription
from .recording import Recording, RecordingError
from .signals import resample, savgol_derivatives

#: angles within this much of a limit count as inside it (encoders and the URDF's rounding, in rad or m)
LIMIT_TOLERANCE = 1e-3


def check_joint_recordings(
    recordings: Sequence[Recording], robot: RobotDescription, named_columns: bool = True
) -> None:
    """Every recording has one coordinate per actuated joint of ``robot``, in the robot file's order when its
    columns are named (``named_columns``), and stays inside the joints' position limits."""
    joints = list(robot.joints)
    limits = np.array([(lo, hi) for lo, hi, _ in robot.joint_limits()])
    for rec in recordings:
        if rec.dim != len(joints):
            raise RecordingError(
                f"{rec.source}: {rec.dim} coordinates per sample (read from {', '.join(rec.columns)}), but the robot "
                f"'{robot.name}' has {len(joints)} actuated joints ({', '.join(joints)}); name the columns to read in "
                "data.columns, and any aux columns in data.aux_columns"
            )
        if named_columns and list(rec.columns) != joints:
            missing = [j for j in joints if j not in rec.columns]
            detail = f"missing {', '.join(missing)}" if missing else "in another order"
            raise RecordingError(
                f"{rec.source}: the columns {', '.join(rec.columns)} are not the robot's joints "
                f"({detail}); name them {', '.join(joints)} in this order, or list them in "
                "data.columns"
            )
        below = rec.pos < limits[:, 0] - LIMIT_TOLERANCE
        above = rec.pos > limits[:, 1] + LIMIT_TOLERANCE
        bad = np.argwhere(below | above)
        if bad.size:
            i, k = (int(v) for v in bad[0])
            lo, hi = limits[k]
            raise RecordingError(
                f"{rec.at(i, rec.columns[k])}: {rec.pos[i, k]:.6g} lies outside "
                f"{joints[k]}'s limits [{lo:.6g}, {hi:.6g}] of the robot '{robot.name}' "
                f"({len(bad)} such value(s)); check the units (deg vs rad) and the joint order"
            )


#: a recorded joint faster than this many times its velocity limit is a jump in the recording, not a motion
SPEED_MARGIN = 2.0


def check_joint_speeds(
    recordings: Sequence[Recording], robot: RobotDescription, dt: float, window: int, polyorder: int
) -> None:
    """No joint moves at over ``SPEED_MARGIN`` times its velocity limit, at the speeds the dataset would hold (the
    step grid ``dt``, the filter's ``window`` and ``polyorder``): such a speed is a jump between two samples (an
    encoder glitch, or demonstrations logged back to back without the motion between them), and it would also
    make the rest at either end unrecognisable (rest is a fraction of the peak speed), so the trimmed
    demonstration would silently be a sliver around the jump."""
    joints = list(robot.joints)
    limits = np.array([v for _, _, v in robot.joint_limits()])
    for rec in recordings:
        t, raw = resample(rec.t, rec.pos, dt)
        if len(t) < window:
            continue  # too short for the filter: the grid says so with its own message
        _, qd, _ = savgol_derivatives(raw, dt, window, polyorder, rec.source)
        over = (np.abs(qd) > SPEED_MARGIN * limits).any(axis=1)
        if over.any():
            j, k, step = _fastest_step(rec, limits, t[int(np.argmax(over))], dt * window)
            raise RecordingError(
                f"{rec.at(j, rec.columns[k])}: {joints[k]} moves {rec.pos[j, k] - rec.pos[j - 1, k]:+.3g} rad in "
                f"{1e3 * step:.3g} ms from the sample before, over {SPEED_MARGIN:g} times its velocity limit of "
                f"{limits[k]:.3g} rad/s on the robot '{robot.name}': a jump in the recording (a glitch, or "
                "demonstrations logged back to back without the motion between them); drop those samples, or cut "
                "the recording there"
            )


def _fastest_step(rec: Recording, limits: np.ndarray, near: float, span: float) -> tuple[int, int, float]:
    """(sample, joint, step in s) of the recorded step fastest against the limits within ``span`` after the time
    ``near`` where the filtered speed first exceeds them: the filter spreads a jump over its window, the samples
    say where it is."""
    lo = max(int(np.searchsorted(rec.t, near - span)), 1)
    hi = min(int(np.searchsorted(rec.t, near + span)) + 1, len(rec.t))
    steps = np.diff(rec.t[lo - 1 : hi])
    ratio = np.abs(np.diff(rec.pos[lo - 1 : hi], axis=0)) / steps[:, None] / limits
    i, k = np.unravel_index(int(np.argmax(ratio)), ratio.shape)
    return lo + int(i), int(k), float(steps[i])


#: the data units a joint-space recording may be in (a prismatic joint's metres are read unchanged with rad)
ANGULAR_UNITS = ("rad", "deg")


def check_units(units: str, joint_space: bool) -> None:
    """Angular units for an arm's joint-space recordings, lengths for an environment of positions: deg applied
    to a plane's millimetres would shrink the demonstrations 57 times without a word."""
    if joint_space and units not in ANGULAR_UNITS:
        raise RecordingError(
            f"data.units={units}: the environment learns from joint angles; set data.units=rad or deg (a prismatic "
            "joint's metres are read unchanged with rad)"
        )
    if not joint_space and units in ANGULAR_UNITS:
        raise RecordingError(
            f"data.units={units} is for an arm's joint angles, but this environment's coordinates are positions; "
            "set data.units=m, cm or mm"
        )
