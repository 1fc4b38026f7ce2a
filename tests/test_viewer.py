"""The 3D viewer (``plots/viewer.py``, ``rmpfusion-view``): the spheres where pybullet puts the links, the obstacle
meshes where their shapes are, moving obstacles where the scene moves them, the command's refusals, and the page
drawn by a real browser (headless Chromium), its screenshot's pixels checked."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pybullet
import pytest
import torch
from conftest import ROOT
from manipulators import PANDA_HOME, robot

from rmpfusion.plots.viewer import (
    EXPERT_COLOR,
    PolicyTrack,
    ViewerInput,
    control_sphere_centers,
    frame_indices,
    obstacle_mesh,
    viewer_figure,
    write_viewer,
)
from rmpfusion.robots import RobotDescription
from rmpfusion.scenes import Scene, scene_aux
from tools.viewer_screenshot import browser_missing, screenshot

F64 = torch.float64


def _panda(**changes) -> RobotDescription:
    return RobotDescription.model_validate({**robot("panda"), **changes})


# ----------------------------------------------------------------------------------------------- kinematics
@pytest.mark.parametrize("mount", [None, {"xyz": [0.3, -0.2, 0.5], "rpy": [0.2, -0.1, 0.7]}])
def test_control_spheres_sit_where_pybullet_puts_their_links(mount):
    """Each sphere centre is its link's pose (from pybullet, with the base at the mount) applied to its offset."""
    desc = _panda(mount=mount)
    qs = torch.stack([PANDA_HOME, PANDA_HOME + 0.3 * torch.linspace(-1, 1, 7)]).to(F64)
    centers, radii = control_sphere_centers(desc, qs)
    assert centers.shape == (2, len(desc.control_points), 3)
    assert radii.tolist() == [c.radius for c in desc.control_points]
    cid = pybullet.connect(pybullet.DIRECT)
    try:
        xyz, rpy = (mount["xyz"], mount["rpy"]) if mount else ([0, 0, 0], [0, 0, 0])
        body = pybullet.loadURDF(
            _urdf_file(desc), xyz, pybullet.getQuaternionFromEuler(rpy), useFixedBase=True, physicsClientId=cid
        )
        info = [
            pybullet.getJointInfo(body, i, physicsClientId=cid)
            for i in range(pybullet.getNumJoints(body, physicsClientId=cid))
        ]
        joint, link = {j[1].decode(): j[0] for j in info}, {j[12].decode(): j[0] for j in info}
        for b, q in enumerate(qs):
            for name, v in zip(desc.joints, q.tolist()):
                pybullet.resetJointState(body, joint[name], v, physicsClientId=cid)
            for c, got in zip(desc.control_points, centers[b]):
                st = pybullet.getLinkState(body, link[c.link], computeForwardKinematics=True, physicsClientId=cid)
                R = np.asarray(pybullet.getMatrixFromQuaternion(st[5])).reshape(3, 3)
                want = np.asarray(st[4]) + R @ np.asarray(c.offset)
                np.testing.assert_allclose(got.numpy(), want, atol=1e-5)
    finally:
        pybullet.disconnect(cid)


def _urdf_file(desc: RobotDescription) -> str:
    from rmpfusion.maps.urdf import resolve_urdf_path

    return resolve_urdf_path(desc.urdf)


# ------------------------------------------------------------------------------------------------- meshes
def _segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    t = np.clip(((p - a) @ (b - a)) / ((b - a) @ (b - a)), 0, 1)
    return np.linalg.norm(p - (a + t[:, None] * (b - a)), axis=1)


def test_obstacle_meshes_have_their_shapes_size_and_pose():
    scene = Scene.model_validate(
        {
            "obstacles": [
                {"type": "box", "center": [0.4, 0.1, 0.3], "half_extents": [0.1, 0.2, 0.05], "rpy": [0.3, 0.0, 0.5]},
                {"type": "cylinder", "center": [0.5, 0.0, 0.2], "radius": 0.07, "height": 0.4, "axis": [1, 1, 0]},
                {"type": "capsule", "center": [0.0, 0.5, 0.2], "radius": 0.05, "length": 0.3, "axis": [0, 1, 1]},
                {"type": "sphere", "center": [0.3, 0.3, 0.3], "radius": 0.12},
            ]
        }
    )
    box, cyl, cap, sph = scene.obstacles
    from rmpfusion.maps.kinematics import rpy_matrix

    v, _ = obstacle_mesh(box, np.array(box.center))
    local = (v - box.center) @ rpy_matrix(box.rpy).numpy()  # back into the box frame
    np.testing.assert_allclose(np.abs(local), np.broadcast_to(box.half_extents, local.shape), atol=1e-12)
    v, _ = obstacle_mesh(cyl, np.array(cyl.center))
    axis = np.array(cyl.axis) / np.linalg.norm(cyl.axis)
    along = (v - cyl.center) @ axis
    radial = np.linalg.norm((v - cyl.center) - along[:, None] * axis, axis=1)
    assert np.all(np.abs(along) <= cyl.height / 2 + 1e-12) and np.isclose(np.abs(along).max(), cyl.height / 2)
    assert np.all(np.isclose(radial, cyl.radius) | np.isclose(radial, 0))  # rim vertices, and the caps' centres
    v, _ = obstacle_mesh(cap, np.array(cap.center))
    axis = np.array(cap.axis) / np.linalg.norm(cap.axis)
    ends = np.array(cap.center) + np.outer([-1, 1], axis) * cap.length / 2
    np.testing.assert_allclose(_segment_distance(v, *ends), cap.radius, atol=1e-12)  # a capsule is a swept sphere
    v, _ = obstacle_mesh(sph, np.array(sph.center))
    np.testing.assert_allclose(np.linalg.norm(v - sph.center, axis=1), sph.radius, atol=1e-12)


def test_frames_are_a_bounded_even_subset_with_both_ends():
    assert frame_indices(5, 40) == [0, 1, 2, 3, 4]
    idx = frame_indices(101, 40)
    assert len(idx) <= 40 and idx[0] == 0 and idx[-1] == 100 and idx == sorted(set(idx))
    assert max(np.diff(idx)) <= 3


# ----------------------------------------------------------------------------------------------- the figure
def _moving_input(n_times: int = 21) -> ViewerInput:
    scene = Scene.model_validate(
        {
            "obstacles": [
                {
                    "type": "sphere",
                    "center": [0.5, 0.0, 0.4],
                    "radius": 0.1,
                    "motion": {"type": "linear", "velocity": [0, 0.2, 0]},
                },
                {"type": "cylinder", "center": [0.4, -0.3, 0.3], "radius": 0.05, "height": 0.6},
            ],
            "ground": {"height": 0.0},
        }
    )
    aux = scene_aux(scene, torch.tensor([[[0.5, 0.0, 0.4], [0.4, -0.3, 0.3]]], dtype=F64), F64)
    aux["goal"] = torch.tensor([[0.4, -0.3, 0.5]], dtype=F64)
    times = torch.linspace(0, 2.0, n_times, dtype=F64)
    q = PANDA_HOME.to(F64) + torch.linspace(0, 1, n_times, dtype=F64)[:, None] * 0.3
    q[-3:] = float("nan")  # a sample that ended early: the robot stays where it stopped
    return ViewerInput(
        robot=_panda(),
        scene=scene,
        aux=aux,
        times=times,
        tracks=[PolicyTrack("expert", q), PolicyTrack("learner @ 0", q.flip(0))],
    )


def test_figure_moves_the_spheres_and_the_moving_obstacle_over_the_recorded_times():
    inp = _moving_input()
    fig = viewer_figure(inp, max_frames=6)
    shown = frame_indices(len(inp.times), 6)
    assert [float(f.name) for f in fig.frames] == pytest.approx([float(inp.times[i]) for i in shown], abs=5e-3)
    names = [t.name for t in fig.data]
    moved = list(fig.frames[0].traces)
    assert [names[i] for i in moved] == ["expert", "learner @ 0", "obstacle 1 (sphere, moving)"]
    assert "obstacle 2 (cylinder)" in names and "ground" in names and "goal" in names
    radius = inp.scene.obstacles[0].radius
    for f, i in zip(fig.frames, shown):
        obstacle = np.c_[f.data[2].x, f.data[2].y, f.data[2].z]
        t = float(inp.times[i])
        np.testing.assert_allclose(obstacle.mean(0), [0.5, 0.2 * t, 0.4], atol=1e-5)  # centre + v·t
        assert np.allclose(np.linalg.norm(obstacle - obstacle.mean(0), axis=1), radius, atol=1e-5)
        spheres = np.c_[f.data[0].x, f.data[0].y, f.data[0].z]
        assert np.isfinite(spheres).all()
    q_last_finite = inp.tracks[0].q[-4]
    want = control_sphere_centers(inp.robot, q_last_finite[None])[0][0].numpy()  # forward-filled
    last = np.c_[fig.frames[-1].data[0].x, fig.frames[-1].data[0].y, fig.frames[-1].data[0].z].reshape(len(want), -1, 3)
    np.testing.assert_allclose(last.mean(1), want, atol=1e-4)  # every sphere's mesh centred on its centre


def test_page_is_self_contained_and_small(tmp_path):
    path = write_viewer(viewer_figure(_moving_input(), max_frames=10), tmp_path / "v.html")
    from html.parser import HTMLParser

    sources = []

    class Scripts(HTMLParser):  # script bodies are not parsed as tags: only the page's own <script> tags count
        def handle_starttag(self, tag, attrs):
            if tag in ("script", "link", "img", "iframe"):
                sources.extend(v for k, v in attrs if k in ("src", "href"))

    html = path.read_text()
    Scripts().feed(html)
    assert sources == [] and html.count("<script") >= 2  # plotly.js inlined, nothing fetched
    assert path.stat().st_size < 6e6, path.stat().st_size


# ------------------------------------------------------------------------------------------------ the browser
def _strong(img: np.ndarray, hex_color: str) -> np.ndarray:
    """Pixels whose colour is the hue of ``hex_color`` (a red here): its channel well above the others, under any
    shading."""
    rgb = np.array([int(hex_color[k : k + 2], 16) for k in (1, 3, 5)])
    main = int(rgb.argmax())
    others = [c for c in range(3) if c != main]
    return (img[..., main].astype(int) - img[..., others].max(-1).astype(int)) > 60


@pytest.mark.skipif(browser_missing() is not None, reason=f"browser test: {browser_missing()}")
def test_a_browser_draws_the_scene_without_javascript_errors(tmp_path):
    from PIL import Image

    inp = _moving_input()
    inp.tracks = inp.tracks[:1]  # the expert alone: its red must be on the screen
    page = write_viewer(viewer_figure(inp, max_frames=5), tmp_path / "v.html")
    errors = screenshot(page, tmp_path / "shot.png", size=(900, 700))
    assert errors == [], errors
    img = np.asarray(Image.open(tmp_path / "shot.png").convert("RGB"))
    red = _strong(img, EXPERT_COLOR)
    assert red.sum() > 2000, f"only {red.sum()} pixels of the spheres' red: WebGL drew no robot"
    rows, cols = np.nonzero(red)
    assert cols.max() - cols.min() > 50 and rows.max() - rows.min() > 50  # a robot, not a legend swatch


# ------------------------------------------------------------------------------------------------ the command
def _view(*args: str, cwd: Path = ROOT) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "rmpfusion.cli.view", *args],
        cwd=cwd,
        capture_output=True,
        text=True,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
        timeout=600,
    )


def test_command_refuses_what_it_cannot_draw_in_one_line(tmp_path):
    (tmp_path / "not_a_run").mkdir()
    (tmp_path / "exists.html").write_text("mine")
    cases = {
        (str(tmp_path / "nowhere"),): "is not a directory",
        (str(tmp_path / "not_a_run"),): "not a run directory",
        ("experiment=franka", "--out", str(tmp_path / "exists.html")): "exists; nothing was written",
        ("experiment=2d1level", "--out", str(tmp_path / "2d.html")): "the viewer draws robots",
        ("experiment=franka", "stray"): "give one run directory, or config overrides",
        ("experiment=frnka",): "do not compose",
    }
    for args, message in cases.items():
        r = _view(*args)
        assert r.returncode == 2 and message in r.stderr and "Traceback" not in r.stderr, (args, r.stderr)
    assert (tmp_path / "exists.html").read_text() == "mine"
    assert not (tmp_path / "2d.html").exists()


def test_command_draws_a_config_expert_and_unit_weights(tmp_path):
    out = tmp_path / "xarm6.html"
    r = _view("experiment=reach", "robot=xarm6", "--horizon", "0.2", "--out", str(out))
    assert r.returncode == 0, r.stderr
    html = out.read_text()
    for label in ('"expert"', '"unit weights"', "obstacle 1 (cylinder)", '"goal"', "xarm6"):
        assert label in html, label


def test_command_composes_with_a_config_dir_of_the_users_robot_files(tmp_path):
    """``--config-dir`` joins the config search path, so ``robot=my_panda`` is found in its robot/ folder and drawn;
    a folder that is not there, and a run directory (which carries its resolved config), are refused in one line."""
    (tmp_path / "robot").mkdir()
    panda = (ROOT / "conf" / "robot" / "panda.yaml").read_text()
    assert "\nname: panda\n" in panda
    (tmp_path / "robot" / "my_panda.yaml").write_text(panda.replace("\nname: panda\n", "\nname: my_panda\n"))
    out = tmp_path / "v.html"
    r = _view(
        "--config-dir", str(tmp_path), "experiment=franka", "robot=my_panda", "--horizon", "0.1", "--out", str(out)
    )
    assert r.returncode == 0, r.stderr
    assert "franka (config): my_panda, one test start" in out.read_text()
    (tmp_path / "not_a_run").mkdir()
    cases = {
        ("--config-dir", str(tmp_path / "nowhere"), "experiment=franka"): (
            f"error: --config-dir {tmp_path / 'nowhere'} is not a folder; give the folder your configs are in"
        ),
        ("--config-dir", str(tmp_path), str(tmp_path / "not_a_run")): (
            "error: --config-dir is for config overrides: a run directory carries its resolved config"
        ),
    }
    for args, message in cases.items():
        r = _view(*args)
        assert r.returncode == 2 and message in r.stderr and "Traceback" not in r.stderr, (args, r.stderr)
        assert len(r.stderr.strip().splitlines()) == 1, r.stderr


@pytest.mark.slow
def test_command_draws_every_snapshot_of_a_trained_run(tmp_path):
    """A tiny Franka run trained for 3 steps: the page holds the expert, the learner at both snapshots (0 and 2)
    and trained (3, from final.pt), each rolled out from the run's checkpoints; a second call refuses to replace
    the page, and a learner without checkpoints is one line."""
    from conftest import compose_cfg

    from rmpfusion.pipeline.run import run_experiment
    from rmpfusion.pipeline.validate import resolve_and_validate

    overrides = [
        "experiment=franka",
        "logger=disabled",
        "env.control_rate=60",
        "data.train_trajectories=3",
        "data.test_trajectories=2",
        "data.val_trajectories=2",
        "data.points=6",
        "env.demo_min_duration=0.2",
        "train.iterations=3",
        "train.batch_size=8",
        "train.snapshots=[0,2]",
        "train.checkpoint_every=3",
        "eval.horizon=0.5",
        "eval.compile=false",
        "eval.figures=false",
    ]
    run_experiment(resolve_and_validate(compose_cfg(overrides)), tmp_path, progress=False)
    r = _view(str(tmp_path), "--frames", "4")
    assert r.returncode == 0, r.stderr
    html = (tmp_path / "viewer.html").read_text()
    for label in ('"expert"', '"learner @ 0"', '"learner @ 2"', '"learner @ 3"', "obstacle 1 (cylinder)"):
        assert label in html, label
    again = _view(str(tmp_path))
    assert again.returncode == 2 and "exists; nothing was written" in again.stderr
    (tmp_path / "checkpoints" / "rmp").rename(tmp_path / "checkpoints" / "other")
    missing = _view(str(tmp_path), "--force")
    assert missing.returncode == 2 and "no checkpoints for learners ['rmp']" in missing.stderr, missing.stderr


def test_unit_weights_put_one_on_every_edge_the_tree_weights():
    """The tree the viewer calls "unit weights" (RMPflow) has w = 1 on every edge, also where the run's tree spec
    carries weights of its own (the generated Franka tree starts an MLP on every edge)."""
    from conftest import compose_cfg

    from rmpfusion.evaluate.weights import edge_weights
    from rmpfusion.pipeline.construct import build_unit_weights, make_env
    from rmpfusion.pipeline.validate import resolve_and_validate

    run = resolve_and_validate(compose_cfg(["experiment=franka"]))
    assert run.tree.model_dump().get("shared_weights"), "the case this test is about: a tree spec with weights"
    env = make_env(run)
    tree = build_unit_weights(run, env.aux_dims())
    gen = torch.Generator().manual_seed(0)
    q, qd, aux = env.sample_initial_states(env.sample_envs(2, gen), 3, gen)
    qd = qd + 0.1 * torch.randn(qd.shape, generator=gen, dtype=qd.dtype)
    edges = list(tree.weights)
    assert "attractor" not in edges  # its own weight removed: an edge without one has w = 1
    assert len(edges) == len(run.env.robot.control_points)  # each control point's shared obstacle weight, now 1
    for e, w in edge_weights(tree, q, qd, aux, edges).items():
        assert torch.allclose(w, torch.ones_like(w)), (e, w)
