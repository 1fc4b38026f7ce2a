"""Demonstrations from ROS bags: the ``sensor_msgs/JointState`` messages a robot logs while it is taught or
teleoperated, in a ROS 1 ``.bag`` file or a ROS 2 bag directory (SQLite3 or MCAP storage).

A robot's joint-state topic is not a table with the robot file's columns: each message names its joints, drivers
list them in their own order (alphabetical on some arms), a gripper's fingers ride along, and two publishers may
share the topic with different joint sets. The reader therefore takes the joints by name, in the order asked
for, from the messages that carry all of them; a message lacking one is skipped, never filled in. One bag is one
demonstration. Times are the messages' header stamps (the driver's clock) where every message has one, else the
times the bag recorded them (never a mix), counted from the first message.

ROS bags are read by ``rosbags`` (Ternaris's pure-Python reader of both ROS generations, no ROS install needed),
an optional dependency: ``pip install -e '.[ros]'``.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from .readers import unit_scale
from .recording import Recording, RecordingError, where

#: the message type read, as rosbags names it for both ROS generations
JOINT_STATE = "sensor_msgs/msg/JointState"
#: a ROS 2 bag is a directory holding this file beside its storage files
ROS2_METADATA = "metadata.yaml"


def is_ros2_bag(path: Path) -> bool:
    """A directory that is a ROS 2 bag (what ``ros2 bag record`` writes), not just any directory."""
    return path.is_dir() and (path / ROS2_METADATA).is_file()


def _any_reader() -> tuple[Any, type[Exception]]:
    try:
        from rosbags.highlevel import AnyReader, AnyReaderError
    except ImportError:
        raise RecordingError(
            "reading ROS bags (data.format=rosbag) needs the rosbags package: pip install -e '.[ros]' in rmpfusion's "
            "checkout (or pip install rosbags)"
        ) from None
    return AnyReader, AnyReaderError


def read_rosbag(
    path: str | Path, topic: str | None = None, joints: Sequence[str] | None = None, units: str = "rad"
) -> list[Recording]:
    """The demonstration a bag holds: the positions of ``joints`` (default: those the topic's first message
    names, in its order) from the ``sensor_msgs/JointState`` messages on ``topic`` (default: the bag's only
    topic of that type). Positions are scaled from ``units`` (ROS's own are rad and m)."""
    any_reader, reader_error = _any_reader()
    path = Path(path)
    source = str(path)
    scale = unit_scale(units, source)
    try:
        with any_reader([path]) as bag:
            connections = _joint_state_connections(bag, topic, source)
            label = f"{source} [{connections[0].topic}]"
            read = [(bag.deserialize(raw, c.msgtype), ns) for c, ns, raw in bag.messages(connections=connections)]
    except reader_error as e:
        raise RecordingError(f"{source}: not a readable ROS bag ({e})") from None
    if not read:
        raise RecordingError(f"{label}: the topic holds no message")
    messages, logged = [m for m, _ in read], [ns for _, ns in read]
    wanted = tuple(joints) if joints is not None else tuple(messages[0].name)
    rows, positions, stamps = _joint_positions(messages, wanted, label)
    t = _seconds(stamps if all(s > 0 for s in stamps) else [logged[i] for i in rows])
    return [
        Recording(
            t=t, pos=positions * scale, source=label, columns=wanted, rows=np.asarray(rows) + 1, row_unit="message"
        )
    ]


def _joint_state_connections(bag: Any, topic: str | None, source: str) -> list[Any]:
    """The bag's connections on the joint-state topic: ``topic`` when given, else the only JointState topic."""
    kinds = {c.topic: c.msgtype for c in bag.connections}
    joint_topics = sorted(name for name, kind in kinds.items() if kind == JOINT_STATE)
    held = _listed(kinds)
    if topic is None:
        if len(joint_topics) > 1:
            raise RecordingError(
                f"{source}: {len(joint_topics)} topics of type {JOINT_STATE}: {', '.join(joint_topics)}; name the "
                "one to read in data.topic"
            )
        if not joint_topics:
            raise RecordingError(f"{source}: no topic of type {JOINT_STATE}; the bag holds {held}")
        topic = joint_topics[0]
    if topic not in kinds:
        raise RecordingError(
            f"{source}: no topic {topic!r} (data.topic); "
            + (f"its {JOINT_STATE} topics: {', '.join(joint_topics)}" if joint_topics else f"the bag holds {held}")
        )
    if kinds[topic] != JOINT_STATE:
        raise RecordingError(
            f"{source}: the topic {topic!r} (data.topic) carries {kinds[topic]}, not {JOINT_STATE}; "
            + (f"its {JOINT_STATE} topics: {', '.join(joint_topics)}" if joint_topics else "the bag has none")
        )
    return [c for c in bag.connections if c.topic == topic]


#: a bag recorded with every topic can hold hundreds: the messages list this many
LISTED_TOPICS = 20


def _listed(kinds: dict[str, str]) -> str:
    """The bag's topics with their types, the first LISTED_TOPICS of them."""
    names = sorted(kinds)
    shown = ", ".join(f"{name} ({kinds[name]})" for name in names[:LISTED_TOPICS]) or "no topic"
    return shown + (f" and {len(names) - LISTED_TOPICS} more" if len(names) > LISTED_TOPICS else "")


def _joint_positions(
    messages: Sequence[Any], wanted: Sequence[str], label: str
) -> tuple[list[int], np.ndarray, list[int]]:
    """The message numbers (0-based) that carry every ``wanted`` joint, their positions in the ``wanted`` order
    and their header stamps (ns)."""
    rows, positions, stamps = [], [], []
    seen: set[str] = set()
    for i, msg in enumerate(messages):
        names = list(msg.name)
        if len(msg.position) != len(names):
            raise RecordingError(
                f"{where(label, i + 1, unit='message')}: the message names {len(names)} joints but holds {len(msg.position)} "
                "positions; a JointState's name and position lists must be the same length"
            )
        seen.update(names)
        index = {name: k for k, name in enumerate(names)}
        if all(joint in index for joint in wanted):
            rows.append(i)
            positions.append([float(msg.position[index[joint]]) for joint in wanted])
            stamps.append(int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec))
    if not rows:
        missing = sorted(set(wanted) - seen)
        raise RecordingError(
            f"{label}: no message carries every joint of {', '.join(wanted)} (never named: "
            f"{', '.join(missing) or 'none, but never all in one message'}); the topic's messages name "
            f"{', '.join(sorted(seen))}. Choose the joints in data.columns, or the robot those joints belong to"
        )
    return rows, np.asarray(positions, dtype=np.float64), stamps


def _seconds(nanoseconds: Sequence[int]) -> np.ndarray:
    """Times in seconds from the first, subtracted in integer nanoseconds so no digit of a 1.7e18-ns clock is lost."""
    ns = np.asarray(nanoseconds, dtype=np.int64)
    return (ns - ns[0]).astype(np.float64) * 1e-9
