"""Joint-space recordings of an arm (experiment=recorded_arm): the shipped recording is a user's file (irregular
stamps, noise, the robot's joint names), read back and checked against the robot file; what a recording implies for
the tree (goal, obstacles, posture) comes from the environment; bad files are refused by file, row and column; the
tree with a learned end-effector map and a posture attractor keeps Theorem 2 on rollouts; and (slow) the shipped file
is what tools/arm_recordings.py makes, and tiny runs (behavior cloning; cloning then trajectory matching) go end
to end. The same for a second arm from another tool: the iiwa's recordings (experiment=recorded_iiwa) are robomimic's
HDF5 layout, solved by pybullet's inverse kinematics, and read back through the same pipeline."""

from __future__ import annotations

import csv
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml
from conftest import ROOT, compose_cfg

from rmpfusion.envs.protocol import JointSpace, LearnsFromRecordings
from rmpfusion.evaluate.lyapunov import lyapunov_monotone
from rmpfusion.pipeline.construct import build_unit_weights, make_env
from rmpfusion.pipeline.validate import resolve_and_validate
from rmpfusion.recordings import RecordingError, check_joint_recordings
from rmpfusion.recordings.readers import read_csv, read_hdf5
from rmpfusion.recordings.source import SHIPPED_DIR, source_file

SHIPPED = SHIPPED_DIR / "panda_via_points.csv"
SHIPPED_IIWA = SHIPPED_DIR / "iiwa_post_ik.hdf5"


@pytest.fixture(scope="module")
def run():
    return resolve_and_validate(compose_cfg(["experiment=recorded_arm"]))


@pytest.fixture(scope="module")
def env(run):
    e = make_env(run)
    yield e
    e.close()


def test_the_shipped_recording_is_a_users_file_of_the_panda(env):
    recs = read_csv(SHIPPED, demo_column="demo", units="rad")
    assert len(recs) == 24
    steps = np.concatenate([np.diff(r.t) for r in recs])
    assert steps.min() > 0 and steps.std() > 1e-3  # irregular stamps (jitter, dropped samples), strictly increasing
    assert min(r.t[0] for r in recs) > 1.0  # the logger's clock does not start at 0
    assert list(recs[0].columns) == list(env.robot_description.joints)
    check_joint_recordings(recs, env.robot_description)  # inside the limits, named as the robot file names them
    assert source_file("rmpfusion:panda_via_points.csv") == SHIPPED


def test_an_unknown_shipped_name_and_a_missing_file_are_clear_errors():
    with pytest.raises(RecordingError, match="ships no such recording.*panda_via_points.csv"):
        source_file("rmpfusion:nothing.csv")
    with pytest.raises(RecordingError, match="no such file.*rmpfusion:NAME"):
        source_file("no/such/file.csv")


def test_what_a_recording_implies_comes_from_the_environment(env):
    assert isinstance(env, LearnsFromRecordings) and isinstance(env, JointSpace)
    goals = torch.tensor([env.params.robot.home, env.params.start_centre()], dtype=torch.float64)
    aux = env.recorded_aux(goals)
    assert set(aux) == set(env.aux_dims())
    assert torch.allclose(aux["goal"], env.ee_position(goals))  # the end effector where the recording ends
    assert torch.equal(aux["posture"], goals)  # the configuration itself
    cyl = env.scene.obstacles[0]
    centre = next(v for k, v in aux.items() if k.endswith("center"))
    assert torch.allclose(centre, torch.tensor([cyl.center, cyl.center], dtype=torch.float64))


def test_starts_past_a_limit_or_in_the_cylinder_are_refused(env):
    home = torch.tensor(env.params.robot.home, dtype=torch.float64)
    past = home.clone()
    past[3] = float(env.upper[3]) + 0.1
    ok = env.recorded_starts(torch.stack([home, past]))
    assert ok.tolist() == [True, False]


def _write(path: Path, header: list[str], rows: list[list[float]]) -> Path:
    with path.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(header)
        w.writerows(rows)
    return path


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ("rename", r"not the robot's joints \(missing panda_joint7\)"),
        ("limit", r"bad\.csv, row 3, column 'panda_joint4': .* outside panda_joint4's limits"),
        ("drop", r"6 coordinates per sample \(read from .*\), but the robot 'panda' has 7"),
    ],
)
def test_a_joint_recording_unlike_the_robot_is_refused_naming_file_row_and_column(tmp_path, env, change, message):
    names = list(env.robot_description.joints)
    home = list(env.params.robot.home)
    rows = [[0.01 * k, *home] for k in range(20)]
    if change == "rename":
        names[-1] = "wrist"
    if change == "limit":
        rows[1][4] = float(env.upper[3]) + 0.5
    if change == "drop":
        names, rows = names[:-1], [r[:-1] for r in rows]
    recs = read_csv(_write(tmp_path / "bad.csv", ["t", *names], rows), units="rad")
    with pytest.raises(RecordingError, match=message):
        check_joint_recordings(recs, env.robot_description)


def test_validation_refuses_a_bad_joint_recording_in_one_line(tmp_path, env):
    names = list(env.robot_description.joints)
    rows = [[0.01 * k, *env.params.robot.home] for k in range(40)]
    rows[5][1] = 99.0
    bad = _write(tmp_path / "bad.csv", ["t", *names], rows)
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "rmpfusion.cli.validate",
            "experiment=recorded_arm",
            f"data.files=[{bad}]",
            "data.demo_column=null",
        ],
        capture_output=True,
        text=True,
        cwd=ROOT,
    )
    assert r.returncode != 0
    assert "Traceback" not in r.stderr + r.stdout
    assert "row 7, column 'panda_joint1'" in r.stderr + r.stdout


def test_the_tree_with_a_learned_map_and_a_posture_keeps_theorem_2_on_rollouts(run, env):
    """The reference tree (every weight 1, the random map) from three starts for 1 s in the kinematic simulator:
    V_r never rises (rtol 1e-6)."""
    tree = build_unit_weights(run, env.aux_dims()).to(torch.float64)
    assert {"ee_latent", "posture"} <= set(tree.maps)
    home = torch.tensor(env.params.robot.home, dtype=torch.float64)
    q0 = home + torch.tensor([[0.0] * 7, [0.1, -0.1, 0.1, 0.1, 0.0, -0.1, 0.2], [-0.1, 0.1, 0.0, -0.1, 0.1, 0.1, 0.0]])
    goal_q = torch.tensor(env.params.start_centre(), dtype=torch.float64).expand(3, -1)
    ro = env.rollout(tree, q0, torch.zeros_like(q0), env.recorded_aux(goal_q), 1.0, env.dt)
    assert ro.V is not None
    assert bool(lyapunov_monotone(ro.V, rtol=1e-6, atol=1e-9).all())
    assert not bool(ro.collided.any())


@pytest.mark.slow
@pytest.mark.parametrize(
    ("shipped", "options"),
    [("panda_via_points.csv", []), ("panda_moved_cylinder.csv", ["--cylinder-shift", "0.04", "0.06"])],
)
def test_the_shipped_recording_is_what_the_tool_makes(tmp_path, shipped, options):
    """The tool's first demonstration at seed 0 is the shipped file's first (the draws are sequential)."""
    out = one_demonstration_of("tools/arm_recordings.py", tmp_path / "one.csv", *options)
    made = out.read_text().splitlines()
    assert made == (SHIPPED_DIR / shipped).read_text().splitlines()[: len(made)]


def one_demonstration_of(tool: str, out: Path, *options: str) -> Path:
    """``out``, written by a recordings tool asked for one demonstration at its default seed."""
    r = subprocess.run(
        [sys.executable, tool, "--demos", "1", "--out", str(out), *options], capture_output=True, text=True, cwd=ROOT
    )
    assert r.returncode == 0, r.stderr[-2000:]
    return out


def tiny_run(tmp_path: Path, experiment: str, *overrides: str) -> dict:
    """metrics.json of ``rmpfusion-run experiment=<experiment>`` at smoke size (3 starts at rest, short horizons) with
    ``overrides``, run as a user runs it; a failed run fails the test with its stderr."""
    command = [sys.executable, "-m", "rmpfusion.cli.run", f"experiment={experiment}", *overrides]
    command += ["data.starts=3", "data.horizon_factor=0.3", "data.convergence_horizon_factor=0.6"]
    command += ["logger=disabled", f"hydra.run.dir={tmp_path}"]
    r = subprocess.run(command, capture_output=True, text=True, cwd=ROOT)
    assert r.returncode == 0, r.stderr[-3000:]
    return json.loads((tmp_path / "metrics.json").read_text())


@pytest.mark.slow
def test_a_tiny_recorded_arm_run_end_to_end(tmp_path):
    m = tiny_run(tmp_path, "recorded_arm", "train.iterations=3", "train.snapshots=[0,3]")
    for res in (m["tree"], m["learners"]["rmp"]):
        assert res["reproduction_test"]["dtw"] > 0
        assert res["convergence"]["starts"] == 3
        assert res["convergence"]["lyapunov_monotone_fraction"] == 1.0
        assert res["reproduction_test"]["collisions"] == 0
    assert (tmp_path / "figures" / "rollouts.png").is_file()


@pytest.mark.slow
def test_a_tiny_trajectory_matching_run_on_the_arm_end_to_end(tmp_path):
    """Cloning, then matching through the kinematic simulator's rollouts, then the evaluation: the whole pipeline of
    the Panda's kept tree trained by train=match_arm_recordings at smoke size."""
    matching = ["train.pretrain_iterations=2", "train.iterations=4", "train.snapshots=[0,4]", "train.batch_size=2"]
    kept = ["learned_leaves=arm_reach", "obstacle_weight=constant", "train=match_arm_recordings"]
    m = tiny_run(tmp_path, "recorded_arm", *kept, *matching, "train.horizon_factor=1.0", "train.log_every=2")
    train = yaml.safe_load((tmp_path / "config.resolved.yaml").read_text())["train"]
    assert train["method"] == "match" and train["pretrain_iterations"] == 2 and train["dt"] == 0.02
    learner = m["learners"]["rmp"]
    assert set(learner["snapshots"]) == {"0", "4"}
    assert 0 < learner["final_train_loss"] < float("inf")  # the matching cost of the last step
    assert learner["convergence"]["starts"] == 3 and learner["certificate"]["ok"]


# ------------------------------------------------------------------------------ the iiwa, another tool's recordings
@pytest.fixture(scope="module")
def iiwa_env():
    e = make_env(resolve_and_validate(compose_cfg(["experiment=recorded_iiwa"])))
    yield e
    e.close()


def iiwa_recordings(env) -> list:
    return read_hdf5(SHIPPED_IIWA, "obs/robot0_joint_pos", rate=20.0, columns=env.robot_description.joints)


def test_the_iiwa_recording_is_robomimics_layout():
    h5py = pytest.importorskip("h5py")
    with h5py.File(SHIPPED_IIWA, "r") as fh:
        demos = fh["data"]
        assert len(demos) == 24 and sum(g.attrs["num_samples"] for g in demos.values()) == demos.attrs["total"]
        first = demos["demo_0"]
        assert (
            first["obs/robot0_joint_pos"].shape[1] == 7
            and first["actions"].shape == first["obs/robot0_joint_pos"].shape
        )
        assert "t" not in first and "timestamp" not in first  # robomimic keeps no time stamps: data.rate gives them
        assert json.loads(demos.attrs["env_args"])["env_kwargs"]["control_freq"] == 20.0


def test_the_iiwa_recordings_pass_over_the_post_by_rmpfusions_own_kinematics(iiwa_env):
    """They were solved by pybullet's inverse kinematics; rmpfusion's forward kinematics of the same angles puts
    every end effector on the post's +y side at the start, on its -y side at the end, and above its top (0.6 m)
    where it crosses y = 0: an independent check of the tool and of the two libraries' agreement."""
    recs = iiwa_recordings(iiwa_env)
    check_joint_recordings(recs, iiwa_env.robot_description, named_columns=False)
    post = iiwa_env.scene.obstacles[0]
    top = post.center[2] + post.half_extents[2]
    for rec in recs:
        ee = iiwa_env.ee_position(torch.tensor(rec.pos)).numpy()
        assert ee[0, 1] > 0.2 and ee[-1, 1] < -0.2
        crossing = int(np.argmin(np.abs(ee[:, 1])))
        assert ee[crossing, 2] > top + 0.1


def test_the_iiwa_recording_without_joint_names_asks_for_them(tmp_path):
    """robomimic's layout names no joints: validating without data.columns says so and how to fix it."""
    r = subprocess.run(
        [sys.executable, "-m", "rmpfusion.cli.validate", "experiment=recorded_iiwa", "data.columns=null"],
        capture_output=True,
        text=True,
        cwd=ROOT,
    )
    out = r.stderr + r.stdout
    assert r.returncode != 0 and "Traceback" not in out
    assert "iiwa_post_ik.hdf5 [data/demo_0]" in out and "not the robot's joints" in out and "data.columns" in out


def test_the_shipped_iiwa_recording_is_what_the_tool_makes(tmp_path, iiwa_env):
    """The tool's first demonstration at seed 0 is the shipped file's first (the draws are sequential), to rounding:
    its inverse kinematics and splines are pybullet's and scipy's, whose releases may change the last bits (2.7e-15
    rad seen on a fresh install), never a demonstration."""
    out = one_demonstration_of("tools/iiwa_recordings.py", tmp_path / "one.hdf5")
    made = read_hdf5(out, "obs/robot0_joint_pos", rate=20.0)[0]
    np.testing.assert_allclose(made.pos, iiwa_recordings(iiwa_env)[0].pos, rtol=0, atol=1e-12)


@pytest.mark.slow
def test_a_tiny_recorded_iiwa_run_end_to_end(tmp_path):
    m = tiny_run(tmp_path, "recorded_iiwa", "train.iterations=3", "train.snapshots=[0,3]")
    learner = m["learners"]["rmp"]
    assert learner["reproduction_test"]["ee_dtw"] > 0 and learner["convergence"]["starts"] == 3
    assert learner["convergence"]["lyapunov_monotone_fraction"] == 1.0 and learner["certificate"]["ok"]
