"""The moving-goal attractor and what docs/math.md §8 ("Moving goals") claims for it:

1. aux held fixed (a goal velocity included): an exact GDS, Theorem 2 on rollouts;
2. the tracker alone on its space, the goal at constant velocity: the goal-frame energy E = ½w|ė|² + Φ₀(e) never
   increases and the error vanishes, where goal_attractor trails by atanh(η·w·|ġ|/gain)/α;
3. an accelerating goal: dE/dt = −η·w·|ė|² − w·ėᵀg̈;
4. any tree with moving aux: dV_r/dt = −q̇ᵀB_r q̇ + ∂_t V_r (the change of V_r through aux alone), and V_r rises.
(M and f against the GDS definitions by finite differences: tests/test_registry_derivatives.py.)"""

import math

import torch
from conftest import assert_energy_identity, assert_lyapunov_non_increasing, rk4_rollout
from manipulators import PANDA_ARM as PANDA_ROBOT
from manipulators import PANDA_HOME as HOME

import rmpfusion

GAIN, ALPHA, ETA, W = 2.0, 3.0, 2.0, 1.0
AUX_DIMS = {"goal": 3, "goal_velocity": 3}


def point_tree(leaf: str):
    """A point in 3-D (the root is the leaf's space) pulled by one attractor with the gains above."""
    if leaf == "moving_goal_attractor":
        node = {
            "map": {"type": "moving_offset", "origin": "goal", "velocity": "goal_velocity"},
            "rmp": {"type": leaf, "gain": GAIN, "alpha": ALPHA, "eta": ETA, "w": W},
        }
    else:
        node = {
            "map": {"type": "offset", "origin": "goal"},
            "rmp": {"type": leaf, "gain": GAIN, "alpha": ALPHA, "eta": ETA},
        }
    return rmpfusion.build_tree(
        {"root": {"name": "x", "dim": 3}, "aux": AUX_DIMS, "nodes": {"goal": {"parent": "x", **node}}}
    )


def panda_tracking_tree():
    """The Panda's end effector tracks the goal through a random positive neural weight (pullback*'s h terms take
    part); a damper and the identity metric on the joints."""
    torch.manual_seed(0)
    return rmpfusion.build_tree(
        {
            "root": {"name": "q", "dim": 7},
            "aux": AUX_DIMS,
            "nodes": {
                "ee": {
                    "parent": "q",
                    "map": {
                        "type": "forward_kinematics",
                        **PANDA_ROBOT,
                        "link": "panda_hand",
                        "offset": [0, 0, 0.1034],
                    },
                },
                "track": {
                    "parent": "ee",
                    "map": {"type": "moving_offset", "origin": "goal", "velocity": "goal_velocity"},
                    "weight": {"type": "mlp", "hidden": [16], "aux": ["goal", "goal_velocity"]},
                    "rmp": {"type": "moving_goal_attractor", "gain": 5.0, "alpha": 10.0, "eta": 5.0},
                },
                "damper": {"parent": "q", "map": {"type": "identity"}, "rmp": {"type": "damper", "w": 0.1, "eta": 2.0}},
                "regulariser": {"parent": "q", "map": {"type": "identity"}, "rmp": {"type": "identity_metric"}},
            },
        }
    )


def circle(centre, radius=0.15, speed=1.0):
    """A goal on a horizontal circle: aux(t) with the goal's position and velocity, and its acceleration."""

    def at(t):
        c, s = math.cos(speed * t), math.sin(speed * t)
        goal = centre + radius * torch.tensor([c, s, 0.0])
        velocity = radius * speed * torch.tensor([-s, c, 0.0])
        return {"goal": goal.expand(centre.shape[0], 3), "goal_velocity": velocity.expand(centre.shape[0], 3)}

    accel = lambda t: -radius * speed**2 * torch.tensor([math.cos(speed * t), math.sin(speed * t), 0.0])
    return at, accel


def goal_frame_energy(rec, at):
    goals = [at(float(t)) for t in rec["t"]]
    e = rec["q"] - torch.stack([a["goal"] for a in goals])
    ed = rec["qd"] - torch.stack([a["goal_velocity"] for a in goals])
    return e, ed, 0.5 * W * (ed * ed).sum(-1) + GAIN * torch.log(torch.cosh(ALPHA * e.norm(dim=-1))) / ALPHA


# ------------------------------------------------------------------------------------------------ claim 1
def test_theorem_2_holds_with_aux_held_fixed_goal_velocity_included():
    tree = panda_tracking_tree()
    g = torch.Generator().manual_seed(1)
    q0 = HOME + 0.3 * torch.randn(4, 7, generator=g)
    aux = {
        "goal": torch.tensor([[0.45, -0.2, 0.45]]) + 0.1 * torch.randn(4, 3, generator=g),
        "goal_velocity": 0.3 * torch.randn(4, 3, generator=g),
    }  # held fixed: the goal does not move
    rec = rk4_rollout(tree, q0, torch.zeros(4, 7), aux, dt=0.01, steps=150)
    assert_lyapunov_non_increasing(rec)
    assert_energy_identity(
        tree, rec["q"][::30].flatten(0, 1), rec["qd"][::30].flatten(0, 1), {k: v.repeat(6, 1) for k, v in aux.items()}
    )


# ------------------------------------------------------------------------------------------------ claim 2
def test_a_goal_at_constant_velocity_is_tracked_without_lag_where_goal_attractor_trails():
    g = torch.Generator().manual_seed(0)
    g0, x0 = torch.randn(3, 3, generator=g), torch.randn(3, 3, generator=g)
    v = torch.randn(3, 3, generator=g)
    v = 0.6 * v / v.norm(dim=-1, keepdim=True)
    at = lambda t: {"goal": g0 + t * v, "goal_velocity": v}
    tracked = rk4_rollout(point_tree("moving_goal_attractor"), x0, torch.zeros(3, 3), at, dt=0.01, steps=800)
    e, _, E = goal_frame_energy(tracked, at)
    assert (E[1:] - E[:-1] <= 1e-9 * (1 + E[:-1])).all() and float(E[-1].max()) < 1e-3 * float(E[0].min())
    assert float(e[-1].norm(dim=-1).max()) < 0.01
    trailed = rk4_rollout(point_tree("goal_attractor"), x0, torch.zeros(3, 3), at, dt=0.01, steps=800)
    lag = goal_frame_energy(trailed, at)[0][-1].norm(dim=-1)
    torch.testing.assert_close(lag, torch.full((3,), math.atanh(ETA * W * 0.6 / GAIN) / ALPHA), rtol=0.05, atol=0)


# ------------------------------------------------------------------------------------------------ claim 3
def test_an_accelerating_goal_changes_the_goal_frame_energy_by_its_acceleration():
    at, accel = circle(torch.zeros(2, 3), radius=0.5, speed=1.5)
    h = 0.01
    rec = rk4_rollout(
        point_tree("moving_goal_attractor"),
        torch.tensor([[1.0, 0.5, 0.2], [-0.5, 0.0, 0.3]]),
        torch.zeros(2, 3),
        at,
        dt=h,
        steps=300,
    )
    _, ed, E = goal_frame_energy(rec, at)
    rate = (E[2:] - E[:-2]) / (2 * h)
    g_dd = torch.stack([accel(float(t)) for t in rec["t"][1:-1]])[:, None, :]
    expect = -ETA * W * (ed[1:-1] ** 2).sum(-1) - W * (ed[1:-1] * g_dd).sum(-1)
    assert float((rate - expect).abs().max()) < 1e-3 * float(expect.abs().max())
    assert float(expect.max()) > 0  # E does rise at times: the acceleration term is not negligible


# ------------------------------------------------------------------------------------------------ claim 4
def test_v_r_changes_by_the_dissipation_and_the_goals_motion():
    tree = panda_tracking_tree()
    at, _ = circle(torch.tensor([[0.45, 0.0, 0.45], [0.4, -0.2, 0.5]]), radius=0.15, speed=2.0)
    g = torch.Generator().manual_seed(2)
    h = 0.01
    rec = rk4_rollout(tree, HOME + 0.2 * torch.randn(2, 7, generator=g), torch.zeros(2, 7), at, dt=h, steps=150)
    V, P = rec["V"], rec["dissipation"]
    rate = (V[2:] - V[:-2]) / (2 * h)
    eps = 1e-6
    with torch.no_grad():
        through_aux = torch.stack(
            [
                (tree(q, qd, at(float(t) + eps)).V - tree(q, qd, at(float(t) - eps)).V) / (2 * eps)
                for t, q, qd in zip(rec["t"][1:-1], rec["q"][1:-1], rec["qd"][1:-1])
            ]
        )
    expect = -P[1:-1] + through_aux
    assert float((rate - expect).abs().max()) < 2e-3 * float(expect.abs().max())
    assert float((V[1:] - V[:-1]).max()) > 0  # V_r is not monotone while the goal moves ...
    assert float(through_aux.abs().max()) > 0.1 * float(P.abs().max())  # ... because of the aux term
