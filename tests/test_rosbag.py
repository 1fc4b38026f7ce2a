"""Robot logs as ROS records them: sensor_msgs/JointState in ROS 1 bags and ROS 2 bags (SQLite3 and MCAP), written
by rosbags' own writers the way drivers publish them (joints in the driver's order, a gripper's fingers in the same
messages or in messages of their own, header stamps on the robot's clock) and read back by name in the robot file's
order; every bad bag answered by one message naming the bag, the message and the joint."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import ROOT, compose_cfg
from pydantic import ValidationError
from sessions import panda_session, shipped_demonstrations

from rmpfusion.assembly.errors import ConfigError
from rmpfusion.pipeline.config import RecordedDataConfig
from rmpfusion.pipeline.validate import resolve_and_validate
from rmpfusion.recordings import RecordingError, read_lasa
from rmpfusion.recordings.source import file_hashes, read_recordings, to_grid
from tools.rosbag_recordings import CLOCK_NS, driver_log, joint_state, main, point_message, typestore, write_bag

PANDA = [f"panda_joint{k}" for k in range(1, 8)]
KINDS = ["ros1", "ros2-sqlite3", "ros2-mcap"]


def bag_path(tmp_path: Path, kind: str, name: str = "demo") -> Path:
    return tmp_path / (f"{name}.bag" if kind == "ros1" else name)


def arm_reach(n: int = 150) -> tuple[np.ndarray, np.ndarray]:
    """A joint-space reach inside the Panda's limits at irregular stamps (about 100 Hz with jitter)."""
    s = np.linspace(0, 1, n)
    q = np.array([0.0, -0.3, 0.0, -2.0, 0.0, 1.8, 0.8]) + np.outer(10 * s**3 - 15 * s**4 + 6 * s**5, np.full(7, 0.4))
    steps = 10_000_000 + np.random.default_rng(0).integers(-2_000_000, 2_000_000, n)
    return q, CLOCK_NS + np.concatenate([[0], np.cumsum(steps[1:])])


def data_block(**keys) -> RecordedDataConfig:
    return RecordedDataConfig.model_validate({"source": "recorded", "format": "rosbag", "units": "rad", **keys})


def edited(kind: str, log: list, k: int, stamp_ns: int | None = None, names=None, positions=None) -> list:
    """``log`` with message ``k`` (0-based) remade: another stamp, other names or other positions."""
    topic, msgtype, msg, logged = log[k]
    stamp = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec if stamp_ns is None else stamp_ns
    new = joint_state(typestore(kind), kind, stamp, names or msg.name, msg.position if positions is None else positions)
    return [*log[:k], (topic, msgtype, new, logged), *log[k + 1 :]]


# ------------------------------------------------------------------------------------------------ good bags
@pytest.mark.parametrize("compressed", [False, True], ids=["plain", "compressed"])
@pytest.mark.parametrize("kind", KINDS)
def test_joint_states_are_read_by_name_in_the_robots_order(tmp_path, kind, compressed):
    q, stamps = arm_reach()
    bag = write_bag(bag_path(tmp_path, kind), kind, driver_log(kind, q, stamps, PANDA), compressed)
    (rec,) = read_recordings(data_block(files=[str(bag)]), joints=PANDA)
    assert rec.columns == tuple(PANDA)
    np.testing.assert_array_equal(rec.pos, q)  # the robot file's order, fingers dropped, gripper messages skipped
    np.testing.assert_allclose(rec.t, (stamps - stamps[0]) * 1e-9, rtol=0, atol=1e-15)  # header stamps, exact
    arm_messages = [k + 1 + k // 3 for k in range(len(q))]  # numbers on the topic, the gripper's messages counted
    np.testing.assert_array_equal(rec.rows, arm_messages)
    assert rec.source == f"{bag} [/joint_states]"


def test_without_header_stamps_the_bags_own_times_are_used(tmp_path):
    q, stamps = arm_reach(40)
    log = driver_log("ros2-mcap", q, stamps, PANDA)
    for k in range(len(log)):
        log = edited("ros2-mcap", log, k, stamp_ns=0)
    (rec,) = read_recordings(data_block(files=[str(write_bag(tmp_path / "b", "ros2-mcap", log))]), PANDA)
    np.testing.assert_allclose(rec.t, (stamps - stamps[0]) * 1e-9, rtol=0, atol=1e-15)  # logged 2 ms later, all


def test_a_ros2_bag_directory_is_one_file_to_patterns_and_hashes(tmp_path):
    q, stamps = arm_reach(40)
    for k in (1, 2, 10):
        write_bag(tmp_path / f"episode_{k}", "ros2-sqlite3", driver_log("ros2-sqlite3", q + 0.01 * k, stamps, PANDA))
    block = data_block(files=[str(tmp_path / "episode_*")])
    recs = read_recordings(block, PANDA)
    assert [r.source for r in recs] == [f"{tmp_path / f'episode_{k}'} [/joint_states]" for k in (1, 2, 10)]
    hashes = file_hashes(block)
    metadata = tmp_path / "episode_2" / "metadata.yaml"
    metadata.write_text(metadata.read_text() + "\n")
    changed = file_hashes(block)
    assert [n for n in hashes if hashes[n] != changed[n]] == [str(tmp_path / "episode_2")]


def test_the_topic_is_chosen_where_a_bag_holds_two(tmp_path):
    q, stamps = arm_reach(40)
    log = driver_log("ros1", q, stamps, PANDA) + driver_log("ros1", q + 0.1, stamps, PANDA, "/teleop/joint_states")
    bag = str(write_bag(tmp_path / "two.bag", "ros1", sorted(log, key=lambda m: m[3])))
    with pytest.raises(
        RecordingError,
        match=r"two\.bag: 2 topics of type sensor_msgs/msg/JointState: /joint_states, /teleop/joint_states; name the "
        r"one to read in data\.topic$",
    ):
        read_recordings(data_block(files=[bag]), PANDA)
    (rec,) = read_recordings(data_block(files=[bag], topic="/teleop/joint_states"), PANDA)
    np.testing.assert_array_equal(rec.pos, q + 0.1)


POINT_TYPES = ["geometry_msgs/msg/PoseStamped", "geometry_msgs/msg/PointStamped", "geometry_msgs/msg/TransformStamped"]


def mocap_bag(tmp_path: Path, msgtype: str, kind: str = "ros2-mcap") -> tuple[Path, np.ndarray, np.ndarray]:
    """A tracked pen's handwriting in the plane z = 0.8 m (a motion-capture driver's topic), at irregular stamps."""
    q, stamps = arm_reach(120)
    xyz = np.stack([0.3 * q[:, 3] + 0.6, 0.2 * q[:, 1], np.full(len(q), 0.8)], 1)
    store = typestore(kind)
    log = [("/mocap/pen/pose", msgtype, point_message(store, kind, msgtype, int(s), p), int(s) + 5_000_000)
           for s, p in zip(stamps, xyz)]  # fmt: skip
    return write_bag(bag_path(tmp_path, kind, "pen"), kind, log), xyz, stamps


@pytest.mark.parametrize("msgtype", POINT_TYPES)
def test_a_motion_capture_topic_reads_as_positions_in_the_plane(tmp_path, msgtype):
    bag, xyz, stamps = mocap_bag(tmp_path, msgtype)
    (rec,) = read_recordings(data_block(files=[str(bag)], units="m", columns=["x", "y"]))
    assert rec.columns == ("x", "y") and rec.source == f"{bag} [/mocap/pen/pose]"
    np.testing.assert_array_equal(rec.pos, xyz[:, :2])
    np.testing.assert_allclose(rec.t, (stamps - stamps[0]) * 1e-9, rtol=0, atol=1e-15)
    (every,) = read_recordings(data_block(files=[str(bag)], units="m"))
    np.testing.assert_array_equal(every.pos, xyz)  # x, y, z without data.columns
    with pytest.raises(RecordingError, match=r"pen \[/mocap/pen/pose\]: w \(data\.columns\) is not a coordinate"):
        read_recordings(data_block(files=[str(bag)], units="m", columns=["x", "w"]))


def test_lasa_handwriting_logged_as_motion_capture_reads_as_the_dataset(tmp_path):
    """People's handwriting (LASA's Sshape, 7 demonstrations), each logged as a tracked pen's PoseStamped topic at
    the dataset's own times: on the plane's step grid the bags give the dataset's demonstrations."""
    store = typestore("ros2-mcap")
    msgtype = "geometry_msgs/msg/PoseStamped"
    for k, rec in enumerate(read_lasa("Sshape")):
        stamps = CLOCK_NS + np.round((rec.t - rec.t[0]) * 1e9).astype(np.int64)
        log = [
            ("/pen", msgtype, point_message(store, "ros2-mcap", msgtype, int(s), (*p, 0.0)), int(s))
            for s, p in zip(stamps, rec.pos)
        ]
        write_bag(tmp_path / f"pen_{k}", "ros2-mcap", log)
    bags = data_block(files=[str(tmp_path / "pen_*")], units="m", columns=["x", "y"])
    lasa = RecordedDataConfig.model_validate({"source": "recorded", "format": "lasa", "shape": "Sshape"})
    from_bags, from_dataset = (to_grid(read_recordings(d), d, 0.02) for d in (bags, lasa))
    assert len(from_bags) == len(from_dataset) == 7
    for a, b in zip(from_bags, from_dataset):
        np.testing.assert_allclose(a.q, b.q, rtol=0, atol=1e-9)
        np.testing.assert_allclose(a.goal, b.goal, rtol=0, atol=1e-9)


def test_a_motion_capture_bag_validates_for_the_plane_and_not_for_an_arm(tmp_path):
    bag, _, _ = mocap_bag(tmp_path, POINT_TYPES[0], kind="ros1")
    mine = [
        "experiment=lasa",
        "data=recorded",
        "data.format=rosbag",
        f"data.files=[{bag}]",
        "data.split=all",
        "name=pen",
    ]
    resolve_and_validate(compose_cfg([*mine, "data.columns=[x,y]"]))
    with pytest.raises(
        ConfigError,
        match=r"have 3 coordinates \(read from the columns 'x', 'y', 'z'\) but the environment particle2d has 2",
    ):
        resolve_and_validate(compose_cfg(mine))
    with pytest.raises(RecordingError, match=r"pen\.bag: no topic of type sensor_msgs/msg/JointState; the bag holds "):
        read_recordings(data_block(files=[str(bag)]), PANDA)  # an arm reads joint states only


# ------------------------------------------------------------------------------------------------ bad bags
def test_a_bag_without_joint_states_names_what_it_holds(tmp_path):
    text = typestore("ros2-mcap").types["std_msgs/msg/String"](data="hello")
    bag = str(write_bag(tmp_path / "chatter", "ros2-mcap", [("/chatter", "std_msgs/msg/String", text, 1)]))
    with pytest.raises(RecordingError, match=r"chatter: no topic of type .*JointState; the bag holds /chatter \(std"):
        read_recordings(data_block(files=[bag]), PANDA)
    with pytest.raises(
        RecordingError, match=r"'/chatter' \(data\.topic\) carries std_msgs/msg/String, not .*has none$"
    ):
        read_recordings(data_block(files=[bag], topic="/chatter"), PANDA)
    with pytest.raises(RecordingError, match=r"no topic '/joint_states' \(data\.topic\); the bag holds /chatter"):
        read_recordings(data_block(files=[bag], topic="/joint_states"), PANDA)


def test_a_bag_of_every_topic_lists_the_first_twenty(tmp_path):
    String = typestore("ros1").types["std_msgs/msg/String"]
    log = [(f"/topic_{k:02d}", "std_msgs/msg/String", String(data="x"), k + 1) for k in range(25)]
    bag = str(write_bag(tmp_path / "all.bag", "ros1", log))
    with pytest.raises(RecordingError, match=r"/topic_19 \(std_msgs/msg/String\) and 5 more$"):
        read_recordings(data_block(files=[bag]), PANDA)


def test_another_robots_bag_names_the_joints_it_lacks(tmp_path):
    q, stamps = arm_reach(20)
    ur = [f"wrist_{k}_joint" if j == "panda_joint7" else j for k, j in enumerate(PANDA)]
    bag = str(write_bag(tmp_path / "ur.bag", "ros1", driver_log("ros1", q, stamps, ur)))
    with pytest.raises(
        RecordingError,
        match=r"ur\.bag \[/joint_states\]: no message carries every joint .*never named: panda_joint7.*wrist_6_joint",
    ):
        read_recordings(data_block(files=[bag]), PANDA)


@pytest.mark.parametrize(
    ("fault", "message"),
    [
        ("nan", r"demo \[/joint_states\], message 5, column 'panda_joint3': nan is not a finite number"),
        ("repeated stamp", r"demo \[/joint_states\], message 5, column 't': time .* does not increase"),
        ("short position list", r"demo \[/joint_states\], message 5: the message names 9 joints but holds 8"),
    ],
)
def test_a_bad_message_is_named_by_its_number(tmp_path, fault, message):
    q, stamps = arm_reach(20)
    log = driver_log("ros2-mcap", q, stamps, PANDA)  # message 5 (index 4) is the arm's, after 3 arm and 1 gripper
    names, positions = list(log[4][2].name), np.array(log[4][2].position)
    if fault == "nan":
        positions[names.index("panda_joint3")] = np.nan
        log = edited("ros2-mcap", log, 4, positions=positions)
    elif fault == "repeated stamp":
        log = edited("ros2-mcap", log, 4, stamp_ns=int(stamps[2]))
    else:
        log = edited("ros2-mcap", log, 4, positions=positions[:-1])
    bag = str(write_bag(tmp_path / "demo", "ros2-mcap", log))
    with pytest.raises(RecordingError, match=message):
        read_recordings(data_block(files=[bag]), PANDA)


def test_a_file_that_is_not_a_bag_is_refused(tmp_path):
    (tmp_path / "notes.bag").write_text("t,x\n0,1\n")
    with pytest.raises(RecordingError, match=r"notes\.bag: not a readable ROS bag"):
        read_recordings(data_block(files=[str(tmp_path / "notes.bag")]), PANDA)


def test_without_rosbags_installed_the_fix_is_named(tmp_path, monkeypatch):
    q, stamps = arm_reach(20)
    bag = str(write_bag(tmp_path / "demo", "ros2-mcap", driver_log("ros2-mcap", q, stamps, PANDA)))
    monkeypatch.setitem(sys.modules, "rosbags.highlevel", None)  # as if the optional package were not installed
    with pytest.raises(RecordingError, match=r"needs the rosbags package: pip install -e '\.\[ros\]'"):
        read_recordings(data_block(files=[bag]), PANDA)


def test_a_directory_that_is_not_a_ros2_bag_is_refused(tmp_path):
    (tmp_path / "bags").mkdir()
    with pytest.raises(RecordingError, match=r"bags: a directory without metadata\.yaml, so not a ROS 2 bag.*/\*"):
        read_recordings(data_block(files=[str(tmp_path / "bags")]), PANDA)


def test_settings_a_bag_cannot_honour_are_refused():
    with pytest.raises(ValidationError, match=r"a ROS bag's JointState messages carry no accelerations"):
        data_block(files=["x.bag"], derivatives="file")
    with pytest.raises(ValidationError, match=r"data\.time_units='ms' is not read by format rosbag"):
        data_block(files=["x.bag"], time_units="ms")


# ------------------------------------------------------------------------------------------------ end to end
def test_the_panda_recordings_as_bags_equal_the_csv_on_the_step_grid(tmp_path):
    """The shipped Panda recordings (a planner's, with noise and irregular stamps) logged by the tool to one ROS 2
    bag per demonstration as a driver publishes them: the run's checks pass and every demonstration lands on the
    step grid exactly as from the CSV. The tool refuses to write over a directory that exists."""
    assert main(["--out", str(tmp_path / "bags")]) == 0
    assert main(["--out", str(tmp_path / "bags")]) == 1
    overrides = ["experiment=recorded_arm", "data.format=rosbag", "data.demo_column=null"]
    run = resolve_and_validate(compose_cfg([*overrides, f"data.files=[{tmp_path}/bags/demo*]"]))
    from_csv = resolve_and_validate(compose_cfg(["experiment=recorded_arm"]))
    dt, _ = from_csv.env.integration_step()
    bags, csvs = (to_grid(read_recordings(r.data, PANDA), r.data, dt) for r in (run, from_csv))
    assert len(bags) == len(csvs) == 24
    for a, b in zip(bags, csvs):
        np.testing.assert_allclose(a.q, b.q, rtol=0, atol=1e-9)
        np.testing.assert_allclose(a.qd, b.qd, rtol=0, atol=1e-6)


def rostopic_csv(path: Path, q: np.ndarray, stamps_ns: np.ndarray) -> list[str]:
    """``rostopic echo -p /joint_states > path`` as ROS 1 writes it for a driver publishing the joints last to
    first with the fingers between: ``%time`` (receipt, ns), the header's fields (stamp in ns, an empty frame id),
    then ``field.name<k>``, ``field.position<k>``, ``field.velocity<k>``, ``field.effort<k>`` per joint. Returns the
    position columns that hold the Panda's joints in the robot's order."""
    order = [*PANDA[:1:-1], "panda_finger_joint1", "panda_finger_joint2", *PANDA[1::-1]]
    n = len(order)
    header = ["%time", "field.header.seq", "field.header.stamp", "field.header.frame_id"]
    header += [f"field.{part}{k}" for part in ("name", "position", "velocity", "effort") for k in range(n)]
    lines = [",".join(header)]
    for seq, (row, stamp) in enumerate(zip(q, stamps_ns)):
        values = dict(zip(PANDA, row)) | {"panda_finger_joint1": 0.04, "panda_finger_joint2": 0.04}
        cells = [str(int(stamp) + 2_000_000), str(seq), str(int(stamp)), ""]
        cells += [*order, *(repr(float(values[j])) for j in order), *["0.0"] * n, *["0.0"] * n]
        lines.append(",".join(cells))
    path.write_text("\n".join(lines) + "\n")
    return [f"field.position{order.index(j)}" for j in PANDA]


def test_a_rostopic_echo_csv_of_joint_states_reads_with_its_columns_named(tmp_path):
    """The other way ROS 1 users keep joint states: ``rostopic echo -p`` CSV, one file per demonstration, names in
    the driver's order and strings beside the numbers. Naming the stamp column (ns) and the position columns in
    the robot's order reads it as the bag is read; left to guess the columns, the first one that is not a number
    is named with the fix."""
    q, stamps = arm_reach()
    columns = rostopic_csv(tmp_path / "demo0.csv", q, stamps)
    bag = bag_path(tmp_path, "ros1")
    write_bag(bag, "ros1", driver_log("ros1", q, stamps, PANDA))
    (from_csv,) = read_recordings(
        data_block(
            format="csv",
            files=[str(tmp_path / "demo0.csv")],
            time_column="field.header.stamp",
            time_units="ns",
            columns=columns,
        ),
        PANDA,
    )
    (from_bag,) = read_recordings(data_block(files=[str(bag)]), PANDA)
    np.testing.assert_array_equal(from_csv.pos, from_bag.pos)
    np.testing.assert_allclose(from_csv.t - from_csv.t[0], from_bag.t - from_bag.t[0], rtol=0, atol=1e-6)
    with pytest.raises(
        RecordingError,
        match=r"demo0\.csv, row 2, column 'field\.header\.frame_id': the cell is empty .*unless data\.columns lists",
    ):
        read_recordings(
            data_block(
                format="csv", files=[str(tmp_path / "demo0.csv")], time_column="field.header.stamp", time_units="ns"
            ),
            PANDA,
        )


def test_a_whole_teaching_session_in_one_bag_is_cut_into_its_demonstrations(tmp_path):
    """The shipped Panda recordings published as one teaching session (tests/sessions.py: the arm held, returned
    to the next start, held, the driver publishing on): one bag, one recording uncut; cut at rests of 1 s keeping the
    odd motions (data.keep_motions), 24 pieces, each holding every message of one demonstration and none of
    another."""
    t, q, owner = panda_session()
    ns = CLOCK_NS + np.round(t * 1e9).astype(np.int64)
    bag = write_bag(bag_path(tmp_path, "ros1", "session"), "ros1", driver_log("ros1", q, ns, PANDA))
    assert len(read_recordings(data_block(files=[str(bag)]), PANDA)) == 1
    pieces = read_recordings(data_block(files=[str(bag)], cut_at_rest=1.0, keep_motions="odd"), PANDA)
    assert len(pieces) == 24 and "(motion 47 of 47, from t=" in pieces[-1].source
    demos = shipped_demonstrations()
    for piece, name in zip(pieces, demos):
        first = int(np.searchsorted(ns, round(piece.t[0] * 1e9) + CLOCK_NS - 1))  # the piece's first message
        mine = owner[first : first + len(piece.t)]
        assert set(mine) - {None} == {name} and mine.count(name) == len(demos[name][0]), piece.source


# ------------------------------------------------------------------------------------------------ aux from a topic
def tracked_cylinder(store, kind: str, stamps: np.ndarray, centre, noise: float, seed: int = 0) -> list:
    """A motion-capture system's pose of the cylinder at 120 Hz over ``stamps``' span, with tracking noise (m)."""
    rng = np.random.default_rng(seed)
    ticks = np.arange(int(stamps[0]), int(stamps[-1]), 8_333_333)
    xyz = np.asarray(centre) + rng.normal(0.0, noise, (len(ticks), 3))
    kind_type = "geometry_msgs/msg/PoseStamped"
    return [("/mocap/cylinder/pose", kind_type, point_message(store, kind, kind_type, int(s), p), int(s))
            for s, p in zip(ticks, xyz)]  # fmt: skip


def test_where_a_tracked_obstacle_stood_is_read_from_its_topic(tmp_path):
    """The moved-cylinder recordings (each demonstration's cylinder in columns ox, oy, oz) logged as bags with the
    cylinder tracked by motion capture (0.2 mm of noise): data.aux_topics reads each bag's cylinder as the CSV's
    columns give it, to the tracking noise, and the run validates; a cylinder moved mid-demonstration is refused
    at the message, and a topic that is not a point is refused by its type."""
    import csv

    with open(ROOT / "rmpfusion" / "recordings" / "files" / "panda_moved_cylinder.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    demos: dict[str, list[dict]] = {}
    for r in rows:
        demos.setdefault(r["demo"], []).append(r)
    store, centres = typestore("ros2-mcap"), {}
    for name in list(demos)[:3]:
        t = np.array([float(r["t"]) for r in demos[name]])
        q = np.array([[float(r[j]) for j in PANDA] for r in demos[name]])
        ns = CLOCK_NS + np.round((t - t[0]) * 1e9).astype(np.int64)
        centres[name] = [float(demos[name][0][c]) for c in ("ox", "oy", "oz")]
        log = driver_log("ros2-mcap", q, ns, PANDA) + tracked_cylinder(store, "ros2-mcap", ns, centres[name], 2e-4)
        write_bag(tmp_path / name, "ros2-mcap", sorted(log, key=lambda m: m[3]))
    aux = {"obstacle1_center": "/mocap/cylinder/pose"}
    recs = read_recordings(data_block(files=[str(tmp_path / "demo*")], topic="/joint_states", aux_topics=aux), PANDA)
    for rec, name in zip(recs, centres):
        np.testing.assert_allclose(rec.aux["obstacle1_center"], centres[name], rtol=0, atol=5e-5)
    overrides = ["experiment=recorded_arm", "learned_leaves=arm_reach", "obstacle_weight=constant",
                 "data=panda_moved_cylinder", "data.format=rosbag", "data.demo_column=null", "data.aux_columns=null",
                 "data.val=1", "data.test=1", f"data.files=[{tmp_path}/demo*]", "data.topic=/joint_states",
                 "data.aux_topics={obstacle1_center: /mocap/cylinder/pose}"]  # fmt: skip
    run = resolve_and_validate(compose_cfg(overrides))
    assert run.data.aux_topics == aux
    t = np.array([float(r["t"]) for r in demos["demo00"]])
    ns = CLOCK_NS + np.round((t - t[0]) * 1e9).astype(np.int64)
    q = np.array([[float(r[j]) for j in PANDA] for r in demos["demo00"]])
    track = tracked_cylinder(store, "ros2-mcap", ns, centres["demo00"], 2e-4)
    for k in range(len(track) // 2, len(track)):  # pushed 2 cm along x halfway through
        pose = track[k][2]
        pose.pose.position.x += 0.02
    write_bag(
        tmp_path / "bumped", "ros2-mcap", sorted(driver_log("ros2-mcap", q, ns, PANDA) + track, key=lambda m: m[3])
    )
    with pytest.raises(RecordingError, match=r"bumped \[/mocap/cylinder/pose\], message \d+: the point is 1\d\.\d mm "
                       r"from where it stands on average .* it moved during the demonstration"):  # fmt: skip
        read_recordings(data_block(files=[str(tmp_path / "bumped")], topic="/joint_states", aux_topics=aux), PANDA)
    with pytest.raises(
        RecordingError, match=r"the topic '/joint_states' \(data\.aux_topics\) carries sensor_msgs/msg/Joint"
    ):
        read_recordings(
            data_block(files=[str(tmp_path / "bumped")], aux_topics={"obstacle1_center": "/joint_states"}), PANDA
        )
