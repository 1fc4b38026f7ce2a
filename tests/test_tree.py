"""RMP-algebra* and RMPTree: eq. 6 against an independent per-sample computation, RMPflow equivalence,
the test vector, batch consistency, trainability through h_i, and build-time checks."""

import numpy as np
import pytest
import rmpflow_reference as ref
import torch
from trees import TEST_VECTOR_SPEC, TWO_LEVEL, two_level_inputs

import rmpfusion
from rmpfusion.assembly import ConfigError
from rmpfusion.core.algebra import Edge, NodeRMP, pullback_star, resolve


def test_issue_test_vector():
    tree = rmpfusion.build_tree(TEST_VECTOR_SPEC)
    out = tree(torch.tensor([[2.5, -3.2]]), torch.tensor([[-1.0, 1.0]]))
    expect_qdd = torch.tensor([[1.304717264859, -1.211390133974]])
    expect_M = torch.tensor([[[1.017880779188, -0.022887397360], [-0.022887397360, 1.029295868621]]])
    torch.testing.assert_close(out.qdd, expect_qdd, atol=1e-9, rtol=0)
    torch.testing.assert_close(out.M, expect_M, atol=1e-9, rtol=0)


def test_unit_weights_equal_rmpflow_reference(gen):
    tree = rmpfusion.build_tree(TEST_VECTOR_SPEC)
    children = [
        (ref.sphere_map(np.zeros(2), 1.0), ref.collision_avoidance),
        (ref.offset_map(np.array([-3.0, 3.0])), ref.goal_attractor),
    ]
    q = 4 * torch.rand(20, 2, generator=gen) - 2 + torch.tensor([2.0, -2.0])
    qd = torch.randn(20, 2, generator=gen)
    out = tree(q, qd)
    for b in range(20):
        a, f, M = ref.rmpflow_root(q[b].numpy(), qd[b].numpy(), children)
        np.testing.assert_allclose(out.f[b].numpy(), f, rtol=1e-11, atol=1e-12)
        np.testing.assert_allclose(out.M[b].numpy(), M, rtol=1e-11, atol=1e-12)
        np.testing.assert_allclose(out.qdd[b].numpy(), a, rtol=1e-9, atol=1e-10)
    # explicit constant weights of 1 are the same tree
    spec = {
        **TEST_VECTOR_SPEC,
        "nodes": {k: {**v, "weight": {"type": "constant", "value": 1.0}} for k, v in TEST_VECTOR_SPEC["nodes"].items()},
    }
    torch.testing.assert_close(rmpfusion.build_tree(spec)(q, qd).qdd, out.qdd, rtol=0, atol=0)


def _random_node(B, n, gen):
    A = torch.randn(B, n, n, generator=gen)
    S = A @ A.transpose(-1, -2) + torch.eye(n)
    return NodeRMP(
        f=torch.randn(B, n, generator=gen),
        M=S + 0.1 * torch.randn(B, n, n, generator=gen),
        G=S,
        B=S.clone(),
        Phi=torch.rand(B, generator=gen),
        L=torch.randn(B, generator=gen),
        V=torch.rand(B, generator=gen),
    )


def test_pullback_star_is_eq6_per_sample(gen):
    """Eq. 6 written out per sample in numpy, children of different dimensions, some unweighted, and the
    shortcuts pullback* takes (1-D children, edges flagged as identity Jacobians) against the general formula."""
    B, m = 4, 3
    xd = torch.randn(B, m, generator=gen)
    kids = []
    for n, weighted, identity in [
        (1, True, False),
        (2, False, False),
        (3, True, False),
        (1, False, False),
        (3, True, True),
        (3, False, True),
    ]:
        J = torch.eye(m).expand(B, m, m) if identity else torch.randn(B, n, m, generator=gen)
        w = torch.rand(B, generator=gen) + 0.1 if weighted else None
        gw = torch.randn(B, m, generator=gen) if weighted else None
        yd = (J @ xd[..., None])[..., 0]
        kids.append(
            (
                # J ≡ I on an identity edge, so its curvature c = J̇ẋ is 0 (pullback* relies on it)
                Edge(
                    J=J,
                    c=torch.zeros(B, n) if identity else torch.randn(B, n, generator=gen),
                    yd=yd,
                    w=w,
                    grad_w=gw,
                    identity=identity,
                ),
                _random_node(B, n, gen),
            )
        )
    out = pullback_star(xd, kids)
    for b in range(B):
        f = np.zeros(m)
        M = np.zeros((m, m))
        G = np.zeros((m, m))
        Bm = np.zeros((m, m))
        L = Phi = V = 0.0
        for e, ch in kids:
            J, c, x_d = e.J[b].numpy(), e.c[b].numpy(), xd[b].numpy()
            w = 1.0 if e.w is None else float(e.w[b])
            gw = np.zeros(m) if e.grad_w is None else e.grad_w[b].numpy()
            Mi, Gi, fi = ch.M[b].numpy(), ch.G[b].numpy(), ch.f[b].numpy()
            h = float(ch.L[b]) * gw - (x_d @ gw) * J.T @ Gi @ J @ x_d
            f += w * J.T @ (fi - Mi @ c) + h
            M += w * J.T @ Mi @ J
            G += w * J.T @ Gi @ J
            Bm += w * J.T @ ch.B[b].numpy() @ J
            L += w * float(ch.L[b])
            Phi += w * float(ch.Phi[b])
            V += w * float(ch.V[b])
        for got, want in [(out.f, f), (out.M, M), (out.G, G), (out.B, Bm), (out.L, L), (out.Phi, Phi), (out.V, V)]:
            np.testing.assert_allclose(got[b].numpy(), want, rtol=1e-12, atol=1e-12)


def test_resolve_solve_equals_pinv_and_handles_singular(gen):
    A = torch.randn(6, 3, 3, generator=gen)
    M = A @ A.transpose(-1, -2) + 0.1 * torch.eye(3)
    M[0] = torch.tensor([[1.0, 0, 0], [0, 0, 0], [0, 0, 0]])  # singular: falls back to the pseudo-inverse
    f = torch.randn(6, 3, generator=gen)
    torch.testing.assert_close(resolve(f, M, "solve"), resolve(f, M, "pinv"), rtol=1e-9, atol=1e-10)


def test_batch_equals_single_calls(gen):
    tree = rmpfusion.build_tree(TWO_LEVEL)
    q, qd, aux = two_level_inputs(9, gen)
    out = tree(q, qd, aux)
    for b in range(9):
        one = tree(q[b : b + 1], qd[b : b + 1], {k: v[b : b + 1] for k, v in aux.items()})
        for name in ("qdd", "f", "M", "G", "B", "Phi", "V", "L"):
            torch.testing.assert_close(getattr(out, name)[b : b + 1], getattr(one, name), rtol=1e-12, atol=1e-12)


def test_gradients_reach_every_weight_parameter_and_match_finite_differences(gen):
    tree = rmpfusion.build_tree(TWO_LEVEL)
    q, qd, aux = two_level_inputs(16, gen)
    target = torch.randn(16, 2, generator=gen)
    loss_fn = lambda: ((tree(q, qd, aux).qdd - target) ** 2).mean()
    params = dict(tree.named_parameters())
    grads = torch.autograd.grad(loss_fn(), list(params.values()))
    for (name, p), g in zip(params.items(), grads):
        assert g is not None and float(g.abs().sum()) > 0, f"no gradient reaches {name}"
    # one scalar per parameter tensor against central differences of the loss
    for (name, p), g in zip(params.items(), grads):
        idx = (0,) * p.dim()
        with torch.no_grad():
            old = p[idx].item()
            p[idx] = old + 1e-6
            lp = loss_fn().item()
            p[idx] = old - 1e-6
            lm = loss_fn().item()
            p[idx] = old
        assert abs((lp - lm) / 2e-6 - g[idx].item()) <= 1e-6 * max(1.0, abs(g[idx].item())), name


def test_h_terms_carry_gradient():
    """With the weight a function of the configuration only through h_i, the loss still depends on it."""
    spec = {
        "root": {"name": "q", "dim": 1},
        "nodes": {
            "a": {
                "parent": "q",
                "map": {"type": "identity"},
                "weight": {"type": "mlp", "hidden": [4]},
                "rmp": {"type": "goal_attractor"},
            },
        },
    }
    tree = rmpfusion.build_tree(spec)
    q, qd = torch.tensor([[0.7]]), torch.tensor([[0.3]])
    w, gw = tree.weights["a"](q, None)
    out = tree(q, qd)
    leaf = tree.rmps["a"](q, qd)
    # single child: qdd = (w f + h) / (w M) exactly
    h = leaf.L[:, None] * gw - (qd * gw).sum(-1, keepdim=True) * leaf.G[:, 0] * qd
    torch.testing.assert_close(out.qdd, (w[:, None] * leaf.f + h) / (w[:, None] * leaf.M[:, 0]))


def test_shared_weight_is_one_module_with_per_edge_bindings(gen):
    spec = {
        "root": {"name": "q", "dim": 2},
        "aux": {"ob1": 2, "ob2": 2, "ob": 2},
        "shared_weights": {"obstacle": {"type": "mlp", "hidden": [8], "aux": ["ob"]}},
        "nodes": {
            "d1": {
                "parent": "q",
                "map": {"type": "sphere_distance", "center": "ob1", "radius": 0.5},
                "weight": {"shared": "obstacle", "bind": {"ob": "ob1"}},
                "rmp": {"type": "collision_avoidance"},
            },
            "d2": {
                "parent": "q",
                "map": {"type": "sphere_distance", "center": "ob2", "radius": 0.5},
                "weight": {"shared": "obstacle", "bind": {"ob": "ob2"}},
                "rmp": {"type": "collision_avoidance"},
            },
            "id": {"parent": "q", "map": {"type": "identity"}, "rmp": {"type": "identity_metric"}},
        },
    }
    tree = rmpfusion.build_tree(spec)
    assert tree.weights["d1"].fn is tree.weights["d2"].fn
    assert sum(p.numel() for p in tree.parameters()) == sum(p.numel() for p in tree.weights["d1"].parameters())
    x = torch.randn(3, 2, generator=gen)
    a = {"ob1": torch.randn(3, 2, generator=gen), "ob2": torch.randn(3, 2, generator=gen)}
    w1, _ = tree.weights["d1"](x, a)
    w_direct, _ = tree.weights["d1"].fn(x, {"ob": a["ob1"]})
    torch.testing.assert_close(w1, w_direct)


def test_build_time_dimension_check_names_the_node():
    spec = {
        "root": {"name": "q", "dim": 2},
        "nodes": {
            "o": {"parent": "q", "map": {"type": "offset", "origin": [0, 0]}, "rmp": {"type": "collision_avoidance"}}
        },
    }
    with pytest.raises(
        ConfigError, match=r"tree.nodes.o.rmp: 'collision_avoidance' is 1-dimensional but the map gives dimension 2"
    ):
        rmpfusion.build_tree(spec)


def test_wrong_state_shape_is_rejected():
    tree = rmpfusion.build_tree(TEST_VECTOR_SPEC)
    with pytest.raises(ValueError, match=r"must both be \(B, 2\)"):
        tree(torch.zeros(3), torch.zeros(3))


def test_describe_draws_the_tree():
    text = rmpfusion.build_tree(TWO_LEVEL).describe()
    assert "└── o2 (dim 1)  map=sphere_distance  weight=rbf  rmp=collision_avoidance" in text
    assert "├── obstacles (dim 2)" in text


def test_non_finite_values_raise_an_error_naming_where():
    from rmpfusion.core.tree import NumericalError

    tree = rmpfusion.build_tree(TWO_LEVEL)
    q, qd, aux = two_level_inputs(3, torch.Generator().manual_seed(0))
    bad_q = q.clone()
    bad_q[1, 0] = float("nan")
    with pytest.raises(NumericalError, match=r"non-finite input q"):
        tree(bad_q, qd, aux)
    bad_aux = dict(aux)
    bad_aux["obstacle2_radius"] = torch.full_like(aux["obstacle2_radius"], float("inf"))
    with pytest.raises(NumericalError, match=r"non-finite input aux\['obstacle2_radius'\]"):
        tree(q, qd, bad_aux)
    with torch.no_grad():
        tree.weights["o1"].fn.layers[0].weight[0, 0] = float("nan")
    with pytest.raises(NumericalError, match=r"non-finite weight at node 'o1'"):
        tree(q, qd, aux)


def test_float32_agrees_with_float64(gen):
    """Training may run in float32: the same tree and weights give the same accelerations to float32 precision."""
    t64 = rmpfusion.build_tree(TWO_LEVEL)
    t32 = rmpfusion.build_tree(TWO_LEVEL, dtype=torch.float32)
    t32.load_state_dict({k: v.float() for k, v in t64.state_dict().items()})
    q, qd, aux = two_level_inputs(64, gen)
    out64 = t64(q, qd, aux).qdd
    out32 = t32(q.float(), qd.float(), {k: v.float() for k, v in aux.items()}).qdd
    scale = out64.abs().amax(-1, keepdim=True) + 1
    assert ((out32.double() - out64).abs() / scale).max() < 1e-4
