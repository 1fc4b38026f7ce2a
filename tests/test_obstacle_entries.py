"""Recordings that pass through an obstacle of the run's world are found before training and refused unless told
(``pipeline/obstacle_entries.py``, ``data.obstacle_entries``). On the arm the spheres' check is held to the
simulator's closest points at every sample (no recording the simulator finds inside may be missed, and each depth is
the simulator's); on the plane to the distance from the raw samples to the disc. The refusal is one message naming
the file, the recording, the time, the point and the depth, and the one-line fixes it names compose and validate."""

from __future__ import annotations

import csv
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import ROOT, compose_cfg

from rmpfusion.assembly.errors import ConfigError
from rmpfusion.pipeline.construct import make_env
from rmpfusion.pipeline.obstacle_entries import ObstacleEntryError, apply_policy, find_entries
from rmpfusion.pipeline.validate import resolve_and_validate
from rmpfusion.recordings.source import SHIPPED_DIR, on_grid_for, read_recordings

JOINTS = [f"panda_joint{j}" for j in range(1, 8)]


def on(log: Path) -> list[str]:
    """The arm's experiment on ``log``, as the tutorial runs one's own file."""
    return ["experiment=recorded_arm", f"data.files=[{log}]", "data.val=1", "data.test=1"]


def validate_command(*overrides: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "rmpfusion.cli.validate", *overrides], capture_output=True, text=True, cwd=ROOT
    )


@pytest.fixture(scope="module")
def six_takes(tmp_path_factory) -> Path:
    """The first six of the Panda's shipped recordings, copied row by row with the csv module."""
    out = tmp_path_factory.mktemp("arm") / "six_takes.csv"
    with (SHIPPED_DIR / "panda_via_points.csv").open(newline="") as f, out.open("w", newline="") as g:
        rows = csv.reader(f)
        w = csv.writer(g)
        w.writerow(next(rows))
        keep = [f"demo{k:02d}" for k in range(6)]
        w.writerows(row for row in rows if row[0] in keep)
    return out


def the_hand_at(log: Path, take: str, t: float) -> list[float]:
    """Where the Panda's end effector is at file time ``t`` of ``take`` (the row nearest it, read with csv)."""
    with log.open(newline="") as f:
        rows = [r for r in csv.DictReader(f) if r["demo"] == take]
    row = min(rows, key=lambda r: abs(float(r["t"]) - t))
    env = make_env(resolve_and_validate(compose_cfg(["experiment=recorded_arm"])))
    hand = env.ee_position(torch.tensor([[float(row[j]) for j in JOINTS]], dtype=torch.float64))[0]
    env.close()
    return [round(float(x), 4) for x in hand]


def a_ball_at(centre: list[float], radius: float = 0.04) -> str:
    return f"env.scene.obstacles=[{{type: sphere, center: [{centre[0]}, {centre[1]}, {centre[2]}], radius: {radius}}}]"


@pytest.fixture(scope="module")
def ball(six_takes) -> tuple[str, float]:
    """A ball of 4 cm placed where take demo03's hand is 1.5 s into its recording, and that file time."""
    with six_takes.open(newline="") as f:
        t0 = next(float(r["t"]) for r in csv.DictReader(f) if r["demo"] == "demo03")
    return a_ball_at(the_hand_at(six_takes, "demo03", t0 + 1.5)), t0 + 1.5


def grid(overrides: list[str]):
    run = resolve_and_validate(compose_cfg([*overrides, "data.obstacle_entries=warn"]))
    env = make_env(run)
    states = on_grid_for(
        read_recordings(run.data, JOINTS),
        run.data,
        env.dt,
        env.dim,
        run.env.type,
        env.robot_description,
        env.aux_dims(),
    )
    return env, states


def test_every_recording_the_simulator_finds_inside_is_found_with_the_simulators_depth(six_takes, ball):
    """The spheres' check against the simulator's clearance at every grid sample of every recording: the same
    recordings enter, and each confirmed entry's depth is the simulator's deepest penetration in its stretch."""
    env, states = grid([*on(six_takes), ball[0]])
    found = find_entries(env, states)
    truth: dict[str, float] = {}
    for s in states:
        q = torch.as_tensor(s.q, dtype=torch.float64)
        clearance = env.clearance(q, {k: v.expand(len(q), -1) for k, v in env.recorded_aux(q[-1:]).items()})
        if bool((clearance <= 0).any()):
            truth[s.source] = -float(clearance.min())
    env.close()
    assert truth and set(found.entering) == set(truth)
    for e in found.confirmed:
        assert e.body_depth == pytest.approx(truth[e.recording], abs=1e-9)
        assert e.depth > 0 and "obstacle1 (sphere)" == e.obstacle
    (where,) = [e for e in found.confirmed if "demo03" in e.recording]
    assert where.file_time == pytest.approx(ball[1], abs=0.3)  # the hand is at the ball's centre then


def test_validation_refuses_them_in_one_message_naming_file_recording_time_point_depth_and_fix(six_takes, ball):
    r = validate_command(*on(six_takes), ball[0])
    out = r.stderr + r.stdout
    assert r.returncode == 2 and "Traceback" not in out
    (error,) = [line for line in out.splitlines() if "an obstacle of the run's world" in line]
    entry = re.search(
        r"six_takes\.csv \[demo=demo03\]: from [\d.]+ to [\d.]+ s, deepest at [\d.]+ s \(file time ([\d.]+) s\): "
        r"(cp\d+ \(control sphere on panda_\w+\)|panda_\w+ \(the sphere around its mesh\)) ([\d.]+) m inside "
        r"obstacle1 \(sphere\); the links' meshes ([\d.]+) m deep by the simulator",
        error,
    )
    assert entry is not None, error
    assert float(entry.group(1)) == pytest.approx(ball[1], abs=0.3)
    assert float(entry.group(3)) > 0.0 and float(entry.group(4)) > 0.0
    for fix in ("env.scene.obstacles=[]", "scene=<your scene file>", "data.obstacle_entries=drop", "=warn"):
        assert fix in error
    resolve_and_validate(compose_cfg([*on(six_takes), ball[0], "env.scene.obstacles=[]"]))  # the fix it names


def test_drop_leaves_out_exactly_the_entering_recordings_and_warn_keeps_them(six_takes, ball):
    env, states = grid([*on(six_takes), ball[0]])
    entering = set(find_entries(env, states).entering)
    kept, _, said = apply_policy(env, states, "drop")
    assert {s.source for s in kept} == {s.source for s in states} - entering
    assert any(w.startswith(f"left out {len(entering)} of 6 recordings") for w in said)
    kept, _, said = apply_policy(env, states, "warn")
    assert len(kept) == 6 and any(w.startswith(f"learning from {len(entering)} recordings") for w in said)
    with pytest.raises(ObstacleEntryError, match="an obstacle of the run's world"):
        apply_policy(env, states, "refuse")
    env.close()


def test_the_one_line_worlds_compose_and_validate(tmp_path):
    """What the tutorial says first: no obstacles, or one's own scene file by name (``--config-dir``)."""
    none = resolve_and_validate(compose_cfg(["experiment=recorded_arm", "env.scene.obstacles=[]"]))
    assert none.env.scene.obstacles == [] and not [n for n in none.tree.nodes if "obstacle" in n]
    (tmp_path / "scene").mkdir()
    (tmp_path / "scene" / "my_lab.yaml").write_text(
        "# @package env.scene\nobstacles:\n  - {type: box, center: [0.3, 0.5, 0.1], half_extents: [0.05, 0.05, 0.1]}\n"
    )
    r = validate_command("--config-dir", str(tmp_path), "experiment=recorded_arm", "scene=my_lab")
    assert r.returncode == 0, r.stderr[-2000:]
    assert "cp1_obstacle1" in r.stdout and "obstacle entries: none of the 24 recordings" in r.stdout


# ------------------------------------------------------------------------------------------------ the plane
def plane_log(path: Path, disc: tuple[float, float, float]) -> tuple[Path, float]:
    """Three straight reaches to the origin at 100 Hz with a second at rest at either end, each with the disc
    ``disc`` (x, y, r) in aux columns; the second passes through it. Returns the file and how deep (m) the second
    reach's raw samples come inside the disc."""
    t = np.arange(500) * 0.01
    s = np.clip((t - 1.0) / 3.0, 0.0, 1.0)
    s = s**3 * (10 - 15 * s + 6 * s**2)
    lines = ["demo,t,x,y,ox,oy,r"]
    depth = 0.0
    for k, start in enumerate([(-0.1, 0.05), (-0.1, 0.0), (-0.1, -0.06)]):
        p = np.outer(1 - s, start)
        lines += [f"d{k},{ti:.3f},{x:.6f},{y:.6f},{disc[0]},{disc[1]},{disc[2]}" for ti, (x, y) in zip(t, p)]
        if k == 1:
            depth = disc[2] - float(np.linalg.norm(p - disc[:2], axis=1).min())
    path.write_text("\n".join(lines) + "\n")
    return path, depth


PLANE = [
    "experiment=lasa",
    "data=recorded",
    "data.demo_column=demo",
    "env.n_obstacles=1",
    "data.aux_columns={obstacle1_center: [ox, oy], obstacle1_radius: [r]}",
]


def test_on_the_plane_a_reach_through_its_disc_is_refused_with_its_depth(tmp_path):
    log, depth = plane_log(tmp_path / "reaches.csv", (-0.05, -0.005, 0.01))
    with pytest.raises(ConfigError) as refused:
        resolve_and_validate(compose_cfg([*PLANE, f"data.files=[{log}]"]))
    (issue,) = refused.value.issues
    entry = re.search(r"reaches\.csv \[demo=d1\]: .*: the position ([\d.]+) m inside obstacle1 \(disc\)", issue.message)
    assert entry is not None and "1 of 3 recordings" in issue.message, issue.message
    assert float(entry.group(1)) == pytest.approx(depth, abs=5e-4)  # the grid's spline and filter, not the raw rows
    assert "data.aux_columns" in issue.message  # the plane's discs come from the files
    run = resolve_and_validate(compose_cfg([*PLANE, f"data.files=[{log}]", "data.obstacle_entries=drop", "data.val=0"]))
    env = make_env(run)
    states = on_grid_for(read_recordings(run.data), run.data, env.dt, env.dim, run.env.type, None, env.aux_dims())
    assert [s.source for s in apply_policy(env, states, "drop")[0]] == [f"{log} [demo=d0]", f"{log} [demo=d2]"]
