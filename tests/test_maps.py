"""Every task map: J and J̇ẋ against finite differences; analytic paths against the autodiff base."""
import pytest
import torch

from conftest import fd_directional, fd_jacobian
from rmpfusion.core.taskmap import TaskMap
from rmpfusion.maps.basic import build_map

AUX = {"c": 2, "r": 1, "c3": 3}

CASES = [
    ("identity", {}, 2),
    ("offset", {"origin": [-3.0, 3.0]}, 2),
    ("offset", {"origin": "c"}, 2),
    ("linear", {"matrix": [[1.0, 2.0], [0.5, -1.0], [3.0, 0.0]], "bias": [1.0, 0.0, -1.0]}, 2),
    ("select", {"indices": [2, 0]}, 3),
    ("sphere_distance", {"center": [0.3, -0.2], "radius": 1.5}, 2),
    ("sphere_distance", {"center": "c", "radius": "r", "normalized": True}, 2),
    ("cylinder_distance", {"center": [0.1, 0.2, 0.0], "radius": 0.3, "axis": [0.0, 0.3, 1.0]}, 3),
    ("box_distance", {"center": [0.0, 0.0, 0.0], "half_extents": [0.5, 1.0, 0.25]}, 3),
    ("joint_limit", {"side": "upper", "limit": [2.0, 1.0, 0.5]}, 3),
    ("joint_limit", {"side": "lower", "limit": -1.0, "joints": [1]}, 3),
    ("compose", {"maps": [{"type": "linear", "matrix": [[1.0, 1.0], [0.0, 2.0], [1.0, -1.0]]},
                          {"type": "sphere_distance", "center": [1.0, 0.0, 0.5], "radius": 0.2}]}, 2),
    ("compose", {"maps": [{"type": "offset", "origin": "c"}, {"type": "sphere_distance", "center": [0.0, 0.0]}]}, 2),
]


def _aux(B, gen):
    return {"c": torch.randn(B, 2, generator=gen), "r": 0.5 + torch.rand(B, 1, generator=gen),
            "c3": torch.randn(B, 3, generator=gen)}


@pytest.mark.parametrize("name,params,dim", CASES, ids=[f"{c[0]}-{i}" for i, c in enumerate(CASES)])
def test_jacobian_and_curvature_match_finite_differences(name, params, dim, gen):
    m = build_map({"type": name, **params}, dim, AUX).double()
    B = 6
    x = 3 * torch.randn(B, dim, generator=gen)
    xd = torch.randn(B, dim, generator=gen)
    aux = _aux(B, gen)
    y, yd, J, c = m(x, xd, aux)
    assert y.shape == (B, m.out_dim) and J.shape == (B, m.out_dim, dim) and c.shape == (B, m.out_dim)
    psi = lambda z: m.psi(z, aux)  # noqa: E731
    torch.testing.assert_close(y, psi(x))
    torch.testing.assert_close(J, fd_jacobian(psi, x), atol=1e-7, rtol=1e-6)
    torch.testing.assert_close(yd, (J @ xd[..., None])[..., 0])
    # J̇ẋ = d/dt [J(x + t ẋ) ẋ] at t = 0
    Jxd = lambda z: (m(z, xd, aux)[2] @ xd[..., None])[..., 0]  # noqa: E731
    torch.testing.assert_close(c, fd_directional(Jxd, x, xd), atol=1e-6, rtol=1e-5)


@pytest.mark.parametrize("name,params,dim", [c for c in CASES if c[0] not in ("box_distance",)])
def test_analytic_derivatives_equal_autodiff(name, params, dim, gen):
    m = build_map({"type": name, **params}, dim, AUX).double()
    x, xd, aux = torch.randn(5, dim, generator=gen), torch.randn(5, dim, generator=gen), _aux(5, gen)
    _, _, J, c = m(x, xd, aux)
    J_ad = TaskMap.jacobian(m, x, aux)
    torch.testing.assert_close(J, J_ad, atol=1e-12, rtol=1e-10)
    torch.testing.assert_close(c, TaskMap.curvature(m, x, xd, aux, J_ad), atol=1e-10, rtol=1e-10)


def test_dimension_errors_are_clear():
    with pytest.raises(ValueError, match="offset.origin has dimension 3"):
        build_map({"type": "offset", "origin": [0, 0, 0]}, 2, {})
    with pytest.raises(ValueError, match="aux name 'goal' is not declared"):
        build_map({"type": "offset", "origin": "goal"}, 2, {})
    with pytest.raises(ValueError, match=r"select.indices \[5\] out of range"):
        build_map({"type": "select", "indices": [5]}, 2, {})
    with pytest.raises(ValueError, match="joint_limit.limit has 2 values for 3 joints"):
        build_map({"type": "joint_limit", "side": "upper", "limit": [1, 2]}, 3, {})


def test_missing_aux_at_call_time_names_it():
    m = build_map({"type": "offset", "origin": "c"}, 2, AUX)
    with pytest.raises(KeyError, match="aux state 'c' is required"):
        m(torch.zeros(1, 2), torch.zeros(1, 2), None)
