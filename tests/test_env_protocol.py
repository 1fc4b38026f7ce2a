"""Both environments satisfy the pipeline's ``Env`` protocol and exactly the capability protocols they claim: the
pipeline decides task metrics, renders and 2-D figures by these ``isinstance`` checks."""
from __future__ import annotations

import pytest
import torch

from rmpfusion.envs import (Env, HasRatioMetrics, HasTaskMetrics, Particle2D, PlanarWorkspace, RenderSettings,
                            Renders, collect)
from rmpfusion.registry import ENVS


def test_particle2d_is_an_env_with_a_planar_workspace_only():
    env = Particle2D(n_obstacles=2)
    assert isinstance(env, Env) and isinstance(env, PlanarWorkspace)
    assert not isinstance(env, (Renders, HasTaskMetrics, HasRatioMetrics))
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
    from rmpfusion.envs.manipulator import Manipulator
    from manipulators import franka_env

    env = franka_env()
    try:
        assert isinstance(env, Env)
        assert isinstance(env, HasTaskMetrics) and isinstance(env, HasRatioMetrics) and isinstance(env, Renders)
        assert not isinstance(env, PlanarWorkspace)
        assert env.dim == 7 and env.dt == pytest.approx(1.0 / env.params.control_rate)
        assert set(env.ratio_metrics) <= {"time", "cspace_length", "ee_length", "goal_distance",
                                          "timeout_goal_distance", "min_goal_distance"}
        s = env.render_settings
        assert isinstance(s, RenderSettings) and s.size == tuple(env.params.render_size)
        assert s.times == tuple(env.params.render_times) and s.gif_fps == env.params.gif_fps
        assert ENVS.get("manipulator").obj is Manipulator
    finally:
        env.close()
