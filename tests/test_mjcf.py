"""Robots described in MJCF (``type: mjcf``, rmpfusion/sims/mjcf.py): the chain rmpfusion builds from MuJoCo's
compiled model equals MuJoCo's own kinematics (mj_kinematics) on an MJCF file written for these tests, the robot
runs in both simulators, and what URDF cannot say is refused naming the body."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from rmpfusion.robots import build_robot
from rmpfusion.robots.robot import RobotField
from rmpfusion.sims import WorldSettings, open_world
from rmpfusion.sims.mjcf import MJCFDescription, MJCFError, urdf_of_mjcf

mujoco = pytest.importorskip("mujoco")

ARM = Path(__file__).parent / "data" / "mjcf" / "arm.xml"
JOINTS = ["j1", "j2", "slide", "wrist"]


def _description(**overrides) -> dict:
    return {
        "type": "mjcf",
        "name": "testarm_mjcf",
        "mjcf": str(ARM),
        "joints": JOINTS,
        "end_effector": {"link": "tool", "offset": [0.0, 0.01, 0.02]},
        "home": [0.1, 0.2, 0.05, 0.3],
        "control_points": [{"link": "link2", "offset": [0, 0, 0.12], "radius": 0.05}],
        **overrides,
    }


def _random_q(n: int, seed: int) -> np.ndarray:
    g = np.random.default_rng(seed)
    lo, hi = np.array([-2.8, -1.5, 0.0, -np.pi]), np.array([2.8, 1.5, 0.1, np.pi])
    return lo + (hi - lo) * g.random((n, 4))


def test_the_chain_equals_mujocos_kinematics():
    """Every body's frame, from rmpfusion's chain (through the URDF written from the compiled model) and from
    mj_kinematics of the MJCF itself, at 6 random configurations: to 1e-12 m / 1e-12 in rotation; the end effector's
    point too."""
    robot = build_robot(MJCFDescription.model_validate(_description()))
    m = mujoco.MjModel.from_xml_path(str(ARM))
    d = mujoco.MjData(m)
    address = [m.jnt_qposadr[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, j)] for j in JOINTS]
    worst = 0.0
    for q in _random_q(6, seed=0):
        d.qpos[address] = q
        mujoco.mj_kinematics(m, d)
        fk = robot.chain.forward_kinematics(torch.tensor(q[None]))
        for b in range(1, m.nbody):
            name = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, b)
            R, p = fk[name]
            worst = max(worst, float(np.abs(p[0].numpy() - d.xpos[b]).max()))
            worst = max(worst, float(np.abs(R[0].numpy() - d.xmat[b].reshape(3, 3)).max()))
        tool = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "tool")
        expected = d.xpos[tool] + d.xmat[tool].reshape(3, 3) @ np.array([0.0, 0.01, 0.02])
        worst = max(worst, float(np.abs(robot.ee_position(torch.tensor(q[None]))[0].numpy() - expected).max()))
    assert worst < 1e-12, worst
    assert (
        robot.params.model().joint("slide").type == "prismatic"
        and robot.params.model().joint("wrist").type == "continuous"
    )


@pytest.mark.parametrize("sim", ["pybullet", "mujoco"])
def test_an_mjcf_robot_runs_in_both_simulators(sim):
    """Its link frames in each simulator equal rmpfusion's (1e-6), and its collision geoms are there: a sphere placed
    on link2's box reads a penetration, one 10 cm away a clearance of about 10 cm."""
    from rmpfusion.sims import Obstacle, SimulatorParams

    robot = build_robot(MJCFDescription.model_validate(_description()))
    world = open_world(robot, WorldSettings(), SimulatorParams.model_validate({"type": sim}))
    try:
        q = _random_q(1, seed=3)[0]
        world.reset(q, np.zeros(4))
        fk = robot.chain.forward_kinematics(torch.tensor(q[None]))
        frames = world.link_frames()
        assert {"link1", "link2", "link3", "link4", "tool"} <= set(frames)
        for link, (position, R) in frames.items():
            assert np.abs(fk[link][1][0].numpy() - position).max() < 1e-6, (sim, link)
            assert np.abs(fk[link][0][0].numpy() - R).max() < 1e-6, (sim, link)
        R2, p2 = (x[0].numpy() for x in fk["link2"])
        on_box = p2 + R2 @ np.array([0.0, 0.0, 0.12])
        world.set_obstacles([Obstacle("sphere", on_box, radius=0.01)])
        assert world.obstacle_distance(0.3) < 0
        away = on_box + R2 @ np.array([0.03 + 0.1 + 0.01, 0.0, 0.0])  # beyond the box's 3 cm half width
        world.set_obstacles([Obstacle("sphere", away, radius=0.01)])
        assert world.obstacle_distance(0.3) == pytest.approx(0.1, abs=3e-3)
    finally:
        world.close()


def _write(tmp_path: Path, body: str) -> Path:
    path = tmp_path / "bad.xml"
    path.write_text(f"<mujoco><worldbody><body name='base'>{body}</body></worldbody></mujoco>")
    return path


@pytest.mark.parametrize(
    "body, message",
    [
        (
            "<body name='elbow'><joint name='a' axis='0 0 1'/><joint name='b' axis='0 1 0'/><geom size='.1'/></body>",
            r"body 'elbow' has 2 joints; give each joint a body of its own",
        ),
        (
            "<body name='elbow'><joint name='a' pos='0 0 .1' axis='0 0 1'/><geom size='.1'/></body>",
            r"joint 'a' sits at pos \[0\.0, 0\.0, 0\.1\] in body 'elbow'.*move the body's pos to the joint",
        ),
        (
            "<body name='elbow'><joint name='a' type='ball'/><geom size='.1'/></body>",
            r"joint 'a' of body 'elbow' is a ball or free joint",
        ),
        ("<body name='elbow'><joint name='a' axis='0 0 1'/><geom size='.1'/></body", r"MuJoCo cannot compile it"),
    ],
    ids=["two-joints", "joint-off-origin", "ball-joint", "malformed"],
)
def test_what_urdf_cannot_say_is_refused_naming_the_body(tmp_path, body, message):
    path = _write(tmp_path, body)
    with pytest.raises(MJCFError, match=message):
        urdf_of_mjcf(str(path))


def test_a_robot_file_naming_a_missing_mjcf_is_one_clear_error():
    from pydantic import BaseModel, ValidationError

    class Holder(BaseModel):
        robot: RobotField

    with pytest.raises(ValidationError, match=r"mjcf: .*nowhere\.xml.*fix mjcf: in the robot's file"):
        Holder.model_validate({"robot": _description(mjcf="nowhere.xml")})
    assert Holder.model_validate({"robot": _description()}).robot.type == "mjcf"
