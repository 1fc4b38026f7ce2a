"""Recordings as other tools write them: spreadsheets' delimiters and byte-order marks, pandas' index column, time
stamps in milliseconds or nanoseconds, the file's own derivatives, ragged NPZ arrays, HDF5 files with time stamps,
statistics beside the demonstrations or another group name; and every way a data block could silently read
something other than what its user meant (a key the format ignores, angles on a plane, one demonstration for three
splits) refused with the key and the fix."""

from __future__ import annotations

import re
import subprocess
import sys

import numpy as np
import pytest
from conftest import ROOT, compose_cfg
from pydantic import ValidationError

from rmpfusion.assembly.errors import ConfigError
from rmpfusion.cli.rundir import RunDirError, check_same_recordings, save_recordings
from rmpfusion.pipeline.config import RecordedDataConfig
from rmpfusion.pipeline.validate import resolve_and_validate
from rmpfusion.recordings import RecordingError, read_csv, read_hdf5, read_npz
from rmpfusion.recordings.source import file_hashes, read_recordings, source_file, to_grid

#: a minimum-jerk reach in the plane (m) over 2 s at 100 Hz with rest at either end, and its exact derivatives
T = np.arange(0, 2.6, 0.01)
S = np.clip((T - 0.3) / 2.0, 0.0, 1.0)
REACH = np.stack([0.1 - 0.1 * (10 * S**3 - 15 * S**4 + 6 * S**5), 0.05 * (10 * S**3 - 15 * S**4 + 6 * S**5)], 1)


def csv_text(rows: list[list], header: list[str], sep: str = ",") -> str:
    return sep.join(header) + "\n" + "\n".join(sep.join(str(v) for v in r) for r in rows) + "\n"


def reach_rows(t_factor: float = 1.0, demo: str | None = None) -> list[list]:
    return [[*([demo] if demo else []), t * t_factor, *p] for t, p in zip(T, REACH)]


def data_block(**keys) -> RecordedDataConfig:
    return RecordedDataConfig.model_validate({"source": "recorded", **keys})


# ------------------------------------------------------------------------------------------------ CSV dialects
@pytest.mark.parametrize(
    ("sep", "encoding"), [(";", "utf-8"), ("\t", "utf-8"), (",", "utf-8-sig")], ids=["semicolon", "tab", "bom"]
)
def test_a_spreadsheets_csv_reads_like_a_plain_one(tmp_path, sep, encoding):
    path = tmp_path / "sheet.csv"
    path.write_text(csv_text(reach_rows(demo="d0"), ["demo", "t", "x", "y"], sep), encoding=encoding)
    (rec,) = read_csv(path, demo_column="demo")
    assert rec.columns == ("x", "y")
    np.testing.assert_allclose(rec.pos, REACH)


@pytest.mark.parametrize(
    ("time_name", "fix"),
    [("time", "; set data.time_column=time"), ("%time", "; set data.time_column=%time"), ("clock", "")],
)
def test_a_time_column_under_another_name_is_named_with_its_fix(tmp_path, time_name, fix):
    path = tmp_path / "log.csv"
    path.write_text(csv_text(reach_rows(), [time_name, "x", "y"]))
    expected = f"log.csv, row 1: the header has no time column 't' (data.time_column); it has {time_name}, x, y{fix}"
    with pytest.raises(RecordingError, match=re.escape(expected) + "$"):
        read_csv(path)
    assert read_csv(path, time_column=time_name)[0].dim == 2


def test_pandas_index_column_is_refused_not_read_as_a_coordinate(tmp_path):
    path = tmp_path / "pandas.csv"
    path.write_text(csv_text([[k, *r] for k, r in enumerate(reach_rows())], ["", "t", "x", "y"]))
    with pytest.raises(RecordingError, match=r"pandas\.csv, row 1: column 1 of the header has no name.*index=False"):
        read_csv(path)
    assert read_csv(path, columns=["x", "y"])[0].dim == 2  # naming the coordinates reads past it


def test_a_decimal_comma_and_an_extra_column_get_their_fix(tmp_path):
    path = tmp_path / "comma.csv"
    path.write_text("t;x\n0;0,5\n0,01;0,6\n")
    with pytest.raises(RecordingError, match=r"comma\.csv, row 3, column 't': '0,01' is not a number; a decimal comma"):
        read_csv(path)
    path = tmp_path / "extra.csv"
    path.write_text("t,x,y,gripper\n0,0,0,open\n0.01,0,0,open\n")
    with pytest.raises(
        RecordingError, match=r"column 'gripper': 'open' is not a number; every column but time is read"
    ):
        read_csv(path)


def test_several_demonstrations_without_their_column_get_the_fix(tmp_path):
    """Two reaches one after the other in one file: the clock restarting, or a pause between them, is refused
    naming data.demo_column or where to cut, never trained on as one demonstration with a jump."""
    restart = tmp_path / "restart.csv"
    restart.write_text(csv_text(reach_rows() + reach_rows(), ["t", "x", "y"]))
    with pytest.raises(RecordingError, match=r"does not increase.*data\.demo_column"):
        read_csv(restart)
    paused = tmp_path / "paused.csv"
    second = [[t + 10.0, *p] for t, *p in reach_rows()]
    paused.write_text(csv_text(reach_rows() + second, ["t", "x", "y"]))
    with pytest.raises(RecordingError, match=rf"paused\.csv, row {len(T) + 2}, column 't': .* without a sample"):
        read_csv(paused)


# ------------------------------------------------------------------------------------------------ time units
def test_milliseconds_read_with_their_unit_equal_seconds_and_without_it_are_refused(tmp_path):
    seconds, millis = tmp_path / "s.csv", tmp_path / "ms.csv"
    seconds.write_text(csv_text(reach_rows(), ["t", "x", "y"]))
    millis.write_text(csv_text(reach_rows(1000.0), ["t", "x", "y"]))
    (a,) = read_recordings(data_block(format="csv", files=[str(seconds)]))
    (b,) = read_recordings(data_block(format="csv", files=[str(millis)], time_units="ms"))
    np.testing.assert_allclose(a.t, b.t, atol=1e-12)
    with pytest.raises(RecordingError, match=r"ms\.csv: lasts 2590 s with its time stamps read in s.*data\.time_units"):
        read_recordings(data_block(format="csv", files=[str(millis)]))


def test_nanosecond_epoch_stamps_read_with_their_unit(tmp_path):
    path = tmp_path / "ns.npz"
    np.savez(path, t=(1_700_000_000_000_000_000 + T * 1e9).astype(np.int64), pos=REACH)
    (rec,) = read_recordings(data_block(format="npz", files=[str(path)], time_units="ns"))
    np.testing.assert_allclose(rec.t - rec.t[0], T, atol=1e-6)


# ------------------------------------------------------------------------------------------------ file derivatives
def test_the_files_own_derivatives_are_read_in_si_and_used(tmp_path):
    """Velocities and accelerations given in mm/ms and mm/ms² (the file's units): converted to m/s and m/s²; the
    file's velocities are twice the positions' true rate, and the grid keeps the file's (a filter would not)."""
    s = np.clip((T - 0.3) / 2.0, 0.0, 1.0)
    ds = np.where((T > 0.3) & (T < 2.3), 0.5, 0.0)
    vel = np.outer((30 * s**2 - 60 * s**3 + 30 * s**4) * ds, [-0.1, 0.05])
    acc = np.outer((60 * s - 180 * s**2 + 120 * s**3) * ds**2, [-0.1, 0.05])
    vel *= 2.0
    rows = [[t * 1e3, *(1e3 * p), *(v * 1e3 / 1e3), *(a * 1e3 / 1e6)] for t, p, v, a in zip(T, REACH, vel, acc)]
    path = tmp_path / "derivs.csv"
    path.write_text(csv_text(rows, ["t", "x", "y", "vx", "vy", "ax", "ay"]))
    d = data_block(
        format="csv",
        files=[str(path)],
        units="mm",
        time_units="ms",
        velocity_columns=["vx", "vy"],
        acceleration_columns=["ax", "ay"],
        derivatives="file",
    )
    (rec,) = read_recordings(d)
    assert rec.columns == ("x", "y")
    np.testing.assert_allclose(rec.vel, vel, atol=1e-12)
    np.testing.assert_allclose(rec.acc, acc, atol=1e-12)
    (states,) = to_grid([rec], d, dt=0.02)
    np.testing.assert_allclose(np.abs(states.qd).max(axis=0), [0.1875, 0.09375], rtol=1e-3)  # 2 x the true peak


def test_file_derivatives_without_their_keys_are_refused():
    with pytest.raises(ValidationError, match=r"data\.velocity_columns and data\.acceleration_columns"):
        data_block(format="csv", files=["x.csv"], derivatives="file")
    with pytest.raises(ValidationError, match=r"data\.acceleration_key, or use data\.derivatives=filter"):
        data_block(format="hdf5", files=["x.hdf5"], rate=10.0, derivatives="file", velocity_key="obs/vel")


# ------------------------------------------------------------------------------------------------ NPZ
def test_ragged_npz_arrays_are_refused_naming_the_layouts(tmp_path):
    path = tmp_path / "ragged.npz"
    ragged = np.empty(2, dtype=object)
    ragged[0], ragged[1] = T, T[:100]
    np.savez(path, t=ragged, pos=ragged)
    with pytest.raises(RecordingError, match=r"ragged\.npz: the array 't' is stored as Python objects.*one per file"):
        read_npz(path)


# ------------------------------------------------------------------------------------------------ HDF5
@pytest.fixture
def h5py():
    return pytest.importorskip("h5py", reason="h5py reads HDF5 recordings (a run-time dependency)")


def test_hdf5_time_stamps_are_read_and_never_replaced_by_a_rate(tmp_path, h5py):
    path = tmp_path / "stamped.hdf5"
    with h5py.File(path, "w") as fh:
        fh.create_dataset("episodes/ep_0/pos", data=REACH)
        fh.create_dataset("episodes/ep_0/t", data=T * 2.0)  # a 50 Hz clock
        fh.create_dataset("episodes/stats", data=np.zeros(3))  # not a demonstration
    (rec,) = read_recordings(data_block(format="hdf5", files=[str(path)], group="episodes"))
    np.testing.assert_allclose(rec.t, T * 2.0)
    with pytest.raises(RecordingError, match=r"holds time stamps, but data\.rate=100\.0 would replace them"):
        read_recordings(data_block(format="hdf5", files=[str(path)], group="episodes", rate=100.0))
    with pytest.raises(RecordingError, match=r"no group 'data' \(data\.group\); top level holds episodes"):
        read_hdf5(path, "pos", time_key="t")


def test_hdf5_keys_that_miss_list_what_the_group_holds(tmp_path, h5py):
    path = tmp_path / "robomimic.hdf5"
    with h5py.File(path, "w") as fh:
        fh.create_dataset("data/demo_0/obs/robot0_eef_pos", data=np.zeros((10, 3)))
        fh.create_dataset("data/demo_0/actions", data=np.zeros((10, 7)))
    with pytest.raises(RecordingError, match=r"no dataset 'pos' \(data\.position_key\); the group holds actions, obs/"):
        read_hdf5(path, "pos", rate=20.0)
    with pytest.raises(RecordingError, match=r"'obs' is a group, not a dataset .*robot0_eef_pos"):
        read_hdf5(path, "obs", rate=20.0)


def write_episodes(folder, h5py, count: int) -> None:
    """ALOHA's and ACT's layout: one episode per file, ``observations/qpos`` at the top level, no time stamps (the
    rate is the recorder's), the reach slowed down k-fold in episode_k so each file is told apart."""
    folder.mkdir()
    for k in range(count):
        with h5py.File(folder / f"episode_{k}.hdf5", "w") as fh:
            fh.attrs["sim"] = True
            fh.create_dataset("observations/qpos", data=np.repeat(REACH, k + 1, axis=0))
            fh.create_dataset("action", data=np.repeat(REACH, k + 1, axis=0))


def test_one_episode_per_file_named_by_a_pattern_reads_in_recording_order(tmp_path, h5py, monkeypatch):
    write_episodes(tmp_path / "episodes", h5py, 11)
    monkeypatch.chdir(tmp_path)
    block = data_block(
        format="hdf5", files=["episodes/episode_*.hdf5"], group=None, position_key="observations/qpos", rate=100.0
    )
    recs = read_recordings(block)
    assert [r.source for r in recs] == [f"episodes/episode_{k}.hdf5" for k in range(11)]  # 2 before 10
    for k, rec in enumerate(recs):
        assert rec.pos.shape == (REACH.shape[0] * (k + 1), 2)
        np.testing.assert_allclose(rec.t[1], 0.01)  # the rate, as no stamps are stored
    hashes = file_hashes(block)
    assert list(hashes) == [f"episodes/episode_{k}.hdf5" for k in range(11)]  # what a run directory records
    with pytest.raises(
        RecordingError,
        match=r"no group 'data' \(data\.group\); top level holds action, observations.*"
        r"data\.group=null",
    ):
        read_recordings(block.model_copy(update={"group": "data"}))
    with pytest.raises(RecordingError, match=r"episodes/epsode_\*\.hdf5: no file matches this pattern \(data\.files\)"):
        read_recordings(block.model_copy(update={"files": ["episodes/epsode_*.hdf5"]}))


def test_a_binary_file_read_as_csv_and_a_directory_say_what_they_are(tmp_path):
    np.savez(tmp_path / "demos.npz", t=T, pos=REACH)
    with pytest.raises(RecordingError, match=r"demos\.npz: not a text CSV file.*data\.format=npz or hdf5"):
        read_csv(tmp_path / "demos.npz")
    with pytest.raises(
        RecordingError, match=r"a directory \(data\.files\); name the recorded files in it.*with a pattern"
    ):
        source_file(str(tmp_path))


# ------------------------------------------------------------------------------------------------ the run directory
def test_a_changed_recording_is_not_resumed_as_the_run_that_learned_from_the_old_one(tmp_path):
    path = tmp_path / "demos.csv"
    path.write_text(csv_text(reach_rows(), ["t", "x", "y"]))
    d = data_block(format="csv", files=[str(path)])
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    save_recordings(file_hashes(d), run_dir)
    check_same_recordings(file_hashes(d), run_dir)  # unchanged: the run resumes
    path.write_text(csv_text(reach_rows()[:-1], ["t", "x", "y"]))
    with pytest.raises(RunDirError, match=rf"learned from another version of {path}.*put the recording back"):
        check_same_recordings(file_hashes(d), run_dir)


# ------------------------------------------------------------------------------------------------ the data block
def test_one_file_may_be_given_without_brackets():
    assert data_block(format="csv", files="a.csv").files == ["a.csv"]


@pytest.mark.parametrize(
    ("keys", "message"),
    [
        (
            {"format": "lasa", "shape": "Angle", "files": ["mine.csv"]},
            r"data\.files=\['mine\.csv'\] is not read by format lasa",
        ),
        (
            {"format": "csv", "files": ["a.csv"], "rate": 100.0},
            r"data\.rate=100\.0 is not read by format csv \(read by: hdf5\)",
        ),
        (
            {"format": "npz", "files": ["a.npz"], "demo_column": "demo"},
            r"data\.demo_column='demo' is not read by format npz",
        ),
        ({"format": "lasa", "shape": "Angle", "units": "mm"}, r"data\.units='mm' is not read by format lasa"),
        ({"format": "csv", "files": ["a.csv"], "test": 0}, r"test\n.*greater than or equal to 1"),
        (
            {"format": "csv", "files": ["a.csv"], "split": "leave_one_out", "val": 3},
            r"data\.val=3 is not read by split leave_one_out",
        ),
        (
            {"format": "csv", "files": ["a.csv"], "fold": 2},
            r"data\.fold=2 is not read by split holdout .*set data\.fold=0",
        ),
        ({"format": "csv", "files": ["a.csv"], "rest_fraction": 0.95}, r"rest_fraction\n.*less than or equal to 0\.25"),
    ],
)
def test_a_key_the_format_ignores_is_refused(keys, message):
    with pytest.raises(ValidationError, match=message):
        data_block(**keys)


def test_a_lasa_run_given_a_users_file_says_so_at_validation(tmp_path):
    with pytest.raises(ConfigError, match=r"data\.files=.* is not read by format lasa"):
        resolve_and_validate(compose_cfg(["experiment=lasa", f"data.files=[{tmp_path / 'mine.csv'}]"]))


def test_angles_on_a_plane_and_too_few_demonstrations_are_refused_at_validation(tmp_path):
    path = tmp_path / "one.csv"
    path.write_text(csv_text(reach_rows(), ["t", "x", "y"]))
    base = ["experiment=lasa", "data=recorded", f"data.files=[{path}]", "name=mine"]
    with pytest.raises(ConfigError, match=r"data\.units=deg is for an arm's joint angles.*data\.units=m, cm or mm"):
        resolve_and_validate(compose_cfg([*base, "data.units=deg"]))
    with pytest.raises(ConfigError, match=r"cannot split 1 demonstration\(s\) into 1 validation, 1 test"):
        resolve_and_validate(compose_cfg(base))


@pytest.mark.slow
def test_a_rerun_after_the_recording_changed_is_refused_and_resumes_once_it_is_back(tmp_path):
    """The command line end to end: the same command into the same directory resumes, unless the recorded file
    changed in between (refused, exit 2, the run's metrics untouched)."""
    path = tmp_path / "demos.csv"
    demos = lambda third: [[f"d{k}", t, *(p * (1 + third * k))] for k in range(3) for t, p in zip(T, REACH)]
    path.write_text(csv_text(demos(0.1), ["demo", "t", "x", "y"]))
    original = path.read_text()
    command = [
        sys.executable,
        "-m",
        "rmpfusion.cli.run",
        "experiment=lasa",
        "data=recorded",
        f"data.files=[{path}]",
        "data.demo_column=demo",
        "name=mine",
        "train.iterations=3",
        "train.snapshots=[0,3]",
        "data.starts=2",
        "data.horizon_factor=0.5",
        "data.convergence_horizon_factor=1.0",
        "logger=disabled",
        f"hydra.run.dir={tmp_path / 'run'}",
    ]
    run = lambda: subprocess.run(command, capture_output=True, text=True, cwd=ROOT)
    first = run()
    assert first.returncode == 0, first.stderr[-2000:]
    metrics = (tmp_path / "run" / "metrics.json").read_bytes()
    path.write_text(csv_text(demos(0.2), ["demo", "t", "x", "y"]))  # two demonstrations recorded again
    changed = run()
    assert changed.returncode == 2 and "Traceback" not in changed.stderr
    assert "learned from another version of" in changed.stderr
    assert (tmp_path / "run" / "metrics.json").read_bytes() == metrics
    path.write_text(original)
    again = run()
    assert again.returncode == 0, again.stderr[-2000:]


def test_a_run_stored_before_the_newer_data_keys_resumes():
    """A run directory's saved config from before time_units, the derivative keys and group existed reads as the
    config it ran with, so rerunning the same command resumes it instead of being refused as another config."""
    from rmpfusion.cli.rundir import config_diff
    from rmpfusion.pipeline.config import RECORDED_DATA_ADDED, upgrade_run_config

    now = resolve_and_validate(compose_cfg(["experiment=lasa"])).model_dump(mode="json")
    before = {**now, "data": {k: v for k, v in now["data"].items() if k not in RECORDED_DATA_ADDED}}
    assert config_diff(upgrade_run_config(before), now) == []


# ------------------------------------------------------------------------------------------------ comments and gaps
def test_comment_lines_and_numpys_savetxt_header_read_with_the_files_own_row_numbers(tmp_path):
    """A logger's ``#`` notes above the header and between samples are skipped; ``numpy.savetxt(..., header=...)``
    writes the header as the last comment above the numbers (``# t,x,y``), which is the header. Rows keep the
    file's line numbers, so an error still points at the right line."""
    noted = tmp_path / "noted.csv"
    lines = [f"{t},{x},{y}" for t, (x, y) in zip(T, REACH)]
    noted.write_text("# kinesthetic teaching, 100 Hz\n# operator: A\nt,x,y\n" + "\n".join(lines[:9]) + "\n# pause\n"
                     + "\n".join(lines[9:]) + "\n")  # fmt: skip
    saved = tmp_path / "saved.csv"
    np.savetxt(saved, np.column_stack([T, REACH]), delimiter=",", header="recorded by numpy\nt,x,y")
    for path in (noted, saved):
        (rec,) = read_csv(path)
        assert rec.columns == ("x", "y")
        np.testing.assert_array_equal(rec.pos, REACH)
    assert list(read_csv(noted)[0].rows[8:11]) == [12, 14, 15]  # the comment on line 13 is skipped
    noted.write_text(noted.read_text().replace(lines[20], f"{T[20]},{REACH[20, 0]},oops"))
    with pytest.raises(RecordingError, match=r"noted\.csv, row 25, column 'y': 'oops' is not a number"):
        read_csv(noted)
    only = tmp_path / "only.csv"
    only.write_text("# nothing was recorded\n")
    with pytest.raises(RecordingError, match=r"only\.csv: the file is empty but for # comments; it needs a header"):
        read_csv(only)


def test_a_trailing_delimiter_on_every_line_is_not_a_column(tmp_path):
    path = tmp_path / "trailing.csv"
    path.write_text(csv_text([[*r, ""] for r in reach_rows()], ["t", "x", "y", ""]))
    (rec,) = read_csv(path)
    assert rec.columns == ("x", "y")
    np.testing.assert_array_equal(rec.pos, REACH)


def test_an_empty_cell_is_named_as_a_missing_sample(tmp_path):
    path = tmp_path / "gap.csv"
    rows = reach_rows()
    rows[40][1] = ""
    path.write_text(csv_text(rows, ["t", "x", "y"]))
    with pytest.raises(RecordingError, match=r"gap\.csv, row 42, column 'x': the cell is empty .*drop the row"):
        read_csv(path)


def test_dates_and_times_in_the_time_column_read_as_seconds(tmp_path):
    """A time column of ISO 8601 dates and times, as pandas writes a DatetimeIndex (with or without a UTC offset):
    the stamps' differences in seconds, to the microseconds they are written in; a unit set for them, or a row
    that is not one, is refused."""
    from datetime import datetime, timedelta, timezone

    start = datetime(2024, 5, 1, 23, 59, 59, tzinfo=timezone(timedelta(hours=2)))  # crosses midnight
    for name, fmt in (("naive", lambda d: d.replace(tzinfo=None).isoformat(sep=" ", timespec="microseconds")),
                      ("offset", lambda d: d.isoformat()))  :  # fmt: skip
        path = tmp_path / f"{name}.csv"
        stamps = [fmt(start + timedelta(seconds=t)) for t in T.tolist()]
        path.write_text(csv_text([[s, *p] for s, p in zip(stamps, REACH.tolist())], ["time", "x", "y"]))
        (rec,) = read_csv(path, time_column="time")
        np.testing.assert_allclose(rec.t - rec.t[0], T, rtol=0, atol=5e-7)  # float64 seconds since 1970
        np.testing.assert_array_equal(rec.pos, REACH)
    with pytest.raises(RecordingError, match=r"row 2, column 'time': the times are dates and times .*drop data\.ti"):
        read_csv(path, time_column="time", time_units="ms")
    path.write_text(path.read_text().replace(stamps[7], "later"))
    with pytest.raises(RecordingError, match=r"row 9, column 'time': 'later' is not a date and time like the first"):
        read_csv(path, time_column="time")
