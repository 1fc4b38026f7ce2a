"""Joint-space recordings checked against the robot they were recorded on: a file of another arm, with the
joints in another order, or with an angle past a limit would train a policy on states the robot cannot be in;
each is refused naming the file, row and column."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..robots import RobotDescription
from .recording import Recording, RecordingError

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
