"""The 2D particle environment: sampling, collision/success tests, integrators, and a real RMPTree rollout."""

from __future__ import annotations

import math

import pytest
import torch
from pydantic import ValidationError

import rmpfusion
from rmpfusion.envs import Particle2D, Rollout
from rmpfusion.evaluate import energy_rate_residual, lyapunov_monotone, max_relative_increase
from rmpfusion.registry import ENVS

F64 = torch.float64


def gen(seed: int) -> torch.Generator:
    return torch.Generator().manual_seed(seed)


# ---------------------------------------------------------------- registry and params


def test_registered_with_validated_params():
    entry = ENVS.get("particle2d")
    assert entry.obj is Particle2D
    env = entry.obj(entry.validate({"n_obstacles": 2, "integrator": "semi_implicit_euler"}))
    assert env.params.n_obstacles == 2
    with pytest.raises(ValidationError):
        entry.validate({"n_obstacle": 2})
    with pytest.raises(ValidationError):
        entry.validate({"integrator": "euler"})
    with pytest.raises(ValidationError):
        entry.validate({"obstacle_radius": (1.5, 0.5)})


def test_aux_dims():
    assert Particle2D().aux_dims() == {"goal": 2, "obstacle1_center": 2, "obstacle1_radius": 1}
    assert Particle2D(n_obstacles=2).aux_dims() == {
        "goal": 2,
        "obstacle1_center": 2,
        "obstacle1_radius": 1,
        "obstacle2_center": 2,
        "obstacle2_radius": 1,
    }


# ---------------------------------------------------------------- sampling


@pytest.mark.parametrize("K", [1, 2])
def test_sampling_is_determined_by_the_seed(K):
    env = Particle2D(n_obstacles=K)
    a = env.sample_initial_states(env.sample_envs(5, gen(0)), 3, gen(1))
    b = env.sample_initial_states(env.sample_envs(5, gen(0)), 3, gen(1))
    c = env.sample_initial_states(env.sample_envs(5, gen(7)), 3, gen(1))
    assert torch.equal(a[0], b[0]) and torch.equal(a[1], b[1])
    assert all(torch.equal(a[2][k], b[2][k]) for k in a[2])
    assert not torch.equal(a[2]["goal"], c[2]["goal"])
    assert not torch.equal(a[0], env.sample_initial_states(env.sample_envs(5, gen(0)), 3, gen(2))[0])
    assert torch.equal(env.sample(5, 3, seed=4)[0], env.sample(5, 3, seed=4)[0])


@pytest.mark.parametrize("K", [1, 2])
def test_shapes_dtype_and_env_major_layout(K):
    env = Particle2D(n_obstacles=K)
    envs = env.sample_envs(4, gen(0))
    assert set(envs) == set(env.aux_dims())
    for k, d in env.aux_dims().items():
        assert envs[k].shape == (4, d) and envs[k].dtype == F64
    q0, qd0, aux = env.sample_initial_states(envs, 3, gen(1))
    assert q0.shape == qd0.shape == (12, 2) and q0.dtype == qd0.dtype == F64
    for k, d in env.aux_dims().items():
        assert aux[k].shape == (12, d)
        assert torch.equal(aux[k][7], envs[k][7 // 3])
    assert env.in_collision(q0, aux).shape == env.success(q0, aux).shape == (12,)
    assert env.in_collision(q0, aux).dtype == torch.bool


@pytest.mark.parametrize("K", [1, 2])
def test_starts_and_goals_are_clear_and_inside(K):
    env = Particle2D(n_obstacles=K)
    p = env.params
    q0, qd0, aux = env.sample(100, 5, seed=3)
    assert not env.in_collision(q0, aux).any()
    assert not env.in_collision(aux["goal"], aux).any()
    assert (env.clearance(q0, aux) >= p.clearance).all()
    assert (env.clearance(aux["goal"], aux) >= p.clearance).all()
    for pts, box in ((q0, p.start_region), (aux["goal"], p.goal_region)):
        for axis in range(2):
            assert (pts[:, axis] >= box[axis][0]).all() and (pts[:, axis] <= box[axis][1]).all()
    speed = qd0.norm(dim=-1)
    assert (speed >= p.start_speed[0]).all() and (speed <= p.start_speed[1] + 1e-12).all()
    c, r = env.obstacles(aux)
    assert (r >= p.obstacle_radius[0]).all() and (r <= p.obstacle_radius[1]).all()
    lo, hi = p.workspace
    assert ((c - r[..., None] >= lo) & (c + r[..., None] <= hi)).all()
    if K == 2:
        gap = (c[:, 0] - c[:, 1]).norm(dim=-1) - r[:, 0] - r[:, 1]
        assert (gap >= p.obstacle_gap).all()
    # usually an obstacle blocks the straight start→goal segment (measured: ~74% for K=1, ~86% for K=2)
    a, b = q0[:, None], aux["goal"][:, None]
    t = (((c - a) * (b - a)).sum(-1) / ((b - a) ** 2).sum(-1)).clamp(0, 1)
    dist = (c - (a + t[..., None] * (b - a))).norm(dim=-1)
    assert (dist < r).any(1).float().mean() > 0.6


# ---------------------------------------------------------------- collision and success


def test_collision_and_success_by_hand():
    env = Particle2D(n_obstacles=2, goal_tolerance=0.1)
    aux = {
        "goal": torch.tensor([[3.0, 0.0]], dtype=F64).expand(5, 2),
        "obstacle1_center": torch.tensor([[0.0, 0.0]], dtype=F64).expand(5, 2),
        "obstacle1_radius": torch.tensor([[1.0]], dtype=F64).expand(5, 1),
        "obstacle2_center": torch.tensor([[0.0, 3.0]], dtype=F64).expand(5, 2),
        "obstacle2_radius": torch.tensor([[0.5]], dtype=F64).expand(5, 1),
    }
    q = torch.tensor([[0.5, 0.5], [0.0, 1.01], [0.1, 2.7], [3.05, 0.05], [2.0, 0.0]], dtype=F64)
    assert env.in_collision(q, aux).tolist() == [True, False, True, False, False]
    assert env.success(q, aux).tolist() == [False, False, False, True, False]
    assert torch.allclose(env.clearance(q, aux)[1], torch.tensor(0.01, dtype=F64))


# ---------------------------------------------------------------- integrators


def _oscillator(integrator: str, dt: float):
    """q̈ = −q from q = (1, 0), q̇ = (0, 1): exactly q(t) = (cos t, sin t), q̇(t) = (−sin t, cos t)."""
    env = Particle2D(n_obstacles=0, dt=dt, integrator=integrator)
    q0 = torch.tensor([[1.0, 0.0]], dtype=F64)
    qd0 = torch.tensor([[0.0, 1.0]], dtype=F64)
    aux = {"goal": torch.tensor([[9.0, 9.0]], dtype=F64)}
    r = env.rollout(lambda q, qd, aux: -q, q0, qd0, aux, horizon=1.0, record_every=0.1)
    t = r.times[:, None]
    exact_q = torch.cat([t.cos(), t.sin()], -1)
    exact_qd = torch.cat([-t.sin(), t.cos()], -1)
    return r, (r.q[:, 0] - exact_q).abs().max().item(), (r.qd[:, 0] - exact_qd).abs().max().item()


def test_rk4_matches_the_harmonic_oscillator():
    r, eq, eqd = _oscillator("rk4", 0.01)
    assert isinstance(r, Rollout)
    assert r.times.shape == (11,) and r.q.shape == r.qd.shape == r.qdd.shape == (11, 1, 2)
    assert torch.allclose(r.times, torch.linspace(0, 1, 11, dtype=F64))
    assert eq < 1e-8 and eqd < 1e-8
    assert torch.equal(r.qdd, -r.q)  # recorded accelerations are the policy at the recorded states
    assert r.V is None and r.dissipation is None
    assert r.collided.tolist() == [False] and r.success.tolist() == [False]


def test_semi_implicit_euler_is_first_order():
    _, e1, _ = _oscillator("semi_implicit_euler", 0.01)
    _, e2, _ = _oscillator("semi_implicit_euler", 0.005)
    assert e1 < 0.01
    assert 1.7 < e1 / e2 < 2.3
    _, r1, _ = _oscillator("rk4", 0.02)
    _, r2, _ = _oscillator("rk4", 0.01)
    assert 12 < r1 / r2 < 20  # fourth order


def test_rollout_rejects_misaligned_times_and_calls_hooks():
    env = Particle2D(n_obstacles=0, dt=0.01)
    q0, qd0 = torch.zeros(2, 2, dtype=F64), torch.zeros(2, 2, dtype=F64)
    aux = {"goal": torch.zeros(2, 2, dtype=F64)}
    pol = lambda q, qd, aux: -q
    with pytest.raises(ValueError, match="record_every"):
        env.rollout(pol, q0, qd0, aux, horizon=1.0, record_every=0.015)
    seen, prog = [], []
    r = env.rollout(
        pol,
        q0,
        qd0,
        aux,
        horizon=0.5,
        record_every=0.2,
        monitor=lambda i, t, q, qd, qdd, V: seen.append((i, round(t, 6))),
        progress=lambda k, n: prog.append((k, n)),
    )
    assert seen == [(0, 0.0), (1, 0.2), (2, 0.4)] and r.times.shape == (3,)
    assert prog[-1] == (50, 50) and prog[0] == (0, 50)
    assert r.success.all()  # at rest on the goal


def test_collision_is_caught_between_records():
    env = Particle2D(dt=0.01, integrator="semi_implicit_euler")
    aux = {
        "goal": torch.tensor([[4.0, 0.0]], dtype=F64),
        "obstacle1_center": torch.tensor([[0.0, 0.0]], dtype=F64),
        "obstacle1_radius": torch.tensor([[0.5]], dtype=F64),
    }
    q0 = torch.tensor([[-1.0, 0.0]], dtype=F64)
    qd0 = torch.tensor([[2.0, 0.0]], dtype=F64)
    r = env.rollout(lambda q, qd, aux: torch.zeros_like(q), q0, qd0, aux, horizon=2.0, record_every=2.0)
    assert r.times.tolist() == [0.0, 2.0]  # the records straddle the crossing of the obstacle
    assert r.collided.tolist() == [True] and r.min_clearance.item() < -0.4
    assert not r.success.any()


# ---------------------------------------------------------------- Lyapunov utilities


def test_lyapunov_monotone_rule():
    V = torch.tensor([[1.0, 1.0, 0.9, 1e-10, 1.0], [0.5, 1.0 + 5e-7, 1.0, 2e-10, float("nan")]], dtype=F64)
    ok = lyapunov_monotone(V)
    # col0: decreasing; col1: +5e-7 on |V|≈1 is within rtol; col2: a 10% rise; col3: tiny absolute rise; col4: NaN
    assert ok.tolist() == [True, True, False, True, False]
    assert not lyapunov_monotone(V, rtol=1e-7)[1]
    inc = max_relative_increase(V)
    assert inc[0] <= 0 and inc[2] > 0.09 and math.isinf(inc[4])


# ---------------------------------------------------------------- a real RMPTree: 2d1level

SPEC_2D1LEVEL = {
    "root": {"name": "q", "dim": 2},
    "nodes": {
        "obstacle": {
            "parent": "q",
            "map": {"type": "sphere_distance", "center": "obstacle1_center", "radius": "obstacle1_radius"},
            "rmp": {"type": "collision_avoidance"},
        },
        # gain 2: cruise speed gain/eta = 1 m/s, so the ~5.5 m trips fit in 10 s (gain 1 needs ~20 s)
        "goal": {
            "parent": "q",
            "map": {"type": "offset", "origin": "goal"},
            "rmp": {"type": "goal_attractor", "gain": 2.0},
        },
    },
}


@pytest.fixture(scope="module")
def tree_rollout():
    env = Particle2D(n_obstacles=1)  # defaults: rk4, dt = 0.01 (dt = 0.02 already breaks monotonicity near the barrier)
    tree = rmpfusion.build_tree(SPEC_2D1LEVEL, aux_dims=env.aux_dims())
    q0, qd0, aux = env.sample(4, 4, seed=1)
    r = env.rollout(tree, q0, qd0, aux, horizon=10.0, record_every=0.1)
    return env, tree, aux, r


def test_tree_rollout_is_safe_stable_and_reaches(tree_rollout):
    _env, tree, aux, r = tree_rollout
    B = 16
    assert r.q.shape == (101, B, 2) and r.V.shape == r.dissipation.shape == (101, B)
    assert not r.collided.any()
    assert (r.min_clearance > 0).all()
    assert lyapunov_monotone(r.V).all(), max_relative_increase(r.V).max()
    assert (r.V[-1] < r.V[0]).all()
    rate = r.success.float().mean().item()
    print(f"2d1level success rate over 10 s: {rate:.2f}")
    assert rate >= 0.6
    # the records are consistent with the tree evaluated at the recorded states
    out = tree(r.q[37], r.qd[37], aux)
    assert torch.allclose(out.qdd, r.qdd[37]) and torch.allclose(out.V, r.V[37])
    assert not r.V.requires_grad


def test_tree_rollout_obeys_the_energy_rate(tree_rollout):
    _, _, _, r = tree_rollout
    res = energy_rate_residual(r.times, r.V, r.dissipation)
    assert res.shape == (99, 16)
    # dV/dt = −q̇ᵀBq̇ up to the central-difference error; the dissipation itself is O(1)
    assert (r.dissipation >= -1e-12).all()
    assert res.abs().median() < 1e-2 * r.dissipation.abs().max()
