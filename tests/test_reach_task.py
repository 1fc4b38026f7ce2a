"""The reaching task for any arm (experiment=reach): the expert's weights by role, the task laid out from the arm's
kinematics with its obstacle in the way, and the run saying so before it trains."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import pytest
import torch

pytest.importorskip("pybullet")

from manipulators import robot, scene

from rmpfusion.assembly.errors import ConfigError
from rmpfusion.assembly.weighting import own_weights, weights_by_name
from rmpfusion.envs.manipulator import Manipulator
from rmpfusion.envs.manipulator.layout import ReachLayout
from rmpfusion.envs.manipulator_tree import manipulator_tree_spec
from rmpfusion.pipeline.collect import check_task
from rmpfusion.pipeline.compose import compose_run
from rmpfusion.scenes.crossing import summarize

CONF = Path(__file__).resolve().parents[1] / "conf"
ROBOTS = sorted(p.stem for p in (CONF / "robot").glob("*.yaml"))


EXPERT = {
    "attractor": {"type": "constant", "value": 40.0},
    "obstacle": {"type": "constant", "value": 200.0},
    "ground": {"type": "constant", "value": 100.0},
}


def _validated(*overrides: str):
    return compose_run(["logger=disabled", *overrides], conf=CONF)


@pytest.mark.parametrize("name", ["panda", "xarm6"])
def test_an_expert_by_role_weights_every_control_point_of_any_arm(name):
    spec = manipulator_tree_spec(robot(name), scene("reach_post"))
    n = len(robot(name)["control_points"])
    named = weights_by_name(spec, {**EXPERT, "cp2_obstacle": {"type": "constant", "value": 7.0}})
    assert sorted(own_weights(spec)) == sorted(named)  # every weighted entry, nothing else
    assert [k for k in named if k.endswith("_obstacle")] == [f"cp{i}_obstacle" for i in range(1, n + 1)]
    assert named["cp2_obstacle"]["value"] == 7.0 and named["cp1_obstacle"]["value"] == 200.0  # a name beats its role
    assert named["ground"]["value"] == 100.0 and named["attractor"]["value"] == 40.0


def test_an_expert_that_leaves_a_weighted_edge_out_is_refused_naming_it():
    with pytest.raises(ConfigError) as e:
        _validated("experiment=reach", "robot=xarm6", "~expert.ground")
    assert "no expert weight for ground (role ground)" in str(e.value)
    run = _validated("experiment=reach", "robot=xarm6")
    assert {"attractor", "ground", *(f"cp{i}_obstacle" for i in range(1, 11))} == set(run.expert)


@pytest.mark.parametrize("name", ROBOTS)
def test_the_layout_puts_the_obstacle_in_the_way_of_most_reaches_on_every_robot(name):
    # the environment as experiment=reach sets it (conf/experiment/reach.yaml): every trajectory its own goal
    env = Manipulator(
        robot=robot(name),
        scene=scene("reach_post"),
        reach_layout=ReachLayout(),
        start_spread=0.25,
        goal_clearance=0.05,
        goal_per_trajectory=True,
    )
    try:
        g = torch.Generator().manual_seed(0)
        q0, _, aux = env.sample_initial_states(env.sample_envs(3, g), 20, g)
        s = summarize(env.path_clearance(q0, aux), env.ee_radius)
        assert s.crossing_fraction >= 0.8, s
        d, layout = env.layout, ReachLayout()
        assert 0.3 < d.reach < 2.0
        post, test_post = env.scene.obstacles[0], env.params.test_scene.obstacles[0]
        S, G = torch.tensor(d.start_point), torch.tensor(d.goal_point)
        xy = torch.tensor(post.center[:2], dtype=torch.float64)
        # between the start and goal points: on the reach's line within the searched band
        line = (G - S)[:2]
        t = float((xy - S[:2]) @ line / (line @ line))
        off = float(abs(line[0] * (xy - S[:2])[1] - line[1] * (xy - S[:2])[0]) / line.norm())
        assert layout.along[0] - 1e-9 <= t <= layout.along[1] + 1e-9 and off <= layout.across * d.reach + 1e-9
        # the test cylinder moved along the reach by 0.04 of it and 1.2 times wider; sizes scale with the reach
        moved = torch.tensor(test_post.center[:2], dtype=torch.float64) - xy
        assert float(moved.norm()) == pytest.approx(0.04 * d.reach) and float(moved @ line) > 0
        assert any(post.radius == pytest.approx(0.06 * k * d.reach) for k in layout.radius_steps)
        assert test_post.radius == pytest.approx(1.2 * post.radius)
        # every start the environment drew is clear of the cylinder, as pybullet measures it
        assert bool((env.start_margin(q0, aux) >= 0).all())
        assert d.crossing >= 0.8  # the layout's own estimate, from its own samples
        assert "reach layout" in env.describe_task()
    finally:
        env.close()


class _Say:
    def __init__(self):
        self.lines: list[str] = []

    def say(self, line: str) -> None:
        self.lines.append(line)


def test_the_run_warns_before_training_when_the_expert_fails_or_the_obstacle_is_not_in_the_way():
    env = Manipulator(robot=robot("panda"), scene=scene("franka_cylinder"))
    crossing = lambda f: {
        "paths": 20,
        "crossing_fraction": f,
        "radius": 0.095,
        "clearance_quantiles": {"median": 0.01},
    }
    try:
        good = {
            "train": {"expert_success": 1.0, "expert_collision": 0.0, "crossing": crossing(0.9)},
            "val": {"expert_success": 0.95, "expert_collision": 0.0, "crossing": crossing(1.0)},
        }
        say = _Say()
        exp = SimpleNamespace(env=env, say=say)
        assert check_task(exp, SimpleNamespace(info=good)) == []
        assert any("90% of 20 straight reaches cross" in line for line in say.lines)
        bad = {"train": {**good["train"], "crossing": crossing(0.5)}, "val": {**good["val"], "expert_success": 0.35}}
        warnings = check_task(exp, SimpleNamespace(info=bad))
        assert len(warnings) == 2
        assert "only 50% of the training reaches cross" in warnings[0]
        assert "the expert reached only 35% of the validation goals" in warnings[1]
    finally:
        env.close()


def test_the_layout_of_a_mounted_arm_is_the_unmounted_layout_moved_with_its_base():
    """Turned about the base, not the world's origin: a Panda mounted 0.3 m along x and −0.2 m along y gets the same
    task shifted by its mount, to rounding."""
    shift = torch.tensor([0.3, -0.2, 0.0], dtype=torch.float64)
    layouts = []
    for mount in (None, {"xyz": shift.tolist(), "rpy": [0.0, 0.0, 0.0]}):
        env = Manipulator(
            robot={**robot("panda"), "mount": mount},
            scene=scene("reach_post"),
            reach_layout=ReachLayout(),
            start_spread=0.25,
            goal_clearance=0.05,
        )
        layouts.append(env.layout)
        env.close()
    plain, mounted = layouts
    torch.testing.assert_close(torch.tensor(mounted.start_point), torch.tensor(plain.start_point) + shift)
    torch.testing.assert_close(torch.tensor(mounted.goal_point), torch.tensor(plain.goal_point) + shift)
    torch.testing.assert_close(
        torch.tensor(mounted.scene.obstacles[0].center), torch.tensor(plain.scene.obstacles[0].center) + shift
    )
    assert mounted.scene.obstacles[0].radius == pytest.approx(plain.scene.obstacles[0].radius)


def test_an_upright_home_starts_leaning_out_and_an_upright_nominal_q_is_refused():
    """The Panda with its joints at 0 (4 and 6 just off it, inside their limits) stands upright (end effector over the base): the layout starts the reaches
    around the nearest configuration that leans out and says so; the same centre given as env.nominal_q is the
    user's choice, never moved, so it is refused naming the fix."""
    upright = [0.0, 0.0, 0.0, -0.1, 0.0, 0.1, 0.0]  # joint 4 of the Panda must stay below 0
    env = Manipulator(
        robot={**robot("panda"), "home": upright},
        scene=scene("reach_post"),
        reach_layout=ReachLayout(),
        start_spread=0.25,
        goal_clearance=0.05,
    )
    try:
        d = env.layout
        assert d.start_centre is not None and env.params.nominal_q == d.start_centre
        out = (env.ee_position(torch.tensor([d.start_centre], dtype=torch.float64))[0, :2]).norm()
        assert 0.45 * d.reach <= float(out) <= 0.75 * d.reach
        assert "home leaves the end effector too near the base's axis" in env.describe_task()
    finally:
        env.close()
    with pytest.raises(ValueError, match=r"env.nominal_q puts panda's end effector less than 0.35 of its reach"):
        Manipulator(
            robot=robot("panda"),
            scene=scene("reach_post"),
            reach_layout=ReachLayout(),
            start_spread=0.25,
            goal_clearance=0.05,
            nominal_q=upright,
        )


def test_where_stopped_names_the_joints_that_hold_a_rollout_at_a_limit():
    """tools/expert_design.py --where-stopped: a rollout that missed its goal is described by its distance from the
    goal and the joints within AT_LIMIT of a limit; a reached one is not described."""

    from tools.expert_design import AT_LIMIT, stopped_short

    lower, upper = torch.tensor([-1.0, -2.0, -3.0], dtype=torch.float64), torch.tensor([1.0, 2.0, 3.0])
    arm = SimpleNamespace(
        lower=lower,
        upper=upper.double(),
        ee_position=lambda q: q,  # the end effector at q itself: distances are easy to check
        params=SimpleNamespace(joints=["a", "b", "c"]),
    )
    last = torch.tensor([[1.0 - AT_LIMIT / 2, 0.0, 0.0], [0.0, -2.0, 3.0], [0.0, 0.0, 0.0]], dtype=torch.float64)
    ro = SimpleNamespace(q=torch.stack([torch.zeros_like(last), last]), reached=torch.tensor([False, False, True]))
    lines = stopped_short(SimpleNamespace(robot=arm), ro, torch.zeros(3, 3, dtype=torch.float64))
    assert len(lines) == 2
    assert "start 0: 0.990 m from the goal; joints at a limit: a;" in lines[0]
    assert "start 1: 3.606 m from the goal; joints at a limit: b, c;" in lines[1]
