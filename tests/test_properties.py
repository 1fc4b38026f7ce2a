"""Property-based checks (hypothesis, bounded examples): random trees, random positive weights, random states."""

import numpy as np
import rmpflow_reference as ref
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from trees import random_tree_spec, randomise_weights

import rmpfusion

SETTINGS = settings(max_examples=12, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])


def _states(seed, dim, B):
    g = torch.Generator().manual_seed(seed)
    q = 4 * torch.rand(B, dim, generator=g) - 2
    qd = 2 * torch.randn(B, dim, generator=g)
    aux = {k: 3 * torch.rand(B, dim, generator=g) - 1.5 for k in ("goal", "c1", "c2", "c3")}
    return q, qd, aux


@SETTINGS
@given(tree_seed=st.integers(0, 10_000), state_seed=st.integers(0, 10_000), dim=st.integers(1, 4), B=st.integers(1, 6))
def test_random_trees_are_finite_satisfy_theorem2_and_batch_consistent(tree_seed, state_seed, dim, B):
    tree = rmpfusion.build_tree(random_tree_spec(tree_seed, dim))
    randomise_weights(tree, tree_seed)
    q, qd, aux = _states(state_seed, dim, B)
    with torch.no_grad():
        out = tree(q, qd, aux)
        for name in ("qdd", "f", "M", "G", "B", "Phi", "V", "L"):
            assert torch.isfinite(getattr(out, name)).all(), name
        # dV/dt along the closed loop by forward-mode AD through the whole tree: exact even where
        # barriers make V and q̈ huge and a finite difference in time would cancel catastrophically
        _, dVdt = torch.func.jvp(lambda a, b: tree(a, b, aux).V, (q, qd), (qd, out.qdd))
        diss = torch.einsum("bi,bij,bj->b", qd, out.B, qd)
        assert ((dVdt + diss).abs() <= 1e-8 * (1 + diss.abs() + out.V.abs())).all()
        assert (diss >= -1e-10).all()
        b = B - 1
        one = tree(q[b:], qd[b:], {k: v[b:] for k, v in aux.items()})
        torch.testing.assert_close(one.qdd, out.qdd[b:], rtol=1e-10, atol=1e-10)


@SETTINGS
@given(
    cx=st.floats(-2, 2),
    cy=st.floats(-2, 2),
    R=st.floats(0.2, 1.5),
    gx=st.floats(-4, 4),
    gy=st.floats(-4, 4),
    qx=st.floats(-4, 4),
    qy=st.floats(-4, 4),
    vx=st.floats(-2, 2),
    vy=st.floats(-2, 2),
    damper=st.booleans(),
)
def test_unit_weights_equal_rmpflow_pullback(cx, cy, R, gx, gy, qx, qy, vx, vy, damper):
    q, qd = np.array([qx, qy]), np.array([vx, vy])
    if np.linalg.norm(q - [cx, cy]) < 1e-3 or np.linalg.norm(q - [gx, gy]) < 1e-3:
        return  # the maps' own singular points
    nodes = {
        "o": {
            "parent": "q",
            "map": {"type": "sphere_distance", "center": [cx, cy], "radius": R, "normalized": True},
            "rmp": {"type": "rmpflow_collision_avoidance"},
        },
        "g": {"parent": "q", "map": {"type": "offset", "origin": [gx, gy]}, "rmp": {"type": "rmpflow_goal_attractor"}},
    }
    children = [
        (ref.sphere_map(np.array([cx, cy]), R), ref.collision_avoidance),
        (ref.offset_map(np.array([gx, gy])), ref.goal_attractor),
    ]
    if damper:
        nodes["d"] = {"parent": "q", "map": {"type": "identity"}, "rmp": {"type": "rmpflow_damper"}}
        children.append((((lambda y: y), (lambda y: np.eye(2)), (lambda y, yd: np.zeros((2, 2)))), ref.damper))
    out = rmpfusion.build_tree({"root": {"name": "q", "dim": 2}, "nodes": nodes})(
        torch.from_numpy(q)[None], torch.from_numpy(qd)[None]
    )
    _, f, M = ref.rmpflow_root(q, qd, children)
    np.testing.assert_allclose(out.f[0].numpy(), f, rtol=1e-10, atol=1e-9 * (1 + np.abs(f).max()))
    np.testing.assert_allclose(out.M[0].numpy(), M, rtol=1e-10, atol=1e-9 * (1 + np.abs(M).max()))
