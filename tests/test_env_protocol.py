"""Both environments satisfy the pipeline's ``Env`` protocol and exactly the capability protocols they claim: the
pipeline decides task metrics, renders and 2-D figures by these ``isinstance`` checks."""

from __future__ import annotations

import pytest
import torch

from rmpfusion.envs import (
    DifferentiableRollouts,
    DifferentiableTask,
    Env,
    HasRatioMetrics,
    HasTaskMetrics,
    Particle2D,
    PlanarWorkspace,
    Renders,
    RenderSettings,
    collect,
)
from rmpfusion.registry import ENVS


def test_particle2d_is_an_env_with_a_planar_workspace_task_metrics_and_differentiable_rollouts():
    env = Particle2D(n_obstacles=2)
    assert isinstance(env, Env) and isinstance(env, PlanarWorkspace) and isinstance(env, HasTaskMetrics)
    assert isinstance(env, DifferentiableRollouts) and isinstance(env, DifferentiableTask)
    assert env.gradient_refusal() is None
    assert not isinstance(env, (Renders, HasRatioMetrics))
    assert env.dim == 2 and env.dt == env.params.dt
    assert ENVS.get("particle2d").obj is Particle2D


def test_particle2d_demonstrations_are_the_generic_collection():
    env = Particle2D(n_obstacles=1)

    def expert(q, qd, aux):
        return -2.0 * (q - aux["goal"]) - 1.5 * qd

    args = (expert, 2, 3, 6, 0.1)
    ds = env.demonstrations(*args, generator=torch.Generator().manual_seed(4), split="test")
    ref = collect(env, *args, torch.Generator().manual_seed(4))
    assert ds.checksum() == ref.checksum() and len(ds) == 2 * 3 * 6


def test_the_manipulator_is_an_env_with_task_metrics_ratios_and_renders():
    pytest.importorskip("pybullet")
    from manipulators import franka_env

    from rmpfusion.envs.manipulator import Manipulator

    env = franka_env()
    try:
        assert isinstance(env, Env)
        assert isinstance(env, HasTaskMetrics) and isinstance(env, HasRatioMetrics) and isinstance(env, Renders)
        assert not isinstance(env, PlanarWorkspace)
        # rollouts integrated in torch (kinematic mode) keep gradients; the clearance is pybullet's and has none
        assert isinstance(env, DifferentiableRollouts) and not isinstance(env, DifferentiableTask)
        assert env.dim == 7 and env.dt == pytest.approx(1.0 / env.params.control_rate)
        assert set(env.ratio_metrics) <= {
            "time",
            "cspace_length",
            "ee_length",
            "goal_distance",
            "timeout_goal_distance",
            "min_goal_distance",
        }
        s = env.render_settings
        assert isinstance(s, RenderSettings) and s.size == tuple(env.params.render_size)
        assert s.times == tuple(env.params.render_times) and s.gif_fps == env.params.gif_fps
        assert ENVS.get("manipulator").obj is Manipulator
    finally:
        env.close()


def test_particle2d_task_metrics_and_goal_distances_follow_its_records():
    """A particle driven straight at its goal: the records carry the distance to the goal, the task metrics the
    time it first came within the tolerance, the polyline's length and the end distance."""
    env = Particle2D(n_obstacles=0, dt=0.01)
    aux = {"goal": torch.tensor([[1.0, 0.0]], dtype=torch.float64)}
    q0, qd0 = torch.zeros(1, 2, dtype=torch.float64), torch.tensor([[0.5, 0.0]], dtype=torch.float64)
    ro = env.rollout(lambda q, qd, a: torch.zeros_like(q), q0, qd0, aux, horizon=3.0, record_every=0.1)
    x = 0.5 * ro.times
    assert torch.allclose(ro.goal_distance[:, 0], (1.0 - x).abs(), atol=1e-12)
    m = env.task_metrics(ro)
    assert float(m["time"]) == pytest.approx(1.8)  # |1 − 0.5 t| ≤ 0.1 first at the record t = 1.8
    assert float(m["path_length"]) == pytest.approx(1.5) and float(m["final_distance"]) == pytest.approx(0.5)
    assert float(m["success"]) == 0.0 and float(m["collided"]) == 0.0 and float(m["min_clearance"]) == float("inf")
