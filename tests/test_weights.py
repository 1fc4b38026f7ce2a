"""Weight functions: constants, positivity at extremes, initial values, gradients that reach the parameters. w > 0
and ∇_x w of every registered weight against finite differences are checked in test_registry_derivatives.py."""

import pytest
import torch

from rmpfusion.registry import WEIGHTS

AUX = {"goal": 2, "obstacle_center": 2, "obstacle_radius": 1}


def make(name, in_dim=2, **params):
    e = WEIGHTS.get(name)
    return e.obj(e.validate(params), in_dim, AUX).double()


def aux(B, gen):
    return {
        "goal": torch.randn(B, 2, generator=gen),
        "obstacle_center": torch.randn(B, 2, generator=gen),
        "obstacle_radius": 0.5 + torch.rand(B, 1, generator=gen),
    }


def test_constant_weight_has_no_gradient_term():
    w = make("constant", value=2.5)
    val, grad = w(torch.zeros(3, 2), None)
    assert grad is None and torch.equal(val, torch.full((3,), 2.5))


def test_non_positive_constant_rejected():
    from pydantic import ValidationError

    with pytest.raises(ValidationError, match="constant weight must be > 0"):
        make("constant", value=0.0)


def test_mlp_stays_positive_for_extreme_outputs(gen):
    w = make("mlp", hidden=[4], floor=1e-3)
    with torch.no_grad():
        w.layers[-1].bias.fill_(-1e4)
    val, _ = w(torch.randn(5, 2, generator=gen), aux(5, gen))
    assert (val >= 1e-3).all()


def test_mlp_init_bias_sets_the_initial_weight(gen):
    w = make("mlp", hidden=[8], init_bias=0.7)
    val, _grad = w(torch.randn(4, 2, generator=gen), aux(4, gen))
    torch.testing.assert_close(val, torch.full((4,), 0.7))


def test_input_gradient_is_differentiable_in_the_parameters(gen):
    """The h_i terms use ∇_x w, so training needs d(∇_x w)/dθ; compare with torch's double backward."""
    w = make("mlp", hidden=[8, 8], aux=["goal"])
    x, a = torch.randn(5, 2, generator=gen), aux(5, gen)
    _, grad = w(x, a)
    g1 = torch.autograd.grad(grad.pow(2).sum(), list(w.parameters()))
    xx = x.clone().requires_grad_()
    (gx,) = torch.autograd.grad(w.value(xx, a).sum(), xx, create_graph=True)
    g2 = torch.autograd.grad(gx.pow(2).sum(), list(w.parameters()))
    for a_, b_ in zip(g1, g2):
        torch.testing.assert_close(a_, b_)


def test_unknown_aux_feature_is_reported():
    with pytest.raises(ValueError, match=r"mlp.aux names \['gaol'\] are not declared"):
        make("mlp", aux=["gaol"])
