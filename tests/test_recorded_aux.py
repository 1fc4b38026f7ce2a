"""Aux state that differs between recorded demonstrations: where the obstacle stood in each, or each one's goal,
read from the files' columns (CSV) or arrays (NPZ, HDF5) and carried to the tree in training and evaluation, with
every name and width checked against the environment's own aux state and every inconsistent file refused."""

from __future__ import annotations

import csv
import io
import re

import h5py
import numpy as np
import pytest
from conftest import compose_cfg
from pydantic import ValidationError

from rmpfusion.assembly.errors import ConfigError
from rmpfusion.pipeline.config import RecordedDataConfig
from rmpfusion.pipeline.experiment import prepare
from rmpfusion.pipeline.progress import Progress
from rmpfusion.pipeline.recorded import evaluation_batch, recorded_splits, told_only_the_scene
from rmpfusion.pipeline.validate import resolve_and_validate
from rmpfusion.recordings import RecordingError, read_hdf5, read_npz
from rmpfusion.recordings.source import SHIPPED_DIR, read_recordings, to_grid

#: the Franka scene's cylinder, moved by demonstration: demoNN stood NN millimetres further along y
CENTRE = np.array([0.55, 0.0, 0.25])


def moved(name: str) -> list[float]:
    return (CENTRE + np.array([0.0, 1e-3 * int(name[4:]), 0.0])).tolist()


def panda_with_obstacle_columns(path) -> None:
    """The shipped Panda recordings with three columns saying where each demonstration's obstacle stood."""
    with open(SHIPPED_DIR / "panda_via_points.csv", newline="") as fh:
        rows = list(csv.reader(fh))
    out = io.StringIO()
    w = csv.writer(out, lineterminator="\n")
    w.writerow([*rows[0], "ox", "oy", "oz"])
    w.writerows([*r, *moved(r[0])] for r in rows[1:])
    path.write_text(out.getvalue())


def arm_run(tmp_path, aux: str = "{obstacle1_center:[ox,oy,oz]}", *more: str):
    path = tmp_path / "panda_obstacles.csv"
    panda_with_obstacle_columns(path)
    return resolve_and_validate(
        compose_cfg(["experiment=recorded_arm", f"data.files=[{path}]", f"data.aux_columns={aux}", *more])
    )


def test_each_demonstrations_obstacle_reaches_training_and_evaluation(tmp_path):
    run = arm_run(tmp_path)
    exp = prepare(run, tmp_path, Progress(False))
    splits, demos, every = recorded_splits(exp)
    train = splits.train
    centres = train.aux["obstacle1_center"].numpy()
    for n, demo in enumerate(demos["train"]):  # every sample of a training demonstration carries its own obstacle
        name = re.search(r"demo=(demo\d+)", demo.source).group(1)
        np.testing.assert_array_equal(centres[train.traj_id.numpy() == n], [moved(name)] * (train.traj_id == n).sum())
    assert set(train.aux) == set(exp.env.aux_dims())  # the rest (goal, the cylinder's size, posture) as before
    batch = evaluation_batch(exp, demos, every)
    for split, rows in batch.index.items():  # each held-out demonstration is rolled out beside its own obstacle
        for n, demo in zip(range(rows.start, rows.stop), batch.demos[split]):
            name = re.search(r"demo=(demo\d+)", demo.source).group(1)
            np.testing.assert_array_equal(batch.aux["obstacle1_center"][n].numpy(), moved(name))
    grid = batch.aux["obstacle1_center"][batch.grid].numpy()  # the starts at rest: the scene's own cylinder
    np.testing.assert_allclose(grid, np.broadcast_to(exp.env.scene.obstacles[0].center, grid.shape))


def test_a_policy_not_told_where_the_obstacle_stood_is_judged_where_it_stood(tmp_path):
    """data.aux_to_policy=false, the baseline that was never told: training samples carry the scene's cylinder for
    every demonstration, the policy reads the scene's cylinder in evaluation (for the whole batch and for the single
    rows fault isolation evaluates), while the rollouts' world, where collisions count, keeps each held-out
    demonstration's own."""
    run = arm_run(tmp_path, "{obstacle1_center:[ox,oy,oz]}", "data.aux_to_policy=false")
    exp = prepare(run, tmp_path, Progress(False))
    splits, demos, every = recorded_splits(exp)
    scene = np.asarray(exp.env.scene.obstacles[0].center)
    np.testing.assert_array_equal(np.unique(splits.train.aux["obstacle1_center"].numpy(), axis=0), [scene])
    batch = evaluation_batch(exp, demos, every)
    held = [d for k in ("test", "val") for d in batch.demos[k]]
    own = [moved(re.search(r"demo=(demo\d+)", d.source).group(1)) for d in held]
    np.testing.assert_array_equal(batch.aux["obstacle1_center"][: len(held)].numpy(), own)  # the world
    np.testing.assert_array_equal(np.unique(batch.policy_aux()["obstacle1_center"].numpy(), axis=0), [scene])
    seen = []
    blind = told_only_the_scene(lambda q, qd, aux: seen.append(aux["obstacle1_center"].clone()), batch.hidden)
    blind(batch.q0, batch.qd0, batch.aux)
    blind(batch.q0[:1], batch.qd0[:1], {k: v[:1] for k, v in batch.aux.items()})
    for told in seen:
        np.testing.assert_array_equal(np.unique(told.numpy(), axis=0), [scene])
        np.testing.assert_array_equal(batch.aux["goal"][: len(told)].numpy(), batch.policy_aux()["goal"][: len(told)])
    told_run = arm_run(tmp_path, "{obstacle1_center:[ox,oy,oz]}")
    assert evaluation_batch(prepare(told_run, tmp_path / "told", Progress(False)), demos, every).hidden == {}


def test_hiding_aux_that_no_file_gives_or_the_goal_is_refused():
    keys = {"source": "recorded", "format": "csv", "files": ["a.csv"], "aux_to_policy": False}
    with pytest.raises(ValidationError, match=r"data\.aux_to_policy=false hides .* but no file gives any"):
        RecordedDataConfig.model_validate(keys)
    with pytest.raises(ValidationError, match=r"a policy is never blind to its own goal"):
        RecordedDataConfig.model_validate({**keys, "aux_columns": {"goal": ["gx", "gy"]}})


def test_aux_the_environment_does_not_read_is_refused(tmp_path):
    with pytest.raises(
        ConfigError,
        match=r"aux state 'obstacle_centre' \(data\.aux_columns / aux_keys / aux_topics\) is not read by the environment "
        r"manipulator; its aux state \(name and width\): goal \(3\), obstacle1_center \(3\), .* posture \(7\)",
    ):
        arm_run(tmp_path, "{obstacle_centre:[ox,oy,oz]}")
    with pytest.raises(ConfigError, match=r"aux state 'obstacle1_center' has 2 value\(s\) but the environment"):
        arm_run(tmp_path, "{obstacle1_center:[ox,oy],goal:[oz]}")


def test_an_obstacle_that_moves_within_a_demonstration_is_refused(tmp_path):
    path = tmp_path / "moving.csv"
    path.write_text("t,x,y,ox\n0,0,0,1\n0.1,0.1,0,1\n0.2,0.2,0,1.5\n")
    block = RecordedDataConfig.model_validate(
        {"source": "recorded", "format": "csv", "files": [str(path)], "aux_columns": {"goal": ["ox"]}}
    )
    with pytest.raises(RecordingError, match=r"moving\.csv, row 4, column 'ox': 1\.5 differs from 1 earlier in .*"):
        read_recordings(block)


def test_a_goal_column_is_the_goal_on_the_plane(tmp_path):
    """Demonstrations that stop short of their goal: the column says where the goal was, not the final rest."""
    path = tmp_path / "short.csv"
    t = np.linspace(0, 2, 101)
    s = np.clip(t / 1.5, 0, 1)
    lines = ["demo,t,x,y,gx,gy"]
    for d, g in (("a", (0.1, 0.0)), ("b", (0.0, 0.1))):
        reach = np.outer(10 * s**3 - 15 * s**4 + 6 * s**5, np.array(g) * 0.9)  # stops 10 % short
        lines += [f"{d},{tk},{p[0]},{p[1]},{g[0]},{g[1]}" for tk, p in zip(t, reach)]
    path.write_text("\n".join(lines) + "\n")
    keys = {"source": "recorded", "format": "csv", "files": [str(path)], "demo_column": "demo"}
    block = RecordedDataConfig.model_validate({**keys, "aux_columns": {"goal": ["gx", "gy"]}})
    states = to_grid(read_recordings(block), block, 0.02)
    np.testing.assert_array_equal([s.goal for s in states], [[0.1, 0.0], [0.0, 0.1]])
    plain = to_grid(read_recordings(RecordedDataConfig.model_validate({**keys, "columns": ["x", "y"]})), block, 0.02)
    np.testing.assert_allclose([s.goal for s in plain], [[0.09, 0.0], [0.0, 0.09]], atol=1e-4)  # the final rest
    with pytest.raises(ValidationError, match=r"data\.goal and a goal aux column .* both give the goal"):
        RecordedDataConfig.model_validate({**keys, "aux_columns": {"goal": ["gx", "gy"]}, "goal": [0.0, 0.0]})


def test_npz_and_hdf5_aux_arrays(tmp_path):
    t = np.linspace(0, 1, 11)
    pos = np.stack([np.stack([t, t], 1), np.stack([t, -t], 1)])
    np.savez(tmp_path / "two.npz", t=np.stack([t, t]), pos=pos, goal=[[1.0, 1.0], [1.0, -1.0]], bad=[1.0, 2.0, 3.0])
    a, b = read_npz(tmp_path / "two.npz", aux_keys={"goal": "goal"})
    np.testing.assert_array_equal([a.aux["goal"], b.aux["goal"]], [[1.0, 1.0], [1.0, -1.0]])
    with pytest.raises(RecordingError, match=r"aux array 'bad' has shape \(3,\); .* \(this file holds 2\)"):
        read_npz(tmp_path / "two.npz", aux_keys={"goal": "bad"})
    with h5py.File(tmp_path / "demos.hdf5", "w") as fh:
        for k, sign in enumerate((1.0, -1.0)):
            g = fh.create_group(f"data/demo_{k}")
            g["t"], g["pos"] = t, np.stack([t, sign * t], 1)
            g["goal"] = [1.0, sign]  # (k,)
            g["obstacle"] = np.tile([0.5, 0.5 * sign], (len(t), 1))  # (T, k), constant
    first, second = read_hdf5(tmp_path / "demos.hdf5", "pos", time_key="t", aux_keys={"goal": "goal"})
    np.testing.assert_array_equal(second.aux["goal"], [1.0, -1.0])
    first, second = read_hdf5(tmp_path / "demos.hdf5", "pos", time_key="t", aux_keys={"goal": "obstacle"})
    np.testing.assert_array_equal([first.aux["goal"], second.aux["goal"]], [[0.5, 0.5], [0.5, -0.5]])
    with h5py.File(tmp_path / "demos.hdf5", "a") as fh:
        fh["data/demo_1/obstacle"][5, 1] = 0.0
    with pytest.raises(RecordingError, match=r"\[data/demo_1\], obstacle\[5, 1\]: 0 differs from -0\.5 earlier"):
        read_hdf5(tmp_path / "demos.hdf5", "pos", time_key="t", aux_keys={"goal": "obstacle"})


def test_aux_keys_a_format_does_not_read_are_refused():
    with pytest.raises(ValidationError, match=r"data\.aux_keys=\{'goal': 'g'\} is not read by format csv"):
        RecordedDataConfig.model_validate(
            {"source": "recorded", "format": "csv", "files": ["a.csv"], "aux_keys": {"goal": "g"}}
        )
    with pytest.raises(ValidationError, match=r"data\.aux_columns=.* is not read by format hdf5"):
        RecordedDataConfig.model_validate(
            {"source": "recorded", "format": "hdf5", "files": ["a.h5"], "aux_columns": {"goal": ["gx"]}}
        )
