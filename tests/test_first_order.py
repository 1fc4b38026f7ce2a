"""The first-order baseline for recorded demonstrations: its field moves the latent point as ż = −r·z exactly (so the
goal is reached from anywhere), and training reaches its learned rate (the tracking both baselines share:
test_velocity_tracking.py)."""

from __future__ import annotations

import torch

from rmpfusion.registry import LEARNERS


def learner(seed: int = 0, **params):
    torch.manual_seed(seed)
    entry = LEARNERS.get("first_order")
    return entry.obj(entry.validate({"init_std": 0.5, "scale": 0.5, "rate": 1.5, **params}), None, {"goal": 2}, 2)


def latent(m, x, goal):
    n = (x - goal) / m.params.scale
    return m.psi(n, torch.zeros_like(n))[0]


def test_the_field_decays_the_latent_point_exponentially_to_the_goal():
    m = learner()
    gen = torch.Generator().manual_seed(1)
    x = 2.0 * torch.randn(32, 2, generator=gen, dtype=torch.float64)
    goal = {"goal": 0.3 * torch.randn(32, 2, generator=gen, dtype=torch.float64)}
    z0 = latent(m, x, goal["goal"]).detach()
    dt, steps = 1e-3, 1000  # RK4 on ẋ = f(x) for 1 s
    with torch.no_grad():
        for _ in range(steps):
            k1 = m.field(x, goal)
            k2 = m.field(x + 0.5 * dt * k1, goal)
            k3 = m.field(x + 0.5 * dt * k2, goal)
            k4 = m.field(x + dt * k3, goal)
            x = x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    z1 = latent(m, x, goal["goal"]).detach()
    torch.testing.assert_close(z1, z0 * torch.exp(torch.tensor(-1.5)), rtol=1e-7, atol=1e-10)  # RK4 at 1 ms: ~1e-8
    assert float((z1 - z0).abs().max()) > 0.1  # it moved


def test_training_differentiates_through_the_field_derivative():
    m = learner(seed=4)
    q = torch.randn(4, 2, dtype=torch.float64)
    qd = torch.randn(4, 2, dtype=torch.float64)
    loss = m(q, qd, {"goal": torch.zeros(4, 2, dtype=torch.float64)}).square().sum()
    loss.backward()
    grads = [p.grad for p in m.parameters()]
    assert all(g is not None and torch.isfinite(g).all() for g in grads)
    assert m.log_rate.grad is not None and float(m.log_rate.grad.abs()) > 0
