"""What ``make bench`` times is built by the same code as the trees users run: the subjects of tools/bench.py are
built here (no timing), so a change to the configs or the generators that breaks the benchmark fails a test, and
the hand-fused reference it compares the training step against still computes the learner's q̈."""
from __future__ import annotations

import sys
from pathlib import Path

import pytest
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tools"))
import bench  # noqa: E402


@pytest.mark.parametrize("n_obstacles", [1, 3])
def test_the_franka_subject_has_one_obstacle_edge_per_control_point_and_obstacle(n_obstacles):
    tree, aux = bench.franka_expert(n_obstacles)
    assert {f"obstacle{k}_center" for k in range(1, n_obstacles + 1)} <= set(aux)
    edges = [n for n in tree.node_dims if "_obstacle" in n]
    assert len(edges) == 14 * n_obstacles, edges
    q = torch.full((1, 7), 0.1, dtype=torch.float64)
    assert torch.isfinite(tree(q, torch.zeros_like(q), aux).qdd).all()


def test_the_fused_training_reference_computes_the_learner_s_acceleration():
    learner, env = bench.learner_2d2level()
    q, qd, aux = env.sample(n_envs=2, n_per_env=5, seed=1)
    aux = learner.tree._normalise_aux(aux, q.shape[0])
    with torch.no_grad():
        torch.testing.assert_close(bench.Fused2d2level(learner)(q, qd, aux), learner(q, qd, aux), rtol=1e-9, atol=1e-9)
