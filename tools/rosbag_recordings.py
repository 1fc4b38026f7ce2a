#!/usr/bin/env python
"""Joint-space recordings logged as a ROS robot logs them: one bag per demonstration of sensor_msgs/JointState
messages, for ``data.format=rosbag`` to read back like a robot's own log.

    python tools/rosbag_recordings.py --out bags     # the shipped Panda recordings, one ROS 2 bag (MCAP) each
    rmpfusion-run experiment=recorded_arm data.format=rosbag data.demo_column=null 'data.files=["bags/demo*"]'

    python tools/rosbag_recordings.py --out session --session   # all of them in one bag, as one teaching session
    rmpfusion-run experiment=recorded_arm data.format=rosbag data.demo_column=null 'data.files=["session/session"]' \
        data.cut_at_rest=1.0 data.keep_motions=odd

The messages are laid out the way real drivers publish them, not the way the robot file lists the joints: the joints
in another order (last to first), the gripper's fingers inside the arm's messages, and after every third one a
gripper-only message on the same topic (a second publisher); the header stamps are the recording's own times on a
robot clock 1.76e9 s past the epoch, and the bag logs each message 2 ms after its stamp. The source is a CSV of a
demonstration column, a time column and one column per joint (``tools/arm_recordings.py`` writes one).

Bags are written by ``rosbags`` (``pip install -e '.[ros]'``): ``--kind ros1`` (a .bag file per demonstration),
``ros2-mcap`` or ``ros2-sqlite3`` (a bag directory per demonstration).
"""

from __future__ import annotations

import argparse
import csv
import shutil
import sys
import tempfile
from collections import defaultdict
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from rmpfusion.recordings.source import SHIPPED_DIR

JOINT_STATE = "sensor_msgs/msg/JointState"
KINDS = ("ros1", "ros2-mcap", "ros2-sqlite3")
#: the robot clock's first stamp (ns): large, so a reader that loses digits of it is caught
CLOCK_NS = 1_760_000_000_123_456_789
#: the bag logs each message this long after its stamp (ns)
LOG_DELAY_NS = 2_000_000
FINGERS = ("panda_finger_joint1", "panda_finger_joint2")


def typestore(kind: str) -> Any:
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS1_NOETIC if kind == "ros1" else Stores.ROS2_HUMBLE)


def _header(store: Any, kind: str, stamp_ns: int, frame_id: str) -> Any:
    """A std_msgs/Header stamped ``stamp_ns`` (ROS 1's carries a sequence number too)."""
    stamp = store.types["builtin_interfaces/msg/Time"](sec=stamp_ns // 10**9, nanosec=stamp_ns % 10**9)
    return store.types["std_msgs/msg/Header"](stamp=stamp, frame_id=frame_id, **({"seq": 0} if kind == "ros1" else {}))


def joint_state(store: Any, kind: str, stamp_ns: int, names: Sequence[str], positions: Iterable[float]) -> Any:
    """One sensor_msgs/JointState with its header stamped ``stamp_ns`` (no velocities or efforts)."""
    types = store.types
    header = _header(store, kind, stamp_ns, "")
    empty = np.zeros(0, dtype=np.float64)
    return types[JOINT_STATE](
        header=header,
        name=list(names),
        position=np.asarray(list(positions), dtype=np.float64),
        velocity=empty,
        effort=empty,
    )


def point_message(store: Any, kind: str, msgtype: str, stamp_ns: int, xyz: Sequence[float]) -> Any:
    """A stamped point in space as ``msgtype`` holds it: a PoseStamped's position (identity orientation), a
    PointStamped's point or a TransformStamped's translation (as motion-capture drivers publish a tracked body)."""
    types = store.types
    header = _header(store, kind, stamp_ns, "world")
    x, y, z = (float(v) for v in xyz)
    rotation = types["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0)
    if msgtype == "geometry_msgs/msg/PoseStamped":
        pose = types["geometry_msgs/msg/Pose"](
            position=types["geometry_msgs/msg/Point"](x=x, y=y, z=z), orientation=rotation
        )
        return types[msgtype](header=header, pose=pose)
    if msgtype == "geometry_msgs/msg/PointStamped":
        return types[msgtype](header=header, point=types["geometry_msgs/msg/Point"](x=x, y=y, z=z))
    translation = types["geometry_msgs/msg/Vector3"](x=x, y=y, z=z)
    transform = types["geometry_msgs/msg/Transform"](translation=translation, rotation=rotation)
    return types[msgtype](header=header, child_frame_id="pen", transform=transform)


def write_bag(path: Path, kind: str, messages: Sequence[tuple[str, str, Any, int]], compressed: bool = False) -> Path:
    """A bag of ``kind`` at ``path`` holding ``messages``: (topic, message type, message, log time in ns);
    ``compressed`` as ``rosbag record --lz4`` (ROS 1) or ``ros2 bag record --compression-mode message
    --compression-format zstd`` (ROS 2) write them."""
    from rosbags.rosbag1 import Writer as Ros1Writer
    from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin
    from rosbags.rosbag2 import Writer as Ros2Writer

    store = typestore(kind)
    writer: Any
    if kind == "ros1":
        writer, serialize = Ros1Writer(path), store.serialize_ros1
        if compressed:
            writer.set_compression(Ros1Writer.CompressionFormat.LZ4)
    else:
        plugin = StoragePlugin.MCAP if kind == "ros2-mcap" else StoragePlugin.SQLITE3
        writer, serialize = Ros2Writer(path, version=9, storage_plugin=plugin), store.serialize_cdr
        if compressed:
            writer.set_compression(CompressionMode.MESSAGE, CompressionFormat.ZSTD)
    with writer:
        connections = {}
        for topic, msgtype in dict.fromkeys((topic, msgtype) for topic, msgtype, _, _ in messages):
            connections[topic] = writer.add_connection(topic, msgtype, typestore=store)
        for topic, msgtype, msg, logged_ns in messages:
            writer.write(connections[topic], logged_ns, serialize(msg, msgtype))
    return path


def driver_log(
    kind: str, q: np.ndarray, stamps_ns: np.ndarray, joints: Sequence[str], topic: str = "/joint_states"
) -> list[tuple[str, str, Any, int]]:
    """The configurations ``q`` (T, len(joints)) as a driver publishes them (module docstring): joints last to
    first with the fingers between them, a gripper-only message after every third."""
    store = typestore(kind)
    order = [*joints[:1:-1], *FINGERS, *joints[1::-1]]
    out = []
    for k, (row, stamp) in enumerate(zip(q, stamps_ns)):
        values = dict(zip(joints, row)) | dict.fromkeys(FINGERS, 0.04)
        msg = joint_state(store, kind, int(stamp), order, [values[j] for j in order])
        out.append((topic, JOINT_STATE, msg, int(stamp) + LOG_DELAY_NS))
        if k % 3 == 2:
            gripper = joint_state(store, kind, int(stamp) + 1_000, FINGERS, [0.04, 0.04])
            out.append((topic, JOINT_STATE, gripper, int(stamp) + LOG_DELAY_NS + 1_000))
    return out


def read_csv_demonstrations(path: Path) -> tuple[list[str], dict[str, tuple[np.ndarray, np.ndarray]]]:
    """The joints (every column but demo and t) and each demonstration's times (s) and angles."""
    rows: dict[str, list[list[float]]] = defaultdict(list)
    with open(path, newline="") as fh:
        reader = csv.DictReader(fh)
        joints = [c for c in reader.fieldnames or [] if c not in ("demo", "t")]
        for row in reader:
            rows[row["demo"]].append([float(row["t"]), *(float(row[j]) for j in joints)])
    return joints, {name: (np.asarray(r)[:, 0], np.asarray(r)[:, 1:]) for name, r in rows.items()}


#: a teaching session: the arm held this long (s) after each demonstration and before the next, and brought back
#: to the next one's start in RETURN_S, at the recordings' nominal rate with this much encoder noise (rad)
HOLD_S, RETURN_S, SESSION_RATE, ENCODER_NOISE = 2.0, 3.0, 100.0, 1e-3


def session(
    demos: dict[str, tuple[np.ndarray, np.ndarray]], seed: int = 0
) -> tuple[np.ndarray, np.ndarray, list[str | None]]:
    """The demonstrations one after another as a person teaching the arm records them in one log: each one's own
    samples and stamps, then the arm held still (``HOLD_S``), brought back to the next one's start by a
    minimum-jerk motion (``RETURN_S``) and held there (``HOLD_S``), the driver publishing on at ``SESSION_RATE``
    with ``ENCODER_NOISE``. Returns the times (s, from 0), the angles, and which demonstration each sample belongs
    to (None: held or returning)."""
    rng = np.random.default_rng(seed)
    items = list(demos.items())
    times, angles, owner, clock = [], [], [], 0.0
    for k, (name, (t, q)) in enumerate(items):
        parts: list[tuple[np.ndarray, str | None]] = [(q, name), (_held(q[-1], rng), None)]
        if k + 1 < len(items):
            start = items[k + 1][1][1][0]
            parts += [(_returned(q[-1], start, rng), None), (_held(start, rng), None)]
        for segment, who in parts:
            if who is None:
                stamps = clock + np.arange(1, len(segment) + 1) / SESSION_RATE
            else:
                stamps = clock + (t - t[0]) + (1 / SESSION_RATE if times else 0.0)
            times.append(stamps)
            angles.append(segment)
            owner += [who] * len(segment)
            clock = float(stamps[-1])
    return np.concatenate(times), np.concatenate(angles), owner


def _held(q: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    return q + rng.normal(0.0, ENCODER_NOISE, (int(HOLD_S * SESSION_RATE), q.shape[0]))


def _returned(a: np.ndarray, b: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    s = np.linspace(0.0, 1.0, int(RETURN_S * SESSION_RATE) + 1)[1:-1, None]
    return a + (b - a) * (10 * s**3 - 15 * s**4 + 6 * s**5) + rng.normal(0.0, ENCODER_NOISE, (len(s), a.shape[0]))


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--csv", type=Path, default=SHIPPED_DIR / "panda_via_points.csv", help="the recordings to log")
    ap.add_argument("--out", type=Path, required=True, help="a new directory for the bags")
    ap.add_argument("--kind", choices=KINDS, default="ros2-mcap")
    ap.add_argument("--compressed", action="store_true", help="LZ4 chunks (ROS 1) or zstd messages (ROS 2)")
    ap.add_argument(
        "--session",
        action="store_true",
        help="one bag of the whole teaching session (the arm held and brought back between demonstrations) "
        "instead of one per demonstration; read with data.cut_at_rest=1.0 data.keep_motions=odd",
    )
    a = ap.parse_args(argv)
    if a.out.exists():
        print(f"{a.out} exists; give a new directory (nothing is overwritten)", file=sys.stderr)
        return 1
    joints, demos = read_csv_demonstrations(a.csv)
    staging = Path(tempfile.mkdtemp(prefix=f".{a.out.name}.", dir=a.out.resolve().parent))
    logs = {"session": session(demos)[:2]} if a.session else {name: (t - t[0], q) for name, (t, q) in demos.items()}
    try:
        for name, (t, q) in logs.items():
            stamps = CLOCK_NS + np.round(t * 1e9).astype(np.int64)
            bag = staging / (f"{name}.bag" if a.kind == "ros1" else name)
            write_bag(bag, a.kind, driver_log(a.kind, q, stamps, joints), a.compressed)
        staging.rename(a.out)  # every bag or none: no half-written directory under the name asked for
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    what = f"1 {a.kind} bag of a session of {len(demos)} demonstrations" if a.session else f"{len(demos)} {a.kind} bags"
    print(f"{a.out}: {what} of {JOINT_STATE} on /joint_states, from {a.csv}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
