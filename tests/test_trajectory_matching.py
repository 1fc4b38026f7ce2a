"""Trajectory matching of demonstrations (train.method=match): the soft-DTW alignment cost against an independent
dynamic-time-warping table, its gradients against finite differences, and the method recovering the shape of
demonstrations a known policy made."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
import torch
from torch import nn

from rmpfusion.envs import Particle2D
from rmpfusion.envs.demonstrations import Dataset
from rmpfusion.learn.alignment import scaled_square_distances, soft_dtw
from rmpfusion.learn.methods.match import DemonstrationPaths, MatchingCost, MatchParams, on_records


def dtw_by_loops(cost: np.ndarray) -> float:
    """The textbook dynamic-time-warping table, cell by cell (the sum of costs, not distances)."""
    n, m = cost.shape
    D = np.full((n + 1, m + 1), np.inf)
    D[0, 0] = 0.0
    for i in range(1, n + 1):
        for j in range(1, m + 1):
            D[i, j] = cost[i - 1, j - 1] + min(D[i - 1, j], D[i, j - 1], D[i - 1, j - 1])
    return float(D[n, m])


def test_soft_dtw_tends_to_dtw_and_reads_only_each_samples_own_rows():
    gen = torch.Generator().manual_seed(0)
    cost = torch.rand(3, 9, 7, generator=gen, dtype=torch.float64)
    lengths = torch.tensor([9, 4, 1])
    soft = soft_dtw(cost, lengths, gamma=1e-5)
    for b in range(3):
        exact = dtw_by_loops(cost[b, : int(lengths[b])].numpy())
        assert soft[b].item() == pytest.approx(exact, abs=1e-4)
        assert soft[b].item() <= exact + 1e-12  # the soft minimum is below the hard one
    padded = cost.clone()
    padded[1, 4:] = 1e3  # the padding of the second sample: never read
    assert torch.equal(soft_dtw(padded, lengths, gamma=1e-5), soft)


def test_soft_dtw_gradients_match_finite_differences():
    gen = torch.Generator().manual_seed(1)
    cost = torch.rand(2, 5, 6, generator=gen, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda c: soft_dtw(c, torch.tensor([5, 3]), gamma=0.1), (cost,))


def test_soft_dtw_refuses_bad_settings():
    cost = torch.rand(1, 3, 3, dtype=torch.float64)
    with pytest.raises(ValueError, match="gamma > 0"):
        soft_dtw(cost, torch.tensor([3]), gamma=0.0)
    with pytest.raises(ValueError, match="lengths must be in 1..3"):
        soft_dtw(cost, torch.tensor([4]), gamma=0.1)


def test_scaled_distances_weigh_each_coordinate_by_its_spread():
    x = torch.tensor([[[1.0, 10.0]]], dtype=torch.float64)
    y = torch.tensor([[[0.0, 0.0], [1.0, 0.0]]], dtype=torch.float64)
    d = scaled_square_distances(x, y, torch.tensor([1.0, 10.0], dtype=torch.float64))
    assert torch.allclose(d, torch.tensor([[[2.0, 1.0]]], dtype=torch.float64))


def test_a_coordinate_the_demonstrations_hold_still_is_not_weighed_by_its_noise():
    """A joint the recordings barely move (the iiwa's wrist: 1 mrad of spread, its noise, beside 0.39 rad) would
    weigh 1/spread² times more than the others and make matching fit its noise: its spread is floored at
    ``spread_floor`` times the largest; coordinates that move keep their own, and nothing moving counts as 1."""
    t = torch.arange(0, 2.0, 0.01, dtype=torch.float64)
    noise = 1e-3 * torch.sin(37.0 * t)
    ds = SimpleNamespace(
        traj_id=torch.zeros_like(t, dtype=torch.long),
        t=t,
        q=torch.stack([0.8 * t, 0.3 * torch.sin(t), noise], 1),
        qd=torch.zeros(len(t), 3, dtype=torch.float64),
        aux={},
    )
    demos = DemonstrationPaths(ds, record_every=0.1)
    own = demos.spread(0.0)
    floored = demos.spread(0.1)
    assert own[2] < 1e-3 and torch.equal(floored[:2], own[:2])
    assert floored[2] == pytest.approx(0.1 * float(own.max()))
    still = SimpleNamespace(**{**vars(ds), "q": torch.zeros(len(t), 3, dtype=torch.float64)})
    assert torch.equal(DemonstrationPaths(still, record_every=0.1).spread(0.1), torch.ones(3, dtype=torch.float64))


def test_demonstrations_are_resampled_on_the_record_grid():
    t = torch.tensor([0.0, 0.03, 0.1, 0.26], dtype=torch.float64)  # irregular
    q = torch.stack([3 * t + 1, -t], 1)  # linear: interpolation is exact
    path = on_records(t, q, 0.05)
    grid = torch.arange(0, 6, dtype=torch.float64) * 0.05
    assert torch.allclose(path, torch.stack([3 * grid + 1, -grid], 1))


class CurlToGoal(nn.Module):
    """q̈ = 4 (goal − q) + a·R(goal − q) − 4 q̇, R the quarter turn: the path to the goal bends with a (straight at
    a = 0), so a is a shape the demonstrations show, whatever their speed."""

    def __init__(self, curl: float):
        super().__init__()
        self.curl = nn.Parameter(torch.tensor(curl, dtype=torch.float64))

    def forward(self, q, qd, aux):
        e = aux["goal"] - q
        turned = torch.stack([-e[:, 1], e[:, 0]], 1)
        return 4.0 * e + self.curl * turned - 4.0 * qd


def demonstrations_of(policy: nn.Module, env: Particle2D, starts: torch.Tensor, goals: torch.Tensor) -> Dataset:
    """Each start's rollout of ``policy`` as a recorded demonstration (every 0.02 s for 3 s)."""
    qd0 = torch.zeros_like(starts)
    with torch.no_grad():
        ro = env.rollout(policy, starts, qd0, {"goal": goals}, horizon=3.0, record_every=0.02)
    T, B = ro.q.shape[:2]
    flat = lambda x: x.transpose(0, 1).reshape(B * T, -1)
    ids = torch.arange(B).repeat_interleave(T)
    return Dataset(
        q=flat(ro.q),
        qd=flat(ro.qd),
        qdd=flat(ro.qdd),
        aux={"goal": goals.repeat_interleave(T, 0)},
        env_id=ids,
        traj_id=ids,
        t=ro.times.repeat(B),
    )


@pytest.fixture
def matching():
    env = Particle2D(n_obstacles=0, dt=0.02)
    starts = torch.tensor([[0.0, 0.0], [1.0, -0.5], [-0.5, 1.0]], dtype=torch.float64)
    goals = torch.tensor([[1.0, 1.0], [0.0, 0.5], [0.5, 0.0]], dtype=torch.float64)
    demos = DemonstrationPaths(demonstrations_of(CurlToGoal(3.0), env, starts, goals), record_every=0.1)
    params = MatchParams(record_every=0.1, horizon_factor=1.5, gamma=0.01)
    return MatchingCost(env, params, demos.spread(params.spread_floor), demos.duration), demos


def test_matching_cost_gradient_equals_finite_differences(matching):
    cost, demos = matching
    policy, idx = CurlToGoal(1.0), torch.arange(len(demos))
    cost(policy, demos, idx, backward=True)
    analytic = policy.curl.grad.item()
    h, base = 1e-5, policy.curl.detach().clone()
    values = []
    for sign in (1, -1):
        with torch.no_grad():
            policy.curl.copy_(base + sign * h)
        values.append(cost(policy, demos, idx, backward=False))
    assert analytic == pytest.approx((values[0] - values[1]) / (2 * h), rel=1e-4)


def test_matching_recovers_the_demonstrators_curl(matching):
    """The demonstrations bend with curl 3; a learner starting straight (curl 0) is driven to it by the alignment
    cost alone, and the cost falls on the way. (A speed alone, e.g. a gain along a straight path, is what DTW
    aligns away: matching learns shapes.)"""
    cost, demos = matching
    policy = CurlToGoal(0.0)
    opt = torch.optim.Adam(policy.parameters(), lr=0.1)
    idx = torch.arange(len(demos))
    first = cost(policy, demos, idx, backward=False)
    for _ in range(80):
        opt.zero_grad()
        cost(policy, demos, idx, backward=True)
        opt.step()
    assert cost(policy, demos, idx, backward=False) < 0.05 * first
    assert policy.curl.item() == pytest.approx(3.0, rel=0.1)  # the cost's minimum is at 2.9: the rollout outlasts
    # the demonstration by half and its tail pairs with the demonstration's last record


class PullToPosture(nn.Module):
    """q̈ = k (posture − q) − 3 q̇ in joint space, k learnable: an arm's rollout as a smooth function of k."""

    def __init__(self, posture: torch.Tensor, gain: float):
        super().__init__()
        self.posture = posture
        self.gain = nn.Parameter(torch.tensor(gain, dtype=torch.float64))

    def forward(self, q, qd, aux):
        return self.gain * (self.posture - q) - 3.0 * qd


def test_the_arms_kinematic_rollouts_carry_the_gradient_trajectory_matching_needs():
    """The manipulator in kinematic mode integrates in torch: a cost of the recorded configurations of a rollout
    on a coarser step (``with_step``) has the gradient the central difference of two rollouts gives; torque mode
    steps pybullet and refuses to pretend otherwise."""
    pytest.importorskip("pybullet")
    from manipulators import franka_env

    env = franka_env(mode="kinematic", control_rate=250.0)
    try:
        coarse = env.with_step(0.02)
        assert coarse.dt == pytest.approx(0.02) and coarse.scene == env.scene and env.with_step(env.dt) is env
        assert coarse.gradient_refusal() is None
        aux = env.sample_envs(1, torch.Generator().manual_seed(0))
        q0, qd0, aux = env.sample_initial_states(aux, 2, torch.Generator().manual_seed(1))
        posture = q0.mean(0) + 0.2
        policy = PullToPosture(posture, 4.0)

        def cost(backward: bool) -> float:
            ro = coarse.rollout(policy, q0, qd0, aux, horizon=1.0, record_every=0.1, enable_grad=backward)
            value = ((ro.q - posture) ** 2).sum(-1).mean()
            if backward:
                value.backward()
            return float(value.detach())

        cost(backward=True)
        analytic = policy.gain.grad.item()
        h, base, values = 1e-5, policy.gain.detach().clone(), []
        for sign in (1, -1):
            with torch.no_grad():
                policy.gain.copy_(base + sign * h)
            values.append(cost(backward=False))
        assert analytic != 0.0 and analytic == pytest.approx((values[0] - values[1]) / (2 * h), rel=1e-5)
        with pytest.raises(ValueError, match="cannot keep the autograd graph: env.mode=torque"):  # a call's own mode
            env.rollout(policy, q0, qd0, aux, horizon=0.1, record_every=0.1, mode="torque", enable_grad=True)
    finally:
        env.close()
    torque = franka_env(mode="torque")
    try:
        assert "env.mode=kinematic" in torque.gradient_refusal()
        with pytest.raises(ValueError, match="cannot keep the autograd graph: env.mode=torque"):
            torque.rollout(policy, q0, qd0, aux, horizon=0.1, record_every=0.1, enable_grad=True)
    finally:
        torque.close()
