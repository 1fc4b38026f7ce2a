"""Weight functions: positive by construction, ∇_x w against finite differences, gradients reach parameters."""
import pytest
import torch

from conftest import fd_jacobian
from rmpfusion.core.weight import WeightFunction
from rmpfusion.registry import WEIGHTS

AUX = {"goal": 2, "obstacle_center": 2, "obstacle_radius": 1}


def make(name, in_dim=2, **params):
    e = WEIGHTS.get(name)
    return e.obj(e.validate(params), in_dim, AUX).double()


def aux(B, gen):
    return {"goal": torch.randn(B, 2, generator=gen), "obstacle_center": torch.randn(B, 2, generator=gen),
            "obstacle_radius": 0.5 + torch.rand(B, 1, generator=gen)}


CASES = [
    ("rbf", {"low": 0.5, "high": 4.0, "center": "obstacle_center", "radius": "obstacle_radius", "sigma": 0.7}),
    ("rbf", {"low": 2.0, "high": 0.1, "center": [1.0, -1.0]}),
    ("logistic", {"low": 0.2, "high": 3.0, "center": "obstacle_center", "radius": "obstacle_radius", "steepness": -3.0, "switch_distance": 0.5}),
    ("mlp", {"hidden": [16, 16], "aux": ["goal", "obstacle_center", "obstacle_radius"]}),
    ("mlp", {"hidden": [8], "activation": "softplus", "positivity": "exp"}),
    ("mlp", {"hidden": [8, 8, 8], "activation": "elu"}),
    ("mlp", {"hidden": [8], "activation": "silu", "aux": ["goal"]}),
    ("mlp", {"hidden": [8], "activation": "sigmoid"}),
]


@pytest.mark.parametrize("name,params", CASES)
def test_gradient_matches_finite_differences_and_weight_is_positive(name, params, gen):
    w = make(name, **params)
    if name == "mlp":
        for p in w.parameters():
            torch.nn.init.normal_(p, std=0.8, generator=gen)
    B = 7
    x, a = 2 * torch.randn(B, 2, generator=gen), aux(B, gen)
    val, grad = w(x, a)
    assert val.shape == (B,) and (val > 0).all()
    fd = fd_jacobian(lambda z: w.value(z, a)[:, None], x)[:, 0, :]
    torch.testing.assert_close(grad, fd, rtol=1e-6, atol=1e-8)
    # agrees with the autodiff default of the base class
    torch.testing.assert_close(grad, WeightFunction.forward(w, x, a)[1], rtol=1e-10, atol=1e-12)


def test_constant_weight_has_no_gradient_term():
    w = make("constant", value=2.5)
    val, grad = w(torch.zeros(3, 2), None)
    assert grad is None and torch.equal(val, torch.full((3,), 2.5))


def test_non_positive_constant_rejected():
    from pydantic import ValidationError
    with pytest.raises(ValidationError, match="greater than 0"):
        make("constant", value=0.0)


def test_mlp_stays_positive_for_extreme_outputs(gen):
    w = make("mlp", hidden=[4], floor=1e-3)
    with torch.no_grad():
        w.layers[-1].bias.fill_(-1e4)
    val, _ = w(torch.randn(5, 2, generator=gen), aux(5, gen))
    assert (val >= 1e-3).all()


def test_mlp_init_bias_sets_the_initial_weight(gen):
    w = make("mlp", hidden=[8], init_bias=0.7)
    val, grad = w(torch.randn(4, 2, generator=gen), aux(4, gen))
    torch.testing.assert_close(val, torch.full((4,), 0.7))


def test_input_gradient_is_differentiable_in_the_parameters(gen):
    """The h_i terms use ∇_x w, so training needs d(∇_x w)/dθ; compare with torch's double backward."""
    w = make("mlp", hidden=[8, 8], aux=["goal"])
    x, a = torch.randn(5, 2, generator=gen), aux(5, gen)
    _, grad = w(x, a)
    g1 = torch.autograd.grad(grad.pow(2).sum(), list(w.parameters()))
    xx = x.clone().requires_grad_()
    gx, = torch.autograd.grad(w.value(xx, a).sum(), xx, create_graph=True)
    g2 = torch.autograd.grad(gx.pow(2).sum(), list(w.parameters()))
    for a_, b_ in zip(g1, g2):
        torch.testing.assert_close(a_, b_)


def test_unknown_aux_feature_is_reported():
    with pytest.raises(ValueError, match=r"mlp.aux names \['gaol'\] are not declared"):
        make("mlp", aux=["gaol"])
