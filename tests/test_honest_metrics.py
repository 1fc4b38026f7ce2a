"""Metrics that measure what they claim: the online loss separated into "collides" and "drifts", the first
collision time, the weights a learner learned beside the expert's, and the validation split."""

from __future__ import annotations

import json

import pytest
import torch
from conftest import compose_cfg

import rmpfusion
from rmpfusion.envs import Particle2D
from rmpfusion.evaluate.metrics import online_loss
from rmpfusion.evaluate.weights import edge_weights, learned_edges, summarize_weights

F64 = torch.float64


def _scene(B: int = 2):
    """Two particles at rest at x = −3: the obstacle (radius 1) at the origin, the goal at (3, 0)."""
    aux = {
        "goal": torch.tensor([[3.0, 0.0]] * B, dtype=F64),
        "obstacle1_center": torch.tensor([[0.0, 0.0]] * B, dtype=F64),
        "obstacle1_radius": torch.tensor([[1.0]] * B, dtype=F64),
    }
    q0 = torch.tensor([[-3.0, 0.0], [-3.0, 3.0]], dtype=F64)[:B]
    return q0, torch.zeros_like(q0), aux


def _expert(env):
    spec = {
        "root": {"name": "q", "dim": 2},
        "nodes": {
            "obstacle": {
                "parent": "q",
                "map": {"type": "sphere_distance", "center": "obstacle1_center", "radius": "obstacle1_radius"},
                "weight": {
                    "type": "rbf",
                    "center": "obstacle1_center",
                    "radius": "obstacle1_radius",
                    "sigma": 0.5,
                    "low": 1.0,
                    "high": 5.0,
                },
                "rmp": {"type": "collision_avoidance", "alpha": 1e-5},
            },
            "goal": {"parent": "q", "map": {"type": "offset", "origin": "goal"}, "rmp": {"type": "goal_attractor"}},
        },
    }
    return rmpfusion.build_tree(spec, aux_dims=env.aux_dims())


def test_first_collision_time_of_a_constant_acceleration():
    """x(t) = −3 + t²/2 enters the unit circle at t = 2 (x = −1); the rollout says so to within one step."""
    env = Particle2D(n_obstacles=1, integrator="semi_implicit_euler")
    q0, qd0, aux = _scene()
    push = lambda q, qd, a: torch.tensor([[1.0, 0.0]], dtype=F64).expand_as(q)
    ro = env.rollout(push, q0, qd0, aux, horizon=3.0, record_every=0.5)
    assert ro.collided.tolist() == [True, False]
    assert ro.first_collision_time[0].item() == pytest.approx(2.0, abs=2 * env.params.dt)
    assert ro.first_collision_time[1].item() == float("inf")


def test_online_loss_before_collision_and_median_separate_collides_from_drifts():
    env = Particle2D(n_obstacles=1, integrator="semi_implicit_euler")
    q0, qd0, aux = _scene()
    expert = _expert(env)
    push = lambda q, qd, a: torch.tensor([[1.0, 0.0]], dtype=F64).expand_as(q)
    res = online_loss(push, expert, env, q0, qd0, aux, horizon=3.0, interval=0.5)
    ro = res.rollout
    # independent computation: squared error per record, per trajectory, then the three reductions
    err = ((ro.qdd - res.expert_qdd) ** 2).mean(-1)  # (T, B)
    assert res.loss == pytest.approx(float(err.mean()))
    assert res.median == pytest.approx(float(err.mean(0).median()))
    before = ro.times[:, None] < ro.first_collision_time[None, :]
    assert before[:, 1].all() and not before[-1, 0]  # trajectory 1 never collides; trajectory 0 does
    assert res.before_collision == pytest.approx(float(err[before].mean()))
    # inside the obstacle the expert's barrier answers with large accelerations: the plain mean is dominated by them
    assert res.loss > 10 * res.before_collision
    assert set(res.metrics()) == {"online_loss", "online_loss_median", "online_loss_before_collision"}


def test_edge_weights_are_the_weight_functions_at_the_parent_states():
    env = Particle2D(n_obstacles=1)
    expert = _expert(env)
    q, qd, aux = env.sample(n_envs=2, n_per_env=5, seed=3)
    w = edge_weights(expert, q, qd, aux, ["obstacle"], chunk=3)  # chunking must not change anything
    direct, _ = expert.weights["obstacle"](q, aux)
    torch.testing.assert_close(w["obstacle"], direct, rtol=0, atol=0)
    s = summarize_weights(w)["obstacle"]
    assert s["min"] == float(direct.min()) and s["max"] == float(direct.max()) and 1.0 <= s["min"] < s["max"] <= 5.0
    assert learned_edges(expert) == []  # designed weights are not learned


def test_tiny_run_reports_validation_loss_weights_and_online_loss_variants(tmp_path):
    from rmpfusion.pipeline.run import run_experiment
    from rmpfusion.pipeline.validate import resolve_and_validate

    cfg = compose_cfg(["experiment=2d2level", "data=tiny", "train=tiny", "logger=disabled", "eval.compile=false"])
    run_experiment(resolve_and_validate(cfg), tmp_path, progress=False)
    m = json.loads((tmp_path / "metrics.json").read_text())
    assert m["data"]["val"]["points"] == 1 * 2 * 3  # data=tiny: 1 validation environment x 2 trajectories x 3 points
    edges = {"goal", "obstacles", "obstacle1", "obstacle2"}
    assert set(m["expert"]["weights"]) == edges
    for snap in m["learners"]["rmp"]["snapshots"].values():
        assert snap["val_loss"] > 0
        assert {"online_loss", "online_loss_median", "online_loss_before_collision"} <= set(snap)
        assert set(snap["weights"]) == edges
        for e in edges:
            assert 0 < snap["weights"][e]["min"] <= snap["weights"][e]["mean"] <= snap["weights"][e]["max"]
    # the expert's designed obstacle1 weight varies over the states; an untrained learner's is another function
    assert m["expert"]["weights"]["obstacle1"] != m["learners"]["rmp"]["snapshots"]["0"]["weights"]["obstacle1"]
    assert (tmp_path / "figures" / "weights_rmp.png").stat().st_size > 0
