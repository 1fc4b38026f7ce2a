"""A whole teaching session in one log, cut into its demonstrations at the rests between them
(``data.cut_at_rest``, ``data.keep_motions``): the pieces are exactly the motions' samples, a pause shorter than the
setting is no cut, the shipped Panda recordings logged as one session with the arm's returns between them come apart
into the 24 they were, and demonstrations logged back to back without the return are refused as a jump."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import compose_cfg
from pydantic import ValidationError
from sessions import panda_session, shipped_demonstrations

from rmpfusion.assembly.errors import ConfigError
from rmpfusion.cli.validate import summary
from rmpfusion.pipeline.config import RecordedDataConfig
from rmpfusion.pipeline.construct import build_all
from rmpfusion.pipeline.validate import resolve_and_validate
from rmpfusion.recordings import RecordingError
from rmpfusion.recordings.signals import runs, without_short_runs
from rmpfusion.recordings.source import read_recordings

RATE = 100.0


def reach(start, end, seconds: float) -> np.ndarray:
    """A minimum-jerk reach sampled at RATE."""
    s = np.linspace(0.0, 1.0, int(seconds * RATE) + 1)[:, None]
    return np.asarray(start) + (np.asarray(end) - np.asarray(start)) * (10 * s**3 - 15 * s**4 + 6 * s**5)


def hold(at, seconds: float) -> np.ndarray:
    return np.repeat(np.asarray(at, dtype=float)[None], int(seconds * RATE), axis=0)


def session(rests=(2.0, 2.0)) -> tuple[np.ndarray, list[slice]]:
    """Three reaches in the plane with the given rests between them (and 1 s at either end), and the rows of
    each reach."""
    points = [(0.0, 0.0), (0.1, 0.05), (0.0, 0.1), (0.1, 0.0)]
    parts, where, at = [hold(points[0], 1.0)], [], int(RATE)
    for k in range(3):
        motion = reach(points[k], points[k + 1], 1.5)
        parts.append(motion)
        where.append(slice(at, at + len(motion)))
        at += len(motion)
        rest = hold(points[k + 1], rests[k] if k < 2 else 1.0)
        parts.append(rest)
        at += len(rest)
    return np.concatenate(parts), where


def write(path, pos: np.ndarray, seed: int = 0) -> np.ndarray:
    """``pos`` with 0.1 mm of noise at jittered stamps (about RATE), as a CSV without a demonstration column."""
    rng = np.random.default_rng(seed)
    t = np.cumsum(np.r_[0.0, 1 / RATE + rng.uniform(-2e-3, 2e-3, len(pos) - 1)])
    noisy = pos + rng.normal(0.0, 1e-4, pos.shape)
    path.write_text("t,x,y\n" + "".join(f"{a!r},{b!r},{c!r}\n" for a, (b, c) in zip(t.tolist(), noisy.tolist())))
    return noisy


def block(path, **keys) -> RecordedDataConfig:
    return RecordedDataConfig.model_validate({"source": "recorded", "format": "csv", "files": [str(path)], **keys})


def test_runs_are_found_whole_and_short_ones_dropped():
    mask = np.array([1, 1, 0, 0, 1, 0, 1, 1, 1], bool)
    assert runs(mask) == [(0, 1), (4, 4), (6, 8)]
    assert runs(np.zeros(4, bool)) == []
    assert runs(without_short_runs(mask, 2)) == [(0, 1), (6, 8)]


def test_a_session_is_cut_into_its_motions_in_the_middle_of_each_rest(tmp_path):
    pos, motions = session()
    noisy = write(tmp_path / "session.csv", pos)
    whole = read_recordings(block(tmp_path / "session.csv"))
    assert len(whole) == 1
    pieces = read_recordings(block(tmp_path / "session.csv", cut_at_rest=1.0))
    assert [p.source.split("(")[1].split(",")[0] for p in pieces] == ["motion 1 of 3", "motion 2 of 3", "motion 3 of 3"]
    rows = np.concatenate([p.rows for p in pieces])
    np.testing.assert_array_equal(rows, np.arange(len(pos)) + 2)  # every sample in exactly one piece, in order
    for piece, motion in zip(pieces, motions):
        first, last = int(piece.rows[0]) - 2, int(piece.rows[-1]) - 2
        assert first < motion.start and motion.stop <= last  # the whole motion, with rest on both sides ...
        np.testing.assert_array_equal(piece.pos, noisy[first : last + 1])  # ... samples exactly as recorded
    cut = int(pieces[1].rows[0]) - 2  # the first cut: near the middle of the 2 s rest (2 s = 200 samples)
    assert abs(cut - (motions[0].stop + 100)) <= 3


def test_a_pause_shorter_than_the_setting_is_not_a_cut(tmp_path):
    pos, _ = session(rests=(2.0, 0.5))
    write(tmp_path / "session.csv", pos)
    assert len(read_recordings(block(tmp_path / "session.csv", cut_at_rest=1.0))) == 2
    assert len(read_recordings(block(tmp_path / "session.csv", cut_at_rest=0.3))) == 3


def write_session(path, t: np.ndarray, q: np.ndarray) -> None:
    joints = ",".join(f"panda_joint{k}" for k in range(1, 8))
    path.write_text(
        f"t,{joints}\n" + "".join(",".join(map(repr, [a, *b])) + "\n" for a, b in zip(t.tolist(), q.tolist()))
    )


def test_a_panda_session_comes_apart_into_its_24_demonstrations(tmp_path):
    """The shipped recordings (a planner's, 1 mrad of noise, irregular stamps) logged as one teaching session
    (tests/sessions.py: held 2 s, returned to the next start in 3 s, held 2 s) and written as one CSV. Cut at rests
    of 1 s it is 47 motions, demonstrations and returns in turn; the 23 returns, straight through the joint space,
    pass through the experiment's cylinder, which validation refuses; keeping the odd ones, each piece holds exactly
    one demonstration's samples, all of them, and the run validates with the 24."""
    t, q, owner = panda_session()
    write_session(tmp_path / "session.csv", t, q)
    keys = ["experiment=recorded_arm", f"data.files=[{tmp_path / 'session.csv'}]", "data.demo_column=null"]
    cut = [*keys, "data.cut_at_rest=1.0"]
    with pytest.raises(
        ConfigError, match=r"data\.obstacle_entries: 23 of 47 recordings enter an obstacle of the run's world"
    ):
        resolve_and_validate(compose_cfg(cut))
    every_motion = resolve_and_validate(compose_cfg([*cut, "data.obstacle_entries=warn"]))
    assert len(read_recordings(every_motion.data)) == 47
    run = resolve_and_validate(compose_cfg([*cut, "data.keep_motions=odd"]))
    assert "cut at every rest of 1 s or more: 24 demonstrations" in summary(run, *build_all(run))  # rmpfusion-validate
    pieces = read_recordings(run.data)
    demos = shipped_demonstrations()
    assert len(pieces) == 24 and "(motion 47 of 47, from t=" in pieces[-1].source
    for piece, name in zip(pieces, demos):
        mine = [owner[int(r) - 2] for r in piece.rows]
        assert set(mine) - {None} == {name} and mine.count(name) == len(demos[name][0]), piece.source
    with pytest.raises(ConfigError, match=r"cannot split 1 demonstration\(s\) into 4 validation"):
        resolve_and_validate(compose_cfg(keys))  # uncut, the session is one demonstration


def test_demonstrations_logged_back_to_back_without_the_return_are_a_jump(tmp_path):
    """Without the return between them (the next demonstration starting where the last one's start is, a moment
    after its end), the joints would move at tens of rad/s: refused at the row where they jump, naming the joint
    and its velocity limit, rather than trimmed into a sliver around the jump."""
    demos = list(shipped_demonstrations().values())
    (t0, q0), (t1, q1) = demos[0], demos[1]
    t = np.concatenate([t0 - t0[0], t1 - t1[0] + (t0[-1] - t0[0]) + 0.01])
    write_session(tmp_path / "jump.csv", t, np.concatenate([q0, q1]))
    keys = ["experiment=recorded_arm", f"data.files=[{tmp_path / 'jump.csv'}]", "data.demo_column=null"]
    with pytest.raises(ConfigError, match=rf"jump\.csv, row {len(t0) + 2}, column 'panda_joint\d': panda_joint\d moves "
                       r"[-+].* rad in .* ms from the sample before, over 2 times its velocity limit of .* a jump in the recording"):  # fmt: skip
        resolve_and_validate(compose_cfg(keys))


def test_keeping_motions_needs_cutting_and_a_motion_to_keep(tmp_path):
    with pytest.raises(ValidationError, match=r"data\.keep_motions=odd chooses among .* data\.cut_at_rest is not set"):
        RecordedDataConfig.model_validate(
            {"source": "recorded", "format": "csv", "files": ["a.csv"], "keep_motions": "odd"}
        )
    pos, _ = session()
    write(tmp_path / "session.csv", pos)
    assert len(read_recordings(block(tmp_path / "session.csv", cut_at_rest=1.0, keep_motions="even"))) == 1
    with pytest.raises(RecordingError, match=r"data\.keep_motions=even: no recording has a motion 2"):
        read_recordings(block(tmp_path / "session.csv", cut_at_rest=5.0, keep_motions="even"))


def test_cutting_is_refused_where_it_cannot_apply():
    with pytest.raises(ValidationError, match=r"data\.cut_at_rest=1\.0 is not read by format lasa"):
        RecordedDataConfig.model_validate({"source": "recorded", "format": "lasa", "shape": "Angle", "cut_at_rest": 1})
    with pytest.raises(ValidationError, match=r"cut_at_rest\n.*greater than 0"):
        RecordedDataConfig.model_validate({"source": "recorded", "format": "csv", "files": ["a.csv"], "cut_at_rest": 0})
