"""The optimised paths compute the same numbers as the plain ones (float64, to 1e-10): the torch.compile'd
tree, the one kinematics pass for every control point, the pullback* shortcuts (tested in test_tree), the fused GDS
terms (test_leaves) and the forward-mode MLP tangent (test_weights); level-batched evaluation against the
node-by-node computation is test_grouped_evaluation. No test here looks at wall time."""

import copy
import warnings

import pytest
import torch
from trees import TWO_LEVEL, two_level_inputs

import rmpfusion

FIELDS = ("qdd", "f", "M", "G", "B", "Phi", "V", "L")


def _assert_same(a, b, tol=1e-10):
    for k in FIELDS:
        torch.testing.assert_close(getattr(a, k), getattr(b, k), rtol=tol, atol=tol, msg=lambda m, k=k: f"{k}: {m}")


@pytest.mark.slow
def test_compiled_tree_equals_eager_values_and_parameter_gradients(gen):
    """One compile of a depth-2 tree with MLP, rbf and constant weights, a barrier, an attractor and a damper:
    every root quantity and every parameter gradient (through the h_i terms) as in eager mode."""
    eager = rmpfusion.build_tree(TWO_LEVEL)
    fast = copy.deepcopy(eager).compile(dynamic=False)
    q, qd, aux = two_level_inputs(16, gen)
    out_e, out_c = eager(q, qd, aux), fast(q, qd, aux)
    _assert_same(out_c, out_e)
    for tree, out in ((eager, out_e), (fast, out_c)):
        (out.qdd.square().sum() + out.V.sum()).backward()
    grads = {n: p.grad for n, p in eager.named_parameters()}
    assert grads, "the tree has learnable weights"
    for n, p in fast.named_parameters():
        torch.testing.assert_close(p.grad, grads[n], rtol=1e-10, atol=1e-10, msg=lambda m, n=n: f"{n}: {m}")


def test_compiled_tree_falls_back_to_the_pseudo_inverse_where_the_solve_fails():
    """A root inertia that is singular for some samples: the compiled fast path reports it and the eager
    resolve gives the Moore–Penrose answer, exactly as without compilation."""
    spec = {
        "root": {"name": "q", "dim": 2},
        "nodes": {
            "x": {
                "parent": "q",
                "map": {"type": "select", "indices": [0]},
                "rmp": {"type": "damper", "w": 1.0, "eta": 1.0},
            }
        },
    }
    eager = rmpfusion.build_tree(spec)
    fast = copy.deepcopy(eager).compile(dynamic=False)
    q = torch.zeros(3, 2, dtype=torch.float64)
    qd = torch.tensor([[1.0, 2.0], [-1.0, 0.5], [0.0, 3.0]], dtype=torch.float64)
    out_e, out_c = eager(q, qd), fast(q, qd)
    _assert_same(out_c, out_e)
    torch.testing.assert_close(out_c.qdd, torch.stack([-qd[:, 0], torch.zeros(3, dtype=torch.float64)], -1))


def test_traced_solve_equals_lapacks_and_refuses_the_same_matrices(gen):
    """The solve a compiler traces (the elimination written out in tensor operations) gives LAPACK's answer and
    trusts exactly the samples LAPACK's LU is trusted on: random roots of 1 to 12 coordinates, rows that need a
    pivot swap, singular and non-finite ones."""
    from rmpfusion.core.algebra import TRACED_ELIMINATION_MAX_DIM, lu_solve

    traced = torch.compile(lu_solve, backend="eager", fullgraph=True)  # traced by dynamo, run without inductor
    for n in (1, 2, 3, 7, TRACED_ELIMINATION_MAX_DIM):
        A = torch.randn(64, n, n, generator=gen)
        M = A @ A.mT + 0.1 * torch.eye(n) + 0.5 * (A - A.mT)  # positive definite symmetric part, not symmetric
        f = torch.randn(64, n, generator=gen)
        (a, good), (a_ref, good_ref) = traced(M, f), lu_solve(M, f)
        assert good.all() and good_ref.all()
        torch.testing.assert_close(a, a_ref, rtol=1e-10, atol=1e-12)
    M = torch.tensor(
        [
            [[0.0, 1.0], [1.0, 0.0]],  # invertible, a zero in the first pivot's place: rows swapped
            [[1.0, 2.0], [2.0, 4.0]],  # singular
            [[0.0, 0.0], [0.0, 0.0]],
            [[1.0, float("nan")], [0.0, 1.0]],
            [[1e-300, 0.0], [0.0, 1.0]],  # invertible, a pivot negligible beside the other
        ]
    )
    f = torch.ones(5, 2)
    (a, good), (a_ref, good_ref) = traced(M, f), lu_solve(M, f)
    assert good.tolist() == good_ref.tolist() == [True, False, False, False, False]
    torch.testing.assert_close(a[0], a_ref[0])


def test_one_kinematics_pass_serves_every_control_point():
    """The Franka tree's 15 kinematic points form one group reading one pass of the chain; the group's position,
    Jacobian and J̇q̇ of every point equal that point's map evaluated on its own."""
    from manipulators import franka_tree_spec

    tree = rmpfusion.build_tree(franka_tree_spec(n_obstacles=2))
    (group,) = [g for g in tree.plan.groups if g.nodes[0] == "ee"]
    assert len(group.nodes) == 15 and all(tree.maps[n].chain is not None for n in group.nodes)
    g = torch.Generator().manual_seed(1)
    lo, hi = tree.maps["ee"].chain.joint_limits()
    q = lo + (hi - lo) * torch.rand(6, 7, generator=g, dtype=torch.float64)
    qd = torch.randn(6, 7, generator=g, dtype=torch.float64)
    together = group.map(q.unsqueeze(0), qd.unsqueeze(0), None)
    for row, n in enumerate(group.nodes):
        for a, b in zip(together, tree.maps[n](q, qd)):
            torch.testing.assert_close(a[row], b, rtol=1e-13, atol=1e-13)


@pytest.mark.parametrize("name", ["identity", "offset"])
def test_maps_flagged_identity_have_identity_jacobians(name, gen):
    from rmpfusion.registry import TASK_MAPS

    entry = TASK_MAPS.get(name)
    params = {"origin": [0.5, -1.0, 2.0]} if name == "offset" else {}
    m = entry.obj(entry.validate(params), 3, {})
    assert m.identity_jacobian
    x, xd = torch.randn(4, 3, generator=gen), torch.randn(4, 3, generator=gen)
    _, yd, J, c = m(x, xd)
    torch.testing.assert_close(J, torch.eye(3).expand(4, 3, 3))
    torch.testing.assert_close(yd, xd)
    torch.testing.assert_close(c, torch.zeros_like(xd))


@pytest.mark.slow
def test_copies_of_a_compiled_tree_evaluate_their_own_weights(gen):
    """Snapshots are evaluated on copies: a copy of a compiled tree must use the copy's weights, not the
    original's (its compiled code is built for the copy on first use)."""
    tree = rmpfusion.build_tree(TWO_LEVEL).compile(dynamic=False)
    q, qd, aux = two_level_inputs(8, gen)
    with torch.no_grad():
        before = tree(q, qd, aux).qdd
        other = copy.deepcopy(tree)
        for p in other.parameters():
            p.add_(0.1)
        moved = other(q, qd, aux).qdd
        assert not torch.allclose(moved, before)
        torch.testing.assert_close(tree(q, qd, aux).qdd, before, rtol=0, atol=0)
        torch.testing.assert_close(moved, copy.deepcopy(other).uncompile()(q, qd, aux).qdd, rtol=1e-10, atol=1e-10)


def test_fixed_structure_compile_still_sees_new_weights(gen):
    """Skipping the module guards must not freeze the parameters: weights loaded after the first call (as
    snapshots are during evaluation) give the eager tree's answer with those weights."""
    eager = rmpfusion.build_tree(TWO_LEVEL)
    fast = copy.deepcopy(eager).compile(dynamic=False, fixed_structure=True)
    q, qd, aux = two_level_inputs(8, gen)
    with torch.no_grad():
        _assert_same(fast(q, qd, aux), eager(q, qd, aux))
        for p in eager.parameters():
            p.add_(0.1 * torch.randn(p.shape, generator=gen, dtype=p.dtype))
        fast.load_state_dict(eager.state_dict())
        _assert_same(fast(q, qd, aux), eager(q, qd, aux))


def test_a_tree_whose_compile_fails_runs_eagerly_and_says_why(gen, monkeypatch):
    """A backend failure (here a missing C++ compiler, as dynamo wraps it: its first line names only the backend)
    turns the tree eager with the same numbers, and the warning names the cause, once."""
    from rmpfusion.core.tree import CompileFallbackWarning

    def compile_that_fails(fn, **kwargs):
        def call(*args):
            raise torch._dynamo.exc.BackendCompilerFailed(lambda *a: None, RuntimeError("no C++ compiler found"), None)

        return call

    eager = rmpfusion.build_tree(TWO_LEVEL)
    tree = copy.deepcopy(eager).compile(dynamic=False)
    monkeypatch.setattr(torch, "compile", compile_that_fails)
    q, qd, aux = two_level_inputs(4, gen)
    with pytest.warns(CompileFallbackWarning, match=r"RuntimeError: no C\+\+ compiler found\); it now runs eagerly"):
        out = tree(q, qd, aux)
    _assert_same(out, eager(q, qd, aux))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        tree(q, qd, aux)  # said once: the tree is eager now
