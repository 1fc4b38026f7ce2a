"""Robot descriptions (conf/robot/, rmpfusion/robots/): every robot's kinematics agrees with pybullet, builds the
Fig. 1b tree and runs in pybullet; descriptions are checked against their URDF; rmpfusion-fit-spheres fits
spheres that cover a URDF's collision geometry and writes a description that loads."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml

pybullet = pytest.importorskip("pybullet")

from manipulators import CONF, robot

import rmpfusion
from rmpfusion.cli.fit_spheres import main as fit_spheres
from rmpfusion.envs.manipulator import Manipulator
from rmpfusion.envs.manipulator_tree import manipulator_tree_spec, with_weights
from rmpfusion.maps.urdf import resolve_urdf_path
from rmpfusion.robots import RobotDescription, build_robot

F64 = torch.float64
ROBOTS = sorted(p.stem for p in (CONF / "robot").glob("*.yaml"))
ONE_SPHERE = {"obstacles": [{"type": "sphere", "center": [0.5, 0.0, 0.3], "radius": 0.05}]}


def test_the_three_robots_are_described():
    assert {"panda", "iiwa", "xarm6"} <= set(ROBOTS)


@pytest.mark.parametrize("name", ROBOTS)
def test_kinematics_agree_with_pybullet(name):
    """Every link frame and the end effector at random configurations, against pybullet's own forward kinematics of
    the same URDF (to 1e-6 m; the held joints at 0 on both sides)."""
    r = build_robot(RobotDescription.model_validate(robot(name)))
    cid = pybullet.connect(pybullet.DIRECT)
    try:
        body = pybullet.loadURDF(r.urdf_path, *r.base_pose(), useFixedBase=True, physicsClientId=cid)
        index = {
            pybullet.getJointInfo(body, i, physicsClientId=cid)[1].decode(): i
            for i in range(pybullet.getNumJoints(body, physicsClientId=cid))
        }
        arm = [index[j] for j in r.params.joints]
        links = {pybullet.getJointInfo(body, i, physicsClientId=cid)[12].decode(): i for i in arm}
        g = torch.Generator().manual_seed(0)
        lo, hi = r.lower.clamp(min=-math.pi), r.upper.clamp(max=math.pi)
        q = lo + torch.rand(5, r.dof, generator=g, dtype=F64) * (hi - lo)
        ours = r.chain.forward_kinematics(q, list(links))
        worst = 0.0
        for b in range(q.shape[0]):
            for i, j in enumerate(arm):
                pybullet.resetJointState(body, j, float(q[b, i]), physicsClientId=cid)
            for link, idx in links.items():
                state = pybullet.getLinkState(body, idx, computeForwardKinematics=True, physicsClientId=cid)
                worst = max(worst, float((ours[link][1][b] - torch.tensor(state[4], dtype=F64)).abs().max()))
            ee = pybullet.getLinkState(
                body, links.get(r.params.end_effector.link, arm[-1]), computeForwardKinematics=True, physicsClientId=cid
            )
            if r.params.end_effector.link in links:
                R = torch.tensor(pybullet.getMatrixFromQuaternion(ee[5]), dtype=F64).reshape(3, 3)
                expected = torch.tensor(ee[4], dtype=F64) + R @ r.ee_offset
                worst = max(worst, float((r.ee_position(q[b : b + 1])[0] - expected).abs().max()))
        assert worst < 1e-6, worst
    finally:
        pybullet.disconnect(cid)


@pytest.mark.parametrize("name", ROBOTS)
def test_every_robot_builds_the_tree_and_runs_in_pybullet(name):
    env = Manipulator(
        robot=robot(name),
        scene=ONE_SPHERE,
        control_rate=100.0,
        goal_region=[[0.3, 0.4], [-0.3, -0.2], [0.3, 0.4]],
        goal_clearance=0.05,
        start_spread=0.05,
        start_clearance=0.0,
    )
    spec = manipulator_tree_spec(robot(name), ONE_SPHERE)
    n_cp = len(robot(name)["control_points"])
    assert sum(n.endswith("_obstacle1") for n in spec["nodes"]) == n_cp and spec["root"]["dim"] == env.dim
    tree = rmpfusion.build_tree(with_weights(spec, {"attractor": 40.0}), aux_dims=env.aux_dims())
    q0, qd0, aux = env.sample(1, 2, seed=0)
    with torch.no_grad():
        ro = env.rollout(tree, q0, qd0, aux, horizon=0.2, record_every=0.1, mode="torque")
    env.close()
    assert ro.error == [None, None] and ro.q.shape == (3, 2, env.dim) and ro.q.isfinite().all()
    assert (ro.q[-1] - ro.q[0]).abs().max() > 1e-4  # it moved
    assert (ro.V[1:] <= ro.V[:-1] + 1e-6 * ro.V[:-1].abs()).all()  # Theorem 2 on the way


def test_descriptions_are_checked_against_the_urdf():
    panda = robot("panda")
    with pytest.raises(
        ValueError,
        match=r"joints\[6\] = 'panda_joint_7' is not a movable joint of "
        r"pkg://pybullet_data/franka_panda/panda.urdf; did you mean 'panda_joint7'",
    ):
        RobotDescription.model_validate({**panda, "joints": panda["joints"][:6] + ["panda_joint_7"]})
    with pytest.raises(ValueError, match=r"home: panda_joint4 = 1.0 lies outside its limits \[-3.1416, 0.0\]"):
        RobotDescription.model_validate({**panda, "home": [1.0] * 7})
    with pytest.raises(ValueError, match=r"limits.panda_joint9: not an actuated joint"):
        RobotDescription.model_validate({**panda, "limits": {"panda_joint9": {"upper": 1.0}}})
    # overrides replace the URDF's limits key by key
    d = RobotDescription.model_validate({**panda, "limits": {"panda_joint1": {"upper": 1.0, "velocity": 0.5}}})
    lo, hi, vel = d.joint_limits()[0]
    assert (hi, vel) == (1.0, 0.5) and lo == pytest.approx(-2.9671)
    with pytest.raises(FileNotFoundError, match=r"no installed Python package 'no_such_package'"):
        resolve_urdf_path("pkg://no_such_package/robot.urdf")


ARM_URDF = """<robot name="two_boxes">
  <link name="base"><collision><geometry><box size="0.2 0.2 0.1"/></geometry></collision></link>
  <link name="upper"><collision><origin xyz="0 0 0.2"/><geometry><cylinder radius="0.04" length="0.4"/></geometry>
    </collision></link>
  <link name="fore"><collision><origin xyz="0.15 0 0" rpy="0 1.5708 0"/><geometry><box size="0.06 0.06 0.3"/>
    </geometry></collision></link>
  <joint name="shoulder" type="revolute"><parent link="base"/><child link="upper"/><origin xyz="0 0 0.05"/>
    <axis xyz="0 0 1"/><limit lower="-2" upper="2" velocity="1" effort="1"/></joint>
  <joint name="elbow" type="revolute"><parent link="upper"/><child link="fore"/><origin xyz="0 0 0.4"/>
    <axis xyz="0 1 0"/><limit lower="-1.5" upper="1.5" velocity="1" effort="1"/></joint>
</robot>"""


def test_fit_spheres_covers_the_collision_geometry_and_writes_a_description(tmp_path, capsys):
    urdf = tmp_path / "arm.urdf"
    urdf.write_text(ARM_URDF)
    out, fig = tmp_path / "arm.yaml", tmp_path / "coverage.png"
    args = [
        str(urdf),
        "--name",
        "arm",
        "--joints",
        "shoulder",
        "elbow",
        "--ee-link",
        "fore",
        "--ee-offset",
        "0.3",
        "0",
        "0",
        "--spheres",
        "3",
        "--out",
        str(out),
        "--figure",
        str(fig),
    ]
    assert fit_spheres(args) == 0
    said = capsys.readouterr().out
    assert "upper: 3 spheres" in said and "fore: 3 spheres" in said and "base" not in said  # the base does not move
    coverage = float(said.split("all: 6 spheres, coverage ")[1].split(" %")[0])
    assert coverage >= 99.0 and "(meets the 99 % target)" in said
    written = yaml.safe_load(out.read_text())
    d = RobotDescription.model_validate(written)  # what the command wrote is a valid description
    assert [c.link for c in d.control_points] == ["upper"] * 3 + ["fore"] * 3 and d.home == [0.0, 0.0]
    assert out.read_text().startswith("# @package env.robot\n") and fig.stat().st_size > 0
    # never over an existing file without --force
    assert fit_spheres(args) == 2 and "exists; choose another --out or add --force" in capsys.readouterr().err
    # --check measures a description's spheres: halving every radius loses coverage
    small = {**written, "control_points": [{**c, "radius": c["radius"] / 2} for c in written["control_points"]]}
    (tmp_path / "small.yaml").write_text(yaml.safe_dump(small))
    assert fit_spheres(["--check", str(tmp_path / "small.yaml")]) == 0
    low = float(capsys.readouterr().out.split("coverage ")[-1].split(" %")[0])
    assert low < 90.0 and "misses" not in said


@pytest.mark.parametrize(
    "tag, given, missing",
    [("cylinder", 'length="0.4"', "radius"), ("cylinder", 'radius="0.04"', "length"), ("sphere", "", "radius")],
)
def test_a_primitive_without_its_size_is_refused_naming_the_link_and_the_attribute(tmp_path, tag, given, missing):
    """A collision cylinder or sphere lacking a size URDF requires is a ValueError naming the link, the element
    and the attribute, not a failed conversion of nothing to a number."""
    from rmpfusion.robots.geometry import link_geometry

    urdf = tmp_path / "arm.urdf"
    urdf.write_text(ARM_URDF.replace('<cylinder radius="0.04" length="0.4"/>', f"<{tag} {given}/>"))
    with pytest.raises(ValueError, match=f"link 'upper': <{tag}> has no '{missing}', which URDF requires"):
        link_geometry(str(urdf))


def test_fit_spheres_measures_coverage_on_fresh_samples():
    """Coverage is measured on points the fit never saw: a fit with one small sphere per link cannot score 100 %."""
    from rmpfusion.robots.spheres import covered_by, kmeans

    pts = np.random.default_rng(0).uniform(-1, 1, (500, 3))
    c = kmeans(pts, 4, seed=0)
    assert c.shape == (4, 3)
    assert covered_by(pts, c, np.full(4, 10.0)).all() and not covered_by(pts, c, np.full(4, 0.01)).any()


PUBLISHED = ["ur5", "kinova", "xarm7", "so101"]  # URDFs and meshes as example-robot-data ships them


def test_published_arms_differ_in_joints_and_mesh_formats():
    import xml.etree.ElementTree as ET

    descriptions = {name: RobotDescription.model_validate(robot(name)) for name in PUBLISHED}
    assert len({len(d.joints) for d in descriptions.values()}) >= 3  # 5, 6 and 7 joints
    formats = set()
    for d in descriptions.values():
        root = ET.parse(resolve_urdf_path(d.urdf)).getroot()
        formats |= {Path(m.get("filename")).suffix.lower() for m in root.iter("mesh")}
        assert all(m.get("filename").startswith("package://") for m in root.iter("mesh"))  # as published
    assert {".stl", ".dae"} <= formats


@pytest.mark.parametrize("name", PUBLISHED)
def test_published_arms_find_starts_above_a_table(name):
    """Starts around the robot file's home, clear of a table at z = 0 by the default start_clearance (0.05 m): the
    UR5's shoulder, 2.3 cm above the table whatever its angle, used to refuse every one."""
    env = Manipulator(robot=robot(name), scene={"ground": {"height": 0.0}}, start_spread=0.2)
    try:
        g = torch.Generator().manual_seed(0)
        q0, _, aux = env.sample_initial_states(env.sample_envs(2, g), 3, g)
        assert q0.shape == (6, env.dim) and bool((env.start_margin(q0, aux) >= 0).all())
        assert bool((env.clearance(q0, aux) > 0).all())
    finally:
        env.close()


def test_every_environment_setting_is_listed_in_conf_env_manipulator():
    """So each is set as env.<key>=<value>, never +env.<key>; robot, scene and sim come from their groups."""
    from rmpfusion.envs.manipulator import ManipulatorParams

    listed = set(yaml.safe_load((CONF / "env" / "manipulator.yaml").read_text()))
    assert set(ManipulatorParams.model_fields) - {"robot", "scene", "sim"} <= listed - {"type"}
    from rmpfusion.cli.preflight import check_command_line

    check_command_line(
        str(CONF),
        [
            "experiment=reach",
            "robot=xarm6",
            "env.start_clearance=0.03",
            "env.max_tries=50",
            "env.robot.home=[0.8,0.3,-1.2,0.0,0.9,0.0]",
        ],
    )
