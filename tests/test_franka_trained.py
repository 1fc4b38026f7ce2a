"""A learner trained with one obstacle runs with several (paper App. D.2): the Franka learner-rmp is trained by
behavior cloning on demonstrations around one cylinder, then rebuilt for a scene with three (one obstacle node per
control point and obstacle, all of a control point's edges sharing its learned weight) and rolled out in pybullet.
Slow: it collects, trains and rolls out for real (about two minutes on two cores)."""

from __future__ import annotations

import os

import pytest
import torch
import yaml

pytest.importorskip("pybullet")

from manipulators import cylinders, franka_env, franka_tree_spec

import rmpfusion
from rmpfusion.envs.manipulator_tree import copy_weights, with_weights
from rmpfusion.evaluate import lyapunov_monotone, max_relative_increase
from rmpfusion.learn.config import TrainConfig
from rmpfusion.learn.objectives import dataset_loss
from rmpfusion.learn.rmp_learner import RMPLearner
from rmpfusion.learn.train import train

F64 = torch.float64
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
RATE = 250.0  # Hz, kinematic integration: the experiment's collection mode, coarser for speed


def _conf(group: str) -> dict:
    with open(os.path.join(ROOT, "conf", group, "franka.yaml"), encoding="utf-8") as f:
        return yaml.safe_load(f)


def _env(scene=None, **overrides):
    """The experiment's environment (conf/env/franka.yaml) with ``overrides``."""
    params = {k: v for k, v in _conf("env").items() if k not in ("type", "defaults")}
    return franka_env(
        scene, **{**params, "control_rate": RATE, "mode": "kinematic", "collect_mode": "kinematic", **overrides}
    )


@pytest.mark.slow
def test_a_trained_learner_runs_with_three_obstacles_without_collision():
    env1 = _env(demo_min_duration=3.0)
    weights = _conf("expert")
    expert1 = rmpfusion.build_tree(with_weights(franka_tree_spec(1), weights), aux_dims=env1.aux_dims())
    g = torch.Generator().manual_seed(0)
    data = env1.demonstrations(expert1, 1, 24, 51, 0.1, g, split="train")
    spec1 = franka_tree_spec(1)
    learner = RMPLearner(
        RMPLearner.Params(
            weights={"type": "mlp", "hidden": [32, 32], "aux": ["goal"], "positivity": "exp"}
        ),  # as conf/experiment/franka.yaml
        spec1,
        env1.aux_dims(),
        7,
        expert=weights,
    )
    before = dataset_loss(learner, data)
    cfg = TrainConfig(
        optimizer="adam",
        lr=1e-3,
        batch_size=200,
        iterations=1500,
        snapshots=[1500],
        checkpoint_every=1500,
        log_every=500,
    )
    train(learner, data, cfg, seed=0)
    after = dataset_loss(learner, data)
    assert after < 0.05 * before, (before, after)  # it learned: the weights are no longer their random start

    # three cylinders: the training one, one beside the way to the goal, one behind the robot's base
    scene = cylinders([(0.55, 0.0, 0.3), (0.45, -0.55, 0.3), (-0.3, 0.3, 0.3)], [0.05, 0.05, 0.08])
    env3 = _env(scene)
    tree3 = rmpfusion.build_tree(franka_tree_spec(3), aux_dims=env3.aux_dims())
    copied = copy_weights(learner.tree, tree3)
    assert "attractor" in copied and all(f"cp{i}_obstacle" in copied for i in range(1, 15))
    g3 = torch.Generator().manual_seed(1)
    q0, qd0, aux = env3.sample_initial_states(env3.sample_envs(1, g3), 6, g3)
    with torch.no_grad():
        ro = env3.rollout(tree3, q0, qd0, aux, horizon=10.0, record_every=0.1)
    env1.close(), env3.close()
    print(f"three obstacles: reached {ro.reached.tolist()}, min clearance {ro.min_clearance.min().item():.3f} m")
    assert ro.error == [None] * 6
    assert not ro.collided.any(), ro.min_clearance
    assert bool(ro.reached.all()), ro.goal_distance[-1]
    assert bool(lyapunov_monotone(ro.V, rtol=1e-6).all()), max_relative_increase(ro.V)
