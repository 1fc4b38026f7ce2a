"""What ``make bench`` times is built by the same code as the trees users run: the subjects of tools/bench.py are
built here (no timing), so a change to the configs or the generators that breaks the benchmark fails a test, and
the hand-fused reference it compares the training step against still computes the learner's q̈."""

from __future__ import annotations

import pytest
import torch

from tools import bench


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


def _checked(spec):
    """The scaling rows' 1024 states among 10 and 100 cylinders take minutes of pybullet distance queries: slow."""
    return pytest.param(spec, marks=pytest.mark.slow) if spec[0] * spec[1] >= 10 * 1024 else spec


@pytest.mark.parametrize(
    "spec", [_checked(s) for s in bench.TIMED_FRANKA_STATES], ids=lambda s: f"obstacles{s[0]}-B{s[1]}-seed{s[2]}"
)
def test_every_franka_state_the_benchmark_times_is_inside_the_joint_limits_and_clear_of_the_obstacles(spec):
    """A state past a joint limit (the Panda's joint 4 spans [−3.07, −0.07] in pybullet_data's URDF) or inside an
    obstacle would time a barrier's saturated branch. Checked here independently of the sampler: the URDF's
    limits as the tree reads them, and pybullet's distance from the robot to every obstacle."""
    tree, q, qd, aux = bench.franka_states(*spec)
    n_obstacles, batch, _ = spec
    assert q.shape == qd.shape == (batch, 7) and all(v.shape[0] == batch for v in aux.values())
    lo, hi = tree.maps["ee"].chain.joint_limits()
    assert float(hi[3]) <= 0.0 and float(lo[3]) >= -3.15  # joint 4 as pybullet_data's Panda has it
    assert ((q > lo) & (q < hi)).all(), (q.min(0).values, q.max(0).values)
    _, env = bench.franka_subject(n_obstacles)
    # pybullet's distance queries cost states x obstacles: among 100 cylinders a seeded quarter of the states (the
    # sampler draws them all alike), every state among fewer
    checked = (
        torch.randperm(batch, generator=torch.Generator().manual_seed(0))[: batch // 4]
        if n_obstacles >= 100
        else slice(None)
    )
    try:
        clearance = env.clearance(q[checked], {k: v[checked] for k, v in aux.items()})
    finally:
        env.close()
    assert (clearance > 0).all(), clearance.min()
    with torch.no_grad():
        assert torch.isfinite(tree(q, qd, aux).qdd).all()


def test_the_rollout_row_s_starts_are_accepted_by_the_arm_and_its_step_runs():
    """The rollout section's subject: experiment=recorded_arm's tree, its environment and 100 starts the
    environment accepts; two integration steps of them run and stay finite (nothing timed)."""
    from rmpfusion.envs.faults import IsolatingPolicy
    from rmpfusion.envs.manipulator.kinematic import integrate

    tree, env, q0, qd0, aux = bench.arm_evaluation_subject(bench.ROLLOUT["starts"])
    try:
        assert q0.shape[0] == bench.ROLLOUT["starts"] and env.recorded_starts(q0).all()
        with torch.no_grad():
            _, path, _, alive = integrate(env, IsolatingPolicy(tree), q0, qd0, aux, 2, 1, None, [None] * 100)
        assert alive.all() and torch.isfinite(path[-1]).all()
    finally:
        env.close()


def test_the_hand_fused_test_vector_is_the_tree_s_policy(gen):
    """The reference section's floor computes the test-vector tree's q̈, here at random states (nothing timed)."""
    import rmpfusion
    from tests.trees import TEST_VECTOR_SPEC

    tree = rmpfusion.build_tree(TEST_VECTOR_SPEC)
    q = torch.tensor([2.0, -2.0]) + 2 * torch.rand(8, 2, generator=gen)
    qd = torch.randn(8, 2, generator=gen)
    with torch.no_grad():
        torch.testing.assert_close(bench.hand_fused_test_vector(q, qd), tree.policy(q, qd), rtol=1e-10, atol=1e-12)
