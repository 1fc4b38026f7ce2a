"""A robot as ROS packages publish it (tests/robot_package.py: package:// STL and DAE meshes, a millimetre mesh, a
continuous, a prismatic and a mimic joint, a fixed end-effector frame, a first link near the ground, a mounted base)
through fit-spheres, the robot file, the kinematics (against pybullet and finite differences) and the environment's
start sampling; and every way a published URDF used to fail, as one line naming the fix."""

from __future__ import annotations

import math
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml

pytest.importorskip("pybullet")
pytest.importorskip("trimesh")
pytest.importorskip("collada")

from conftest import CONF
from robot_package import JOINTS, MOUNT, PACKAGE, random_q, write_package

from rmpfusion.cli import fit_spheres
from rmpfusion.maps.kinematics import ForwardKinematics
from rmpfusion.robots import RobotDescription, build_robot
from rmpfusion.robots.packages import mesh_path, package_dir, resolved_urdf


@pytest.fixture(scope="module")
def package(tmp_path_factory) -> Path:
    return write_package(tmp_path_factory.mktemp("ros"))


@pytest.fixture(scope="module")
def fitted(package, tmp_path_factory) -> tuple[dict, str]:
    """The robot file rmpfusion-fit-spheres writes for the package's URDF (nothing but the URDF's path given), with
    a mount added by hand; and what the fit printed."""
    import contextlib
    import io

    out = tmp_path_factory.mktemp("conf") / "robot" / "testarm.yaml"
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        rc = fit_spheres.main(
            [str(package), "--name", "testarm", "--joints", *JOINTS, "--ee-link", "tool", "--out", str(out)]
        )
    assert rc == 0, printed.getvalue()
    data = yaml.safe_load(out.read_text())
    data["mount"] = MOUNT
    return data, printed.getvalue()


def _fit_error(argv: list[str], capsys) -> str:
    rc = fit_spheres.main(argv)
    err = capsys.readouterr().err.strip()
    assert rc == 2 and err.startswith("error: ") and "\n" not in err and "Traceback" not in err, err
    return err


def test_fit_reads_every_mesh_format_and_says_which_links_it_covered_by_their_visuals(fitted):
    data, printed = fitted
    links = {cp["link"] for cp in data["control_points"]}
    assert links == {"link1", "link2", "link3", "link4", "link5", "link6"}  # STL, DAE, mm STL, primitives, visual
    assert "coverage 100.00 %" in printed.splitlines()[-4] or "meets the 99 % target" in printed
    assert "links covered by their visual geometry (they have no collision geometry): link6" in printed
    assert "home [" in printed  # proposed, none was given
    link3 = [cp for cp in data["control_points"] if cp["link"] == "link3"]
    assert all(cp["radius"] < 0.15 for cp in link3)  # metres: the millimetre mesh was scaled (else ~75 m spheres)
    assert data["packages"] == {PACKAGE: None}  # found above the URDF: listed, to be set on a command line


def test_package_search_order_and_resolved_copy(package, tmp_path, monkeypatch):
    urdf = str(package)
    found, _ = package_dir(PACKAGE, urdf)
    assert Path(found) == package.parent.parent  # the folder above the URDF holding the package.xml
    # an explicit folder comes first; ROS_PACKAGE_PATH before the folders above the URDF
    copy = tmp_path / "elsewhere" / PACKAGE
    shutil.copytree(package.parent.parent, copy)
    assert Path(package_dir(PACKAGE, urdf, {PACKAGE: str(copy)})[0]) == copy
    monkeypatch.setenv("ROS_PACKAGE_PATH", str(tmp_path / "elsewhere"))
    assert Path(package_dir(PACKAGE, urdf)[0]) == copy
    monkeypatch.delenv("ROS_PACKAGE_PATH")
    monkeypatch.setenv("AMENT_PREFIX_PATH", str(tmp_path / "prefix"))
    (tmp_path / "prefix" / "share").mkdir(parents=True)
    shutil.copytree(copy, tmp_path / "prefix" / "share" / PACKAGE)
    assert Path(package_dir(PACKAGE, urdf)[0]) == tmp_path / "prefix" / "share" / PACKAGE
    monkeypatch.delenv("AMENT_PREFIX_PATH")
    assert mesh_path("file://" + str(copy / "meshes" / "link1.stl"), "link1", urdf) == str(
        copy / "meshes" / "link1.stl"
    )
    assert mesh_path("../meshes/link1.stl", "link1", urdf) == str(package.parent.parent / "meshes" / "link1.stl")
    # the copy simulators load: every mesh absolute, the same file for the same URDF
    monkeypatch.setenv("RMPFUSION_CACHE", str(tmp_path / "cache"))
    resolved = resolved_urdf(urdf)
    assert resolved == resolved_urdf(urdf) and Path(resolved).parent == tmp_path / "cache" / "urdf"
    text = Path(resolved).read_text()
    assert "package://" not in text and str(package.parent.parent / "meshes" / "link2.dae") in text


def test_kinematics_with_a_mount_and_a_mimic_joint_agree_with_pybullet(fitted):
    """Every link's world position: rmpfusion's chain (mount, mimic follower) against pybullet's (the resolved copy
    loaded at the mount, the follower driven), at random configurations."""
    from rmpfusion.envs.manipulator.worlds import TaskWorld
    from rmpfusion.sims import SimulatorParams, WorldSettings

    robot = build_robot(RobotDescription.model_validate(fitted[0]))
    world = TaskWorld(robot, WorldSettings(), SimulatorParams(type="pybullet"))
    try:
        worst = 0.0
        for q in random_q(8, seed=1):
            world.reset(q)
            fk = robot.chain.forward_kinematics(torch.tensor(q[None]))
            for link, (position, _) in world.sim.link_frames().items():
                worst = max(worst, float(np.abs(fk[link][1][0].numpy() - position).max()))
        assert worst < 1e-6, worst
        held = world.sim.state()[0][robot.dof :]
        finger = held[robot.held_joints().index("finger")]  # the joint that turns link6
        assert finger == pytest.approx(0.5 * q[4] + 0.1)  # the follower where its <mimic> puts it
    finally:
        world.close()


def test_mimic_jacobian_and_curvature_match_finite_differences(fitted):
    data = fitted[0]
    fk = ForwardKinematics(
        ForwardKinematics.Params(
            urdf=data["urdf"], joints=JOINTS, link="link6", offset=[0.01, 0.02, 0.04], mount=MOUNT
        ),
        in_dim=5,
    )
    gen = torch.Generator().manual_seed(0)
    q = torch.tensor(random_q(3, seed=2))
    qd = torch.randn(3, 5, generator=gen, dtype=torch.float64)
    y, _, J, Jdqd = fk(q, qd)
    h = 1e-6
    J_fd = torch.stack([(fk.psi(q + h * e) - fk.psi(q - h * e)) / (2 * h) for e in torch.eye(5, dtype=q.dtype)], -1)
    assert torch.allclose(J, J_fd, atol=1e-8)
    assert float(J[:, :, 4].norm()) > 0.01  # the thumb moves link6 through its own joint and the follower's
    h = 1e-4  # ÿ along q(t) = q + t q̇ (no acceleration) is J̇q̇
    acc = (fk.psi(q + h * qd) - 2 * y + fk.psi(q - h * qd)) / h**2
    assert torch.allclose(Jdqd, acc, atol=1e-5)
    frozen = ForwardKinematics(ForwardKinematics.Params(urdf=data["urdf"], joints=JOINTS[:4], link="link6"), in_dim=4)
    assert not torch.allclose(frozen.psi(q[:, :4]), fk.psi(q)[:, :], atol=1e-3)  # without the leader: frozen, offset


def test_start_sampling_ignores_a_link_that_no_joint_can_lower(fitted):
    """link1 spins about z 2 cm above the ground (under start_clearance 0.05): starts are still found, and every link
    that can move down is checked."""
    from rmpfusion.envs.manipulator import Manipulator

    env = Manipulator(
        robot=fitted[0],
        scene={"ground": {"height": 0.0}},
        mode="kinematic",
        goal_region=((0.3, 0.35), (-0.2, -0.15), (0.2, 0.25)),
        start_spread=0.2,
    )
    try:
        world = env.checker()
        assert "link1" not in world.ground_reach and "link2" in world.ground_reach
        g = torch.Generator().manual_seed(0)
        q0, _, aux = env.sample_initial_states(env.sample_envs(2, g), 2, g)
        assert q0.shape == (4, 5) and bool((env.start_margin(q0, aux) >= 0).all())
    finally:
        env.close()


def test_start_sampling_failure_names_the_robot_files_home(fitted):
    from rmpfusion.envs.manipulator import Manipulator

    env = Manipulator(
        robot=fitted[0],
        scene={"ground": {"height": 0.0}},
        mode="kinematic",
        start_clearance=5.0,
        clearance_query=6.0,
        max_tries=2,
    )
    try:
        g = torch.Generator().manual_seed(0)
        with pytest.raises(
            RuntimeError,
            match=r"move the starts' centre \(home in the robot file of testarm, "
            r"env.robot.home\), or change env.start_spread or env.start_clearance",
        ):
            env.sample_initial_states(env.sample_envs(1, g), 1, g)
    finally:
        env.close()


def test_every_published_failure_is_one_line(package, tmp_path, capsys, monkeypatch):
    base = ["--name", "t", "--joints", *JOINTS, "--ee-link", "tool", "--out", str(tmp_path / "t.yaml")]
    broken = tmp_path / "broken"
    shutil.copytree(package.parent.parent, broken / PACKAGE)
    urdf = str(broken / PACKAGE / "urdf" / "testarm.urdf")
    (broken / PACKAGE / "meshes" / "link2.dae").unlink()
    err = _fit_error([urdf, *base], capsys)
    assert (
        "link 'link2': mesh 'package://testarm_description/meshes/link2.dae' not found; looked in: " in err
        and f"{broken / PACKAGE} (above the URDF)" in err
        and "--package-dir NAME=PATH" in err
    )
    # only the fitted links' meshes are read: without link2 among them, the missing file is never opened
    assert fit_spheres.main([urdf, *base, "--links", "link1", "link3", "--force"]) == 0
    capsys.readouterr()
    (broken / PACKAGE / "meshes" / "link2.dae").write_text("<COLLADA>not a mesh")
    assert "link 'link2': mesh " in _fit_error([urdf, *base, "--force"], capsys)
    # two folders for one package at one step
    for k in (1, 2):
        shutil.copytree(package.parent.parent, tmp_path / f"ws{k}" / PACKAGE)
    monkeypatch.setenv("ROS_PACKAGE_PATH", os.pathsep.join(str(tmp_path / f"ws{k}") for k in (1, 2)))
    err = _fit_error([str(package), *base, "--force"], capsys)
    assert (
        f"package 'testarm_description' is found twice by ROS_PACKAGE_PATH: {tmp_path / 'ws1' / PACKAGE} and "
        f"{tmp_path / 'ws2' / PACKAGE}" in err
    )
    monkeypatch.delenv("ROS_PACKAGE_PATH")
    # xacro, a follower listed as actuated, a --package-dir without '='
    xacro = tmp_path / "arm.urdf.xacro"
    xacro.write_text(
        '<robot name="a" xmlns:xacro="http://www.ros.org/wiki/xacro"><xacro:property name="l" '
        'value="1"/><link name="b"/></robot>'
    )
    assert "run xacro first" in _fit_error([str(xacro), *base, "--force"], capsys)
    err = _fit_error([str(package), *base[:3], "spin", "finger", *base[3 + len(JOINTS) :], "--force"], capsys)
    assert "'finger' follows 'thumb' (URDF <mimic>), so it cannot be actuated on its own; list 'thumb'" in err
    assert "write NAME=PATH" in _fit_error([str(package), *base, "--package-dir", "x", "--force"], capsys)
    bad_dir = str(tmp_path / "nowhere")
    assert f"packages.testarm_description = '{bad_dir}': no folder" in _fit_error(
        [str(package), *base, "--package-dir", f"{PACKAGE}={bad_dir}", "--force"], capsys
    )


def _rmpfusion(module: str, conf: Path, *overrides: str, timeout: int = 600):
    import subprocess
    import sys

    root = Path(__file__).resolve().parents[1]
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join([str(root), os.environ.get("PYTHONPATH", "")]),
        "WANDB_MODE": "disabled",
        "MPLBACKEND": "Agg",
    }
    return subprocess.run(
        [sys.executable, "-m", f"rmpfusion.cli.{module}", "--config-dir", str(conf), *overrides],
        cwd=root,
        env=env,
        capture_output=True,
        text=True,
        timeout=timeout,
    )


@pytest.fixture(scope="module")
def config_dir(fitted, tmp_path_factory) -> Path:
    """The user's folder of configs: the fitted robot file (with its mount) as robot/testarm.yaml."""
    conf = tmp_path_factory.mktemp("user_conf")
    (conf / "robot").mkdir()
    (conf / "robot" / "testarm.yaml").write_text("# @package env.robot\n" + yaml.safe_dump(fitted[0], sort_keys=False))
    return conf


def test_the_fitted_robot_validates_with_a_shipped_experiment(config_dir, tmp_path):
    done = _rmpfusion(
        "validate",
        config_dir,
        "experiment=reach",
        "robot=testarm",
        f"env.robot.packages.{PACKAGE}={config_dir / 'nowhere'}",
        f"hydra.run.dir={tmp_path}",
    )
    assert (
        done.returncode != 0
        and f"packages.{PACKAGE} = '{config_dir / 'nowhere'}': no folder" in done.stderr
        and "Traceback" not in done.stderr
    ), done.stderr
    package_root = Path(yaml.safe_load((config_dir / "robot" / "testarm.yaml").read_text())["urdf"]).parents[1]
    done = _rmpfusion(
        "validate",
        config_dir,
        "experiment=reach",
        "robot=testarm",
        "env.start_clearance=0.04",
        f"env.robot.packages.{PACKAGE}={package_root}",
        f"hydra.run.dir={tmp_path}",
    )
    assert done.returncode == 0, done.stderr
    assert "OK: the configuration is valid and builds" in done.stdout


@pytest.mark.slow
def test_the_fitted_robot_runs_a_tiny_experiment(config_dir, tmp_path):
    done = _rmpfusion(
        "run",
        config_dir,
        "experiment=reach",
        "robot=testarm",
        "data=tiny",
        "train=tiny",
        "eval=fast",
        "logger=disabled",
        "eval.compile=false",
        f"hydra.run.dir={tmp_path}",
    )
    assert done.returncode == 0, done.stderr[-2000:]
    assert (tmp_path / "metrics.json").is_file()


@pytest.mark.parametrize("sim", ["pybullet", "mujoco"])
def test_a_mimic_joint_follows_its_leader_under_computed_torque(fitted, sim):
    """In torque mode the follower is driven (its leader's acceleration fed forward, PD on the rest) to
    multiplier · q_leader + offset while the leader swings, in either simulator."""
    pytest.importorskip(sim)
    from rmpfusion.envs.manipulator.worlds import TaskWorld
    from rmpfusion.sims import SimulatorParams, WorldSettings

    robot = build_robot(RobotDescription.model_validate(fitted[0]))
    world = TaskWorld(robot, WorldSettings(timestep=0.002), SimulatorParams(type=sim))
    try:
        world.reset(np.array([0.0, 0.3, 0.05, 0.2, -0.5]))
        q, _ = world.sim.state()
        assert q[5] == pytest.approx(0.5 * -0.5 + 0.1)
        worst = 0.0
        for k in range(250):  # 0.5 s of the thumb accelerating back and forth
            a = np.zeros(5)
            a[4] = 4.0 * math.cos(8.0 * k * 0.002)
            world.step_computed_torque(a, robot.params.held_joint_gains)
            q, _ = world.sim.state()
            worst = max(worst, abs(q[5] - (0.5 * q[4] + 0.1)))
        assert abs(q[4] + 0.5) > 0.05 and worst < 1e-3, worst  # it moved, and the finger with it
    finally:
        world.close()


def test_an_srdf_exempts_link_pairs_from_self_collision(fitted, tmp_path):
    from rmpfusion.envs.manipulator_tree import self_collision_pairs

    srdf = tmp_path / "testarm.srdf"
    srdf.write_text('<robot name="testarm"><disable_collisions link1="link2" link2="link5" reason="Never"/></robot>')
    plain = RobotDescription.model_validate(fitted[0])
    exempt = RobotDescription.model_validate({**fitted[0], "srdf": str(srdf)})
    links = lambda pairs, d: {frozenset((d.control_points[i - 1].link, d.control_points[j - 1].link)) for i, j in pairs}
    before, after = links(self_collision_pairs(plain, 2)[0], plain), links(self_collision_pairs(exempt, 2)[0], exempt)
    assert frozenset(("link2", "link5")) in before and before - after == {frozenset(("link2", "link5"))}
    srdf.write_text('<robot name="testarm"><disable_collisions link1="link2" link2="lnk5" reason="Never"/></robot>')
    with pytest.raises(ValueError, match="names 'lnk5', not a link of .*did you mean 'link5'"):
        RobotDescription.model_validate({**fitted[0], "srdf": str(srdf)})


def test_the_generated_tree_carries_the_mount_and_no_ground_edge_for_spheres_no_joint_lowers(fitted):
    from rmpfusion.envs.manipulator_tree import manipulator_tree_spec
    from rmpfusion.robots.home import spheres_at_fixed_height

    spec = manipulator_tree_spec(fitted[0], {"ground": {"height": 0.0}})
    maps = [n["map"] for n in spec["nodes"].values() if n.get("map", {}).get("type") == "forward_kinematics"]
    assert maps and all(m["mount"] == MOUNT for m in maps)
    still = spheres_at_fixed_height(RobotDescription.model_validate(fitted[0]))
    cps = fitted[0]["control_points"]
    assert [cps[i]["link"] for i in still] == ["link1", "link1"]  # the spinning link's two spheres
    grounded = {name.split("_")[0] for name in spec["nodes"] if name.endswith("_ground")}
    assert grounded == {f"cp{i + 1}" for i in range(len(cps)) if i not in still}


def test_a_sphere_below_the_ground_in_every_configuration_gets_no_ground_edge():
    """The UR5 as published (example-robot-data): its upper arm's fitted sphere, 17 cm across beside the shoulder
    axis, reaches below the table whatever the joints do. A ground barrier there would act at full strength wherever
    the arm is (the expert reached 3 of 20 validation goals with it): the generated tree gives it no ground edge,
    while every sphere that can clear the ground keeps one."""
    import yaml

    from rmpfusion.envs.manipulator_tree import manipulator_tree_spec
    from rmpfusion.robots.home import (
        sampled_configurations,
        sphere_heights,
        spheres_at_fixed_height,
        spheres_never_clear_of,
    )

    data = yaml.safe_load((CONF / "robot" / "ur5.yaml").read_text())  # example-robot-data: the dev extra
    ur5 = RobotDescription.model_validate(data)
    lowest = sphere_heights(ur5, sampled_configurations(ur5, 4096, seed=1))  # more samples than the rule takes
    below = {i for i, top in enumerate(lowest.max(0).values.tolist()) if top < 0.0}
    never = set(spheres_never_clear_of(ur5))
    assert never == below and [ur5.control_points[i].link for i in sorted(never)] == ["shoulder_link", "upper_arm_link"]
    skipped = never | set(spheres_at_fixed_height(ur5))
    spec = manipulator_tree_spec(data, {"ground": {"height": 0.0}})
    grounded = {name.split("_")[0] for name in spec["nodes"] if name.endswith("_ground")}
    assert grounded == {f"cp{i + 1}" for i in range(len(ur5.control_points)) if i not in skipped}
