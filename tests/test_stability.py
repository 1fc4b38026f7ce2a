"""Theorem 2 on real rollouts: random trees of depth ≥ 2 with random positive neural weights and
velocity-dependent collision metrics; V_r never increases and dV_r/dt = −q̇ᵀB_r q̇."""

import pytest
import torch
from trees import setup

import rmpfusion


def rk4_rollout(tree, q, qd, aux, dt, steps):
    """Independent closed-loop integrator; records V_r and q̇ᵀB_r q̇ at every step."""
    Vs, Ps = [], []
    f = lambda q_, qd_: tree(q_, qd_, aux)
    with torch.no_grad():
        for _ in range(steps + 1):
            o = f(q, qd)
            Vs.append(o.V)
            Ps.append(torch.einsum("bi,bij,bj->b", qd, o.B, qd))
            a1 = o.qdd
            k2q, k2v = qd + 0.5 * dt * a1, f(q + 0.5 * dt * qd, qd + 0.5 * dt * a1).qdd
            k3q, k3v = qd + 0.5 * dt * k2v, f(q + 0.5 * dt * k2q, qd + 0.5 * dt * k2v).qdd
            k4q, k4v = qd + dt * k3v, f(q + dt * k3q, qd + dt * k3v).qdd
            q = q + dt / 6 * (qd + 2 * k2q + 2 * k3q + k4q)
            qd = qd + dt / 6 * (a1 + 2 * k2v + 2 * k3v + k4v)
    return torch.stack(Vs), torch.stack(Ps)


@pytest.mark.parametrize("seed,dim", [(0, 2), (1, 2), (2, 3)])
def test_lyapunov_non_increasing_on_rollouts(seed, dim):
    tree, q, qd, aux = setup(seed, dim, B=6)
    dt, steps = 2e-3, 400
    V, P = rk4_rollout(tree, q, qd, aux, dt, steps)
    dV = V[1:] - V[:-1]
    assert (dV <= 1e-9 * (1 + V[:-1].abs())).all(), f"V increased by up to {float(dV.max()):.3e}"
    assert (V[-1] < V[0]).all()  # and it actually dissipates
    # (V(t+dt) − V(t))/dt ≈ −q̇ᵀB_r q̇ (trapezoid on P: second-order accurate)
    rate = dV / dt
    expect = -0.5 * (P[1:] + P[:-1])
    scale = P.abs().max(dim=0).values + 1e-6
    assert ((rate - expect).abs() / scale).max() < 1e-3


@pytest.mark.parametrize("seed,dim", [(3, 2), (4, 3)])
def test_energy_identity_is_exact_at_any_state(seed, dim):
    """dV_r/dt along q̈ = π(q, q̇) by a central difference in time, against −q̇ᵀB_r q̇, at single states."""
    tree, q, qd, aux = setup(seed, dim, B=16)
    with torch.no_grad():
        o = tree(q, qd, aux)
        eps = 1e-5
        Vp = tree(q + eps * qd, qd + eps * o.qdd, aux).V
        Vm = tree(q - eps * qd, qd - eps * o.qdd, aux).V
    dVdt = (Vp - Vm) / (2 * eps)
    expect = -torch.einsum("bi,bij,bj->b", qd, o.B, qd)
    torch.testing.assert_close(dVdt, expect, rtol=1e-6, atol=1e-7)


def test_energy_identity_fails_without_h_terms():
    """The h_i correction is what makes Theorem 2 hold: dropping it breaks the identity (guards the test above)."""
    from rmpfusion.core import algebra

    tree, q, qd, aux = setup(5, 2, B=16)
    original = algebra.edge_contribution

    def without_h(xd, edge, child):
        return original(xd, edge._replace(grad_w=None), child)

    import rmpfusion.core.passes as tree_mod

    tree_mod.edge_contribution = without_h
    try:
        with torch.no_grad():
            o = tree(q, qd, aux)
            eps = 1e-5
            dVdt = (tree(q + eps * qd, qd + eps * o.qdd, aux).V - tree(q - eps * qd, qd - eps * o.qdd, aux).V) / (
                2 * eps
            )
    finally:
        tree_mod.edge_contribution = original
    expect = -torch.einsum("bi,bij,bj->b", qd, o.B, qd)
    assert (dVdt - expect).abs().max() > 1e-3


def test_energy_identity_on_the_franka_tree_even_with_penetrating_control_points():
    """The paper's Franka tree with the expert's weights, at states where control spheres overlap the obstacle."""
    from pathlib import Path

    import yaml
    from manipulators import franka_tree_spec

    from rmpfusion.envs.manipulator_tree import with_weights

    expert = yaml.safe_load((Path(__file__).parents[1] / "conf" / "expert" / "franka.yaml").read_text())
    tree = rmpfusion.build_tree(with_weights(franka_tree_spec(), expert))
    g = torch.Generator().manual_seed(0)
    B = 8
    q = torch.tensor([0.0, -0.3, 0.0, -2.2, 0.0, 2.0, 0.8]) + 0.3 * torch.randn(B, 7, generator=g)
    qd = 0.5 * torch.randn(B, 7, generator=g)
    aux = {
        "goal": torch.tensor([[0.5, -0.3, 0.4]]).expand(B, 3),
        "obstacle1_center": torch.tensor([[0.5, 0.0, 0.25]]).expand(B, 3),
        "obstacle1_radius": torch.tensor([[0.05]]).expand(B, 1),
    }
    with torch.no_grad():
        o = tree(q, qd, aux, return_nodes=True)
        dists = torch.cat([o.nodes["state"][n][0] for n in o.nodes["state"] if n.endswith("_obstacle1")], dim=1)
        assert (dists < 0).any()  # the scenario really has penetration

        # the barriers make V large (hundreds) and stiff inside obstacles and are only C¹ at their switch points,
        # so a central difference needs a small step; the tolerance is relative to V's scale
        eps = 1e-7
        dVdt = (tree(q + eps * qd, qd + eps * o.qdd, aux).V - tree(q - eps * qd, qd - eps * o.qdd, aux).V) / (2 * eps)
    expect = -torch.einsum("bi,bij,bj->b", qd, o.B, qd)
    torch.testing.assert_close(dVdt, expect, rtol=1e-6, atol=2e-8 * float(o.V.abs().max()))
