"""Leaf RMPs beyond the registry-driven finite-difference check of M and f (test_registry_derivatives.py):
barrier behaviour, and the RMPflow ports against an independent transcription of RMPflow's reference code."""

import numpy as np
import pytest
import rmpflow_reference as ref
import torch
from scipy.integrate import quad

from rmpfusion.registry import LEAF_RMPS


def make(name, dim, **params):
    entry = LEAF_RMPS.get(name)
    return entry.obj(entry.validate(params), dim)


def test_barrier_inside_obstacle_is_finite_and_pushes_out():
    leaf = make("collision_avoidance", 1, alpha=1.0)
    y = torch.tensor([[-0.5], [0.0], [1e-9]])
    out = leaf(y, torch.zeros(3, 1))
    assert torch.isfinite(out.f).all() and torch.isfinite(out.M).all()
    assert (out.f[:, 0] > 0).all()  # a positive force on the distance coordinate: away from the obstacle


def test_barrier_inactive_beyond_support():
    leaf = make("collision_avoidance", 1, r_w=0.5)
    out = leaf(torch.tensor([[0.6]]), torch.tensor([[-1.0]]))
    assert float(out.G.abs().max()) == 0.0 and float(out.f.abs().max()) == 0.0


@pytest.mark.parametrize("x,xd", [(0.7, -1.3), (0.2, 0.4), (-0.1, -0.5), (3.0, 0.0)])
def test_rmpflow_collision_avoidance_matches_reference(x, xd):
    leaf = make("rmpflow_collision_avoidance", 1)
    out = leaf(torch.tensor([[x]]), torch.tensor([[xd]]))
    f, M = ref.collision_avoidance(x, xd)
    np.testing.assert_allclose(out.f[0].numpy(), f, rtol=1e-12)
    np.testing.assert_allclose(out.M[0].numpy(), M, rtol=1e-12)


def test_rmpflow_goal_attractor_matches_reference(gen):
    leaf = make("rmpflow_goal_attractor", 2)
    for _ in range(10):
        x, xd = 3 * torch.randn(2, generator=gen), torch.randn(2, generator=gen)
        out = leaf(x[None], xd[None])
        f, M = ref.goal_attractor(x.numpy(), xd.numpy())
        np.testing.assert_allclose(out.f[0].numpy(), f, rtol=1e-12, atol=1e-14)
        np.testing.assert_allclose(out.M[0].numpy(), M, rtol=1e-12)


def test_rmpflow_goal_attractor_potential_is_the_radial_integral():
    leaf = make("rmpflow_goal_attractor", 2, gain=1.5, sigma=0.8)
    r = torch.tensor([0.001, 0.005, 0.01, 0.3, 1.0, 2.5, 7.0, 30.0])
    Phi = leaf.potential(r)

    def grad_norm(s):
        w = (leaf.w_u - leaf.w_l) * np.exp(-s * s / (2 * leaf.sigma**2)) + leaf.w_l
        return leaf.gain * w * np.tanh(leaf.alpha * s)

    for ri, Pi in zip(r.tolist(), Phi.tolist()):
        expect = quad(grad_norm, leaf.tol, ri, epsabs=1e-14, epsrel=1e-13, limit=200)[0] if ri > leaf.tol else 0.0
        assert abs(Pi - expect) <= 1e-11 * max(1.0, abs(expect))
    # and its gradient is the leaf's ∇Φ (used in f)
    rr = torch.tensor([0.4, 1.7, 4.0])
    dPhi = (leaf.potential(rr + 1e-6) - leaf.potential(rr - 1e-6)) / 2e-6
    torch.testing.assert_close(dPhi, torch.as_tensor(grad_norm(rr.numpy())), rtol=1e-8, atol=1e-9)


def test_rmpflow_damper_matches_reference(gen):
    leaf = make("rmpflow_damper", 3, w=2.0, eta=0.5)
    x, xd = torch.randn(3, generator=gen), torch.randn(3, generator=gen)
    out = leaf(x[None], xd[None])
    f, M = ref.damper(x.numpy(), xd.numpy(), w=2.0, eta=0.5)
    np.testing.assert_allclose(out.f[0].numpy(), f, rtol=1e-14)
    np.testing.assert_allclose(out.M[0].numpy(), M, rtol=1e-14)


def test_fixed_dimension_leaf_rejects_other_dimensions():
    with pytest.raises(ValueError, match="1-dimensional"):
        make("collision_avoidance", 2)


def test_params_are_validated_with_clear_errors():
    from pydantic import ValidationError

    with pytest.raises(ValidationError, match="epsilon"):
        make("rmpflow_collision_avoidance", 1, epsilon=-1.0)
    with pytest.raises(ValidationError, match="Extra inputs are not permitted"):
        make("damper", 2, gian=1.0)
