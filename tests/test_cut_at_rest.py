"""A whole teaching session in one log, cut into its demonstrations at the rests between them
(``data.cut_at_rest``): the pieces are exactly the motions' samples, a pause shorter than the setting is no cut, and
the shipped Panda recordings logged back to back as one session come apart into the 24 they were."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import compose_cfg
from pydantic import ValidationError

from rmpfusion.assembly.errors import ConfigError
from rmpfusion.pipeline.config import RecordedDataConfig
from rmpfusion.pipeline.validate import resolve_and_validate
from rmpfusion.recordings.cutting import rest_runs
from rmpfusion.recordings.source import SHIPPED_DIR, read_recordings

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


def test_rest_runs_are_found_whole():
    assert rest_runs(np.array([1, 1, 0, 0, 1, 0, 1, 1, 1], bool)) == [(0, 1), (4, 4), (6, 8)]
    assert rest_runs(np.zeros(4, bool)) == []


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


def test_the_panda_recordings_back_to_back_come_apart_into_the_24(tmp_path):
    """The shipped recordings (a planner's, 1 mrad of noise, irregular stamps) logged as one session: each
    demonstration's samples on one clock, the arm held for 2 s between them (noisy, as encoders read at rest),
    written without a demonstration column. Cut at rests of 1 s, each piece holds exactly one demonstration's
    samples, and the run validates with 24 demonstrations."""
    import csv

    with open(SHIPPED_DIR / "panda_via_points.csv", newline="") as fh:
        rows = list(csv.reader(fh))
    header, body = rows[0], rows[1:]
    demos: dict[str, list[list[float]]] = {}
    for r in body:
        demos.setdefault(r[0], []).append([float(v) for v in r[1:]])
    rng = np.random.default_rng(1)
    lines, owner, clock = [",".join(header[1:])], [], 0.0
    for name, samples in demos.items():
        arr = np.asarray(samples)
        t = arr[:, 0] - arr[0, 0] + clock
        lines += [",".join(repr(v) for v in (tk, *q)) for tk, q in zip(t.tolist(), arr[:, 1:].tolist())]
        owner += [name] * len(arr)
        held = arr[-1, 1:] + rng.normal(0.0, 1e-3, (200, arr.shape[1] - 1))
        lines += [",".join(repr(v) for v in (float(t[-1]) + 0.01 * (k + 1), *q)) for k, q in enumerate(held.tolist())]
        owner += [None] * 200
        clock = t[-1] + 2.01
    path = tmp_path / "session.csv"
    path.write_text("\n".join(lines) + "\n")
    keys = ["experiment=recorded_arm", f"data.files=[{path}]", "data.demo_column=null", "data.cut_at_rest=1.0"]
    run = resolve_and_validate(compose_cfg(keys))
    pieces = read_recordings(run.data)
    assert len(pieces) == 24
    for piece, name in zip(pieces, demos):
        held = {owner[int(r) - 2] for r in piece.rows} - {None}
        assert held == {name}, (piece.source, held)
        assert sum(owner[int(r) - 2] == name for r in piece.rows) == len(demos[name])  # all of its samples
    with pytest.raises(ConfigError, match=r"cannot split 1 demonstration\(s\) into 4 validation"):
        resolve_and_validate(compose_cfg(keys[:-1]))  # uncut, the session is one demonstration


def test_cutting_is_refused_where_it_cannot_apply():
    with pytest.raises(ValidationError, match=r"data\.cut_at_rest=1\.0 is not read by format lasa"):
        RecordedDataConfig.model_validate({"source": "recorded", "format": "lasa", "shape": "Angle", "cut_at_rest": 1})
    with pytest.raises(ValidationError, match=r"cut_at_rest\n.*greater than 0"):
        RecordedDataConfig.model_validate({"source": "recorded", "format": "csv", "files": ["a.csv"], "cut_at_rest": 0})
