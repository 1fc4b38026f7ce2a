"""A recording as a Franka lab logs it, read the way the tutorial says to run one (``experiment=recorded_arm
data.files=[that.csv] data.val=1 data.test=1``): long, at rest for seconds at either end, 1 kHz, the gripper's two
finger columns and a wall clock beside the seven joints, and an encoder's noise. The file is written here with the
csv module from the shipped recordings' joint paths (read with the csv module too, smoothed and retimed with scipy),
never by rmpfusion's readers or resampling, so what the pipeline makes of it is checked against what went in: the
arm's seven joints read by name and every other column listed as ignored, the rests trimmed to the motion, the
samples resampled onto the environment's 250 Hz, and (slow) a run that trains end to end at smoke size."""

from __future__ import annotations

import csv
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import ROOT, compose_cfg
from scipy.interpolate import CubicSpline

from rmpfusion.pipeline.construct import make_env
from rmpfusion.pipeline.validate import resolve_and_validate
from rmpfusion.recordings.source import SHIPPED_DIR, on_grid_for, read_recordings

JOINTS = [f"panda_joint{j}" for j in range(1, 8)]
FINGERS = ["panda_finger_joint1", "panda_finger_joint2"]
#: the logger's rate, the rests at either end and the motion's duration (s)
RATE, REST_BEFORE, REST_AFTER, MOTION = 1000.0, 3.0, 2.5, 5.0
#: the encoders' noise (rad, white, per sample): what a Panda's joint positions carry at rest
NOISE = 5e-4
#: the speed (rad/s) below which the trimming takes the arm for at rest (data.rest_speed; why: the trimming test)
REST_SPEED = 0.1
#: where the logger's clock stood at the first sample of the file (s), and the wall clock then (ns since the epoch)
CLOCK_START, WALL_START = 812.25, 1_733_580_000_000_000_000


def shipped_paths(n: int) -> list[np.ndarray]:
    """The joint paths (T, 7) of the first ``n`` shipped demonstrations, read with the csv module."""
    with (SHIPPED_DIR / "panda_via_points.csv").open(newline="") as f:
        rows = list(csv.DictReader(f))
    demos: dict[str, list[list[float]]] = {}
    for row in rows:
        demos.setdefault(row["demo"], []).append([float(row[j]) for j in JOINTS])
    return [np.asarray(q) for q in list(demos.values())[:n]]


def min_jerk(tau: np.ndarray) -> np.ndarray:
    """The minimum-jerk time scaling 10τ³ − 15τ⁴ + 6τ⁵ on [0, 1], at rest at both ends."""
    tau = np.clip(tau, 0.0, 1.0)
    return tau**3 * (10 - 15 * tau + 6 * tau**2)


def real_style_demonstration(path: np.ndarray, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """One recording: the path's samples averaged in runs of 9 (its own noise out), from where it leaves its start
    to where it reaches its end, as a spline's knots, traversed in
    ``MOTION`` s by a minimum-jerk profile between ``REST_BEFORE`` and ``REST_AFTER`` s at rest, logged at ``RATE``
    with 20 µs of jitter and ``NOISE`` on every joint; the gripper open (0.04 m a finger) until it closes on an object
    to 0.025 m in the final rest; the wall clock in ns. ``faster``: the first and last time the motion itself (the
    noise left out) is faster than ``REST_SPEED``."""
    smooth = np.stack([np.convolve(path[:, k], np.ones(9) / 9, mode="valid") for k in range(7)], 1)
    away = np.flatnonzero(
        (np.linalg.norm(smooth - smooth[0], axis=1) > 0.02) & (np.linalg.norm(smooth - smooth[-1], axis=1) > 0.02)
    )
    moving = smooth[away[0] - 1 : away[-1] + 2]  # the shipped take's own rests left out: the profile is the motion
    knots = np.vstack([moving[:-1:20], moving[-1]])
    spline = CubicSpline(np.linspace(0.0, 1.0, len(knots)), knots, axis=0)
    n = int((REST_BEFORE + MOTION + REST_AFTER) * RATE)
    t = np.arange(n) / RATE + rng.normal(0.0, 2e-5, n)
    clean = spline(min_jerk((t - REST_BEFORE) / MOTION))
    q = clean + rng.normal(0.0, NOISE, (n, 7))
    speed = np.linalg.norm(np.gradient(clean, t, axis=0), axis=1)  # the motion's own, without the noise
    over = np.flatnonzero(speed > REST_SPEED)
    closing = np.clip((t - REST_BEFORE - MOTION - 1.0) / 0.5, 0.0, 1.0)
    finger = 0.04 - 0.015 * closing + rng.normal(0.0, 2e-5, n)
    return {"t": t, "q": q, "fingers": np.stack([finger, finger], 1), "faster": np.array([t[over[0]], t[over[-1]]])}


def write_log(path: Path, demos: list[dict[str, np.ndarray]]) -> Path:
    """The demonstrations as one CSV, a demonstration column first, the fingers before the joints (loggers write
    whatever order their topics came in), the logger's clock in s and the wall clock in ns."""
    with path.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["demo", "t", "wall_ns", *FINGERS, *JOINTS])
        clock = CLOCK_START
        for k, d in enumerate(demos):
            for ti, fi, qi in zip(d["t"], d["fingers"], d["q"]):
                at = clock + ti
                w.writerow([f"take{k + 1}", f"{at:.6f}", WALL_START + round(at * 1e9), *(f"{x:.6f}" for x in fi),
                            *(f"{x:.6f}" for x in qi)])  # fmt: skip
            clock += float(d["t"][-1]) + 10.0  # the next take starts ten seconds later
    return path


@pytest.fixture(scope="module")
def takes() -> list[dict[str, np.ndarray]]:
    rng = np.random.default_rng(7)
    return [real_style_demonstration(p, rng) for p in shipped_paths(3)]


@pytest.fixture(scope="module")
def log(tmp_path_factory, takes) -> Path:
    return write_log(tmp_path_factory.mktemp("lab") / "franka_takes.csv", takes)


#: the run as the tutorial says to run it on one's own file: the experiment's defaults, every column as logged
def tutorial(log: Path) -> list[str]:
    return ["experiment=recorded_arm", f"data.files=[{log}]", "data.val=1", "data.test=1"]


def test_the_arm_joints_are_read_by_name_and_the_other_columns_are_listed_as_ignored(log):
    run = resolve_and_validate(compose_cfg(tutorial(log)))
    recordings = read_recordings(run.data, JOINTS)
    assert len(recordings) == 3
    for rec in recordings:
        assert list(rec.columns) == JOINTS
        assert set(rec.ignored) == {"wall_ns", *FINGERS}
        assert abs(rec.duration - (REST_BEFORE + MOTION + REST_AFTER)) < 0.01
    with log.open(newline="") as f:
        first = next(csv.DictReader(f))
    assert recordings[0].pos[0] == pytest.approx([float(first[j]) for j in JOINTS], abs=1e-12)


def grid_states(log: Path, *overrides: str) -> list:
    """The demonstrations on the environment's step grid, as validation and the collect stage make them."""
    run = resolve_and_validate(compose_cfg([*tutorial(log), *overrides]))
    env = make_env(run)
    try:
        recordings = read_recordings(run.data, JOINTS)
        return on_grid_for(recordings, run.data, env.dt, env.dim, run.env.type, env.robot_description, env.aux_dims())
    finally:
        env.close()


def test_the_rests_are_trimmed_and_the_motion_is_resampled_onto_the_control_rate(log, takes):
    """The noise (0.5 mrad a sample at 1 kHz) reads as 0.03 rad/s of filtered speed at rest (0.045–0.05 at the 99th
    percentile: the filter's window, 21 samples of the 250 Hz grid, does not average it away), above 2 % of the
    motions' peak of 1.1 to 1.2 rad/s, so trimming by ``data.rest_fraction`` alone keeps the rests whole; the
    rests are trimmed with ``data.rest_speed=0.1`` rad/s, above the noise and a twentieth of the peak. What is kept
    is where the motion itself (the noise left out) is faster than that, within the filter's reach."""
    untrimmed = grid_states(log)
    assert all(s.t[-1] > MOTION + 3.0 for s in untrimmed)
    for s in untrimmed:  # why: the noise's speed at rest against the peak and the rest speed chosen
        speed = np.linalg.norm(s.qd, axis=1)
        at_rest = speed[(s.t > 0.2) & (s.t < REST_BEFORE - 0.5)]  # the filter's edge left out
        assert 0.02 < np.median(at_rest) < 0.035 and np.quantile(at_rest, 0.99) < 0.06 < REST_SPEED
        assert np.median(at_rest) > 0.02 * speed.max() and 1.0 < speed.max() < 1.3
    with log.open(newline="") as f:
        first: dict[str, float] = {}
        for row in csv.DictReader(f):
            first.setdefault(row["demo"], float(row["t"]))
    trimmed = grid_states(log, f"data.rest_speed={REST_SPEED}")
    for s, take, start in zip(trimmed, takes, first.values()):
        assert np.diff(s.t) == pytest.approx(np.full(len(s.t) - 1, 1 / 250.0))  # env.control_rate
        begins, ends = take["faster"]
        assert s.start_time - start == pytest.approx(begins, abs=0.05)  # on the file's own clock
        assert s.t[-1] == pytest.approx(ends - begins, abs=0.1)


#: smoke size: 20 iterations, 4 starts at rest, rollouts as long as the longest demonstration (1.5 times from rest)
SMOKE = [
    "train.iterations=20",
    "train.snapshots=[0,20]",
    "data.starts=4",
    "data.horizon_factor=1.0",
    "data.convergence_horizon_factor=1.5",
    "eval.figures=false",
    "logger=disabled",
]


@pytest.mark.slow
def test_a_real_style_recording_trains_end_to_end_at_smoke_size(log, tmp_path):
    """rmpfusion-run on the lab's log as the tutorial says to run one's own file (and the rest speed its noise
    needs, see the trimming test), at smoke size: it trains and evaluates, and metrics.json says which columns it
    left out and that no recording enters the experiment's cylinder."""
    command = [sys.executable, "-m", "rmpfusion.cli.run", *tutorial(log), f"data.rest_speed={REST_SPEED}", *SMOKE]
    r = subprocess.run([*command, f"hydra.run.dir={tmp_path}"], capture_output=True, text=True, cwd=ROOT)
    assert r.returncode == 0, r.stderr[-3000:]
    assert "ignored the other columns wall_ns, panda_finger_joint1, panda_finger_joint2" in r.stdout
    m = json.loads((tmp_path / "metrics.json").read_text())
    assert {len(m["data"][s]["demonstrations"]) for s in ("train", "val", "test")} == {1}
    read = m["data"]["recordings"]
    assert read["ignored_columns"] == {"wall_ns": 3, "panda_finger_joint1": 3, "panda_finger_joint2": 3}
    assert read["obstacle_entries"]["checked"] == 3 and read["obstacle_entries"]["entering"] == []
    learner = m["learners"]["rmp"]
    assert set(learner["snapshots"]) == {"0", "20"} and 0 < learner["final_train_loss"] < float("inf")
    for policy in (m["tree"], learner):
        assert policy["reproduction_test"]["ee_dtw"] > 0 and policy["convergence"]["starts"] == 4
        assert policy["convergence"]["lyapunov_monotone_fraction"] == 1.0
