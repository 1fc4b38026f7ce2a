"""Demonstrations from ROS bags: the ``sensor_msgs/JointState`` messages a robot logs while it is taught or
teleoperated, in a ROS 1 ``.bag`` file or a ROS 2 bag directory (SQLite3 or MCAP storage).

A robot's joint-state topic is not a table with the robot file's columns: each message names its joints, drivers
list them in their own order (alphabetical on some arms), a gripper's fingers ride along, and two publishers may
share the topic with different joint sets. The reader therefore takes the joints by name, in the order asked
for, from the messages that carry all of them; a message lacking one is skipped, never filled in. One bag is one
demonstration. Times are the messages' header stamps (the driver's clock) where every message has one, else the
times the bag recorded them (never a mix), counted from the first message.

An environment of positions (the plane) may instead read a point in space per message: a motion-capture body's
``geometry_msgs/PoseStamped`` (as vrpn and mocap drivers publish it), a ``PointStamped`` or a ``TransformStamped``,
its coordinates chosen among x, y, z by ``data.columns``. Such a topic may also give a demonstration's aux state
(``data.aux_topics``): where a tracked obstacle stood, the mean of its positions over the bag.

ROS bags are read by ``rosbags`` (Ternaris's pure-Python reader of both ROS generations, no ROS install needed),
an optional dependency: ``pip install -e '.[ros]'``.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from .readers import unit_scale
from .recording import Recording, RecordingError, where

#: the message type read, as rosbags names it for both ROS generations
JOINT_STATE = "sensor_msgs/msg/JointState"
#: the message types of a point in space read for an environment of positions (motion capture, a tracked tool),
#: and where each holds its point
POINT_TYPES: dict[str, Callable[[Any], Any]] = {
    "geometry_msgs/msg/PoseStamped": lambda msg: msg.pose.position,
    "geometry_msgs/msg/PointStamped": lambda msg: msg.point,
    "geometry_msgs/msg/TransformStamped": lambda msg: msg.transform.translation,
}
#: a point's coordinates, what data.columns chooses among
AXES = ("x", "y", "z")
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


#: a point read as aux state (an obstacle a motion-capture system tracks) may wander this much (m) from its mean
#: over a demonstration (tracking noise); more is an obstacle that moved, which one aux value cannot describe
AUX_STILL = 0.005


def read_rosbag(
    path: str | Path,
    topic: str | None = None,
    columns: Sequence[str] | None = None,
    units: str = "rad",
    joint_space: bool = False,
    aux_topics: Mapping[str, str] | None = None,
) -> list[Recording]:
    """The demonstration a bag holds, from the messages on ``topic`` (default: the bag's only topic of a type read):
    for an arm (``joint_space``) ``sensor_msgs/JointState``, the positions of the joints ``columns`` by name
    (default: those its first message names, in its order); for an environment of positions also a point in space
    (``POINT_TYPES``: motion capture, a tracked tool), its coordinates ``columns`` among x, y, z (default all three).
    Positions are scaled from ``units`` (ROS's own are rad and m). ``aux_topics``: aux name -> a topic of a point
    (``POINT_TYPES``) whose x, y, z in m, averaged over the bag, are that aux state (where a tracked obstacle
    stood)."""
    any_reader, reader_error = _any_reader()
    path = Path(path)
    source = str(path)
    scale = unit_scale(units, source)
    kinds = (JOINT_STATE,) if joint_space else (JOINT_STATE, *POINT_TYPES)
    try:
        with any_reader([path]) as bag:
            connections = _topic_connections(bag, topic, source, kinds)
            label = f"{source} [{connections[0].topic}]"
            read = [(bag.deserialize(raw, c.msgtype), ns) for c, ns, raw in bag.messages(connections=connections)]
            aux = {name: _still_point(bag, aux_topic, source) for name, aux_topic in (aux_topics or {}).items()}
    except reader_error as e:
        raise RecordingError(f"{source}: not a readable ROS bag ({e})") from None
    if not read:
        raise RecordingError(f"{label}: the topic holds no message")
    messages, logged = [m for m, _ in read], [ns for _, ns in read]
    kind = connections[0].msgtype
    if kind == JOINT_STATE:
        wanted = tuple(columns) if columns is not None else tuple(messages[0].name)
        rows, positions, stamps = _joint_positions(messages, wanted, label)
    else:
        wanted = tuple(columns) if columns is not None else AXES
        rows, positions, stamps = _point_positions(messages, POINT_TYPES[kind], wanted, label)
    t = _seconds(stamps if all(s > 0 for s in stamps) else [logged[i] for i in rows])
    return [
        Recording(
            t=t,
            pos=positions * scale,
            source=label,
            columns=wanted,
            aux=aux,
            rows=np.asarray(rows) + 1,
            row_unit="message",
        )
    ]


def _topic_connections(
    bag: Any, topic: str | None, source: str, kinds: Sequence[str], key: str = "data.topic"
) -> list[Any]:
    """The bag's connections on the topic read: ``topic`` (the setting ``key``) when given, else the only topic of
    one of ``kinds``."""
    types = {c.topic: c.msgtype for c in bag.connections}
    readable = sorted(name for name, kind in types.items() if kind in kinds)
    what = " or ".join(kinds)
    held = _listed(types)
    if topic is None:
        if len(readable) > 1:
            raise RecordingError(
                f"{source}: {len(readable)} topics of type {what}: {', '.join(readable)}; name the one to read in "
                "data.topic"
            )
        if not readable:
            raise RecordingError(f"{source}: no topic of type {what}; the bag holds {held}")
        topic = readable[0]
    if topic not in types:
        raise RecordingError(
            f"{source}: no topic {topic!r} ({key}); "
            + (f"its topics of type {what}: {', '.join(readable)}" if readable else f"the bag holds {held}")
        )
    if types[topic] not in kinds:
        raise RecordingError(
            f"{source}: the topic {topic!r} ({key}) carries {types[topic]}, not {what}; "
            + (f"its topics of those types: {', '.join(readable)}" if readable else "the bag has none")
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
            stamps.append(_stamp_ns(msg))
    if not rows:
        missing = sorted(set(wanted) - seen)
        raise RecordingError(
            f"{label}: no message carries every joint of {', '.join(wanted)} (never named: "
            f"{', '.join(missing) or 'none, but never all in one message'}); the topic's messages name "
            f"{', '.join(sorted(seen))}. Choose the joints in data.columns, or the robot those joints belong to"
        )
    return rows, np.asarray(positions, dtype=np.float64), stamps


def _point_positions(
    messages: Sequence[Any], point_of: Callable[[Any], Any], wanted: Sequence[str], label: str
) -> tuple[list[int], np.ndarray, list[int]]:
    """Every message's point (``point_of``: where a message of its type holds it), its ``wanted`` coordinates among
    x, y, z, and its header stamp (ns)."""
    unknown = [c for c in wanted if c not in AXES]
    if unknown:
        raise RecordingError(
            f"{label}: {', '.join(unknown)} (data.columns) is not a coordinate of a point; choose among x, y, z"
        )
    points = [point_of(msg) for msg in messages]
    positions = np.array([[float(getattr(p, axis)) for axis in wanted] for p in points], dtype=np.float64)
    stamps = [_stamp_ns(msg) for msg in messages]
    return list(range(len(messages))), positions, stamps


def _still_point(bag: Any, topic: str, source: str) -> np.ndarray:
    """The mean x, y, z (m) of the point a topic of ``POINT_TYPES`` carries over the bag, refused where it moves
    more than ``AUX_STILL`` from it (one aux value per demonstration)."""
    connections = _topic_connections(bag, topic, source, tuple(POINT_TYPES), key="data.aux_topics")
    point_of = POINT_TYPES[connections[0].msgtype]
    messages = [bag.deserialize(raw, c.msgtype) for c, _, raw in bag.messages(connections=connections)]
    label = f"{source} [{topic}]"
    if not messages:
        raise RecordingError(f"{label}: the topic (data.aux_topics) holds no message")
    xyz = _point_positions(messages, point_of, AXES, label)[1]
    mean = xyz.mean(axis=0)
    off = np.linalg.norm(xyz - mean, axis=1)
    if off.max() > AUX_STILL:
        i = int(np.argmax(off))
        raise RecordingError(
            f"{where(label, i + 1, unit='message')}: the point is {1e3 * off[i]:.3g} mm from where it stands on "
            f"average over the bag, more than a tracker's noise ({1e3 * AUX_STILL:g} mm): it moved during the "
            "demonstration, and aux state (data.aux_topics) holds one value per demonstration"
        )
    return mean


def _stamp_ns(msg: Any) -> int:
    """A stamped message's header time in integer nanoseconds (0 where the publisher left it unset)."""
    return int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)


def _seconds(nanoseconds: Sequence[int]) -> np.ndarray:
    """Times in seconds from the first, subtracted in integer nanoseconds so no digit of a 1.7e18-ns clock is lost."""
    ns = np.asarray(nanoseconds, dtype=np.int64)
    return (ns - ns[0]).astype(np.float64) * 1e-9
