"""The first-order field of a tree (its overdamped limit −B_r⁻¹∇Φ_r) against independent computations, and the
field-fitting method (train.method=field) recovering a field it was shown."""

from __future__ import annotations

import dataclasses

import pytest
import torch

from rmpfusion.assembly.tree import build_tree
from rmpfusion.envs.demonstrations import Dataset
from rmpfusion.learn.method import MethodContext
from rmpfusion.learn.methods.field import FieldFit, FieldParams, field_loss
from rmpfusion.registry import LEARNERS


def flow_tree(seed: int, weight: dict | None = None, layers: int = 4):
    """A tree as conf/tree/lasa_flow.yaml's (smaller), optionally with a weight on the attractor and a damper beside
    it, so the weights' gradients and a second damping leaf enter the field."""
    torch.manual_seed(seed)
    nodes = {
        "rel": {"parent": "x", "map": {"type": "offset", "origin": "goal"}},
        "latent": {
            "parent": "rel",
            "map": {"type": "diffeomorphism", "layers": layers, "hidden": [8], "origin": [0.0, 0.0], "init_std": 0.5},
        },
        "attractor": {
            "parent": "latent",
            "map": {"type": "identity"},
            "rmp": {"type": "goal_attractor", "gain": 3.0, "alpha": 2.0, "eta": 4.0, "w_u": 2.0, "w_l": 1.0},
        },
    }
    if weight is not None:
        nodes["attractor"]["weight"] = weight
        nodes["damper"] = {
            "parent": "rel",
            "map": {"type": "identity"},
            "rmp": {"type": "damper", "w": 0.5, "eta": 2.0},
        }
    return build_tree({"root": {"name": "x", "dim": 2}, "nodes": nodes}, aux_dims={"goal": 2}).double()


def states(n: int, seed: int = 1):
    gen = torch.Generator().manual_seed(seed)
    q = torch.randn(n, 2, generator=gen, dtype=torch.float64)
    return q, {"goal": 0.3 * torch.randn(n, 2, generator=gen, dtype=torch.float64)}


@pytest.mark.parametrize("weight", [None, {"type": "mlp", "hidden": [8], "aux": []}])
def test_the_overdamped_field_is_minus_the_damping_inverse_times_the_potential_gradient(weight):
    """f_r(q, 0) = −∇_q Φ_r with Φ_r = Σ W_i Φ_i the root's potential, differentiated here by autograd (a computation
    the tree's pullback* does not share), so v = B_r⁻¹ f_r(q, 0) = −B_r⁻¹ ∇Φ_r."""
    tree = flow_tree(0, weight)
    q, aux = states(16)
    q.requires_grad_(True)
    out = tree(q, torch.zeros_like(q), aux)
    (grad_phi,) = torch.autograd.grad(out.Phi.sum(), q)
    expected = -torch.linalg.solve(out.B.detach(), grad_phi.unsqueeze(-1)).squeeze(-1)
    torch.testing.assert_close(tree.overdamped_field(q.detach(), aux), expected, rtol=1e-9, atol=1e-12)


def test_through_a_diffeomorphism_the_field_is_the_natural_gradient_descent_of_the_latent_attractor():
    """One attractor under a learned map, constant weights: v = −gain/(η·w(z))·J⁻¹·tanh(α|z|)·z/|z| with the
    metric's scale w(z) = (w_u − w_l)·exp(−|z|²/2σ²) + w_l (B = η·w·I), the field Euclideanizing flows learn; z and J
    from the map's own forward."""
    tree = flow_tree(2)
    q, aux = states(32, seed=3)
    latent = tree.maps["latent"]
    z, _, J, _ = latent(q - aux["goal"], torch.zeros_like(q), aux)
    r = z.norm(dim=-1, keepdim=True)
    w = (2.0 - 1.0) * torch.exp(-(r**2) / 2.0) + 1.0
    latent_velocity = -3.0 / (4.0 * w) * torch.tanh(2.0 * r) * z / r
    expected = torch.linalg.solve(J, latent_velocity.unsqueeze(-1)).squeeze(-1)
    torch.testing.assert_close(tree.overdamped_field(q, aux), expected, rtol=1e-9, atol=1e-12)


def _dataset(q: torch.Tensor, qd: torch.Tensor, aux: dict) -> Dataset:
    n = q.shape[0]
    ids = torch.arange(n)
    return Dataset(
        q=q, qd=qd, aux=aux, qdd=torch.zeros_like(q), env_id=ids, traj_id=ids, t=torch.zeros(n, dtype=q.dtype)
    )


def test_field_fitting_recovers_a_teachers_field_on_held_out_points():
    """Velocities made by one random tree's field are fitted by another tree of the same structure, from another
    random start and a third of the teacher's gain: the relative error on points it never saw falls twenty-fold."""
    teacher = flow_tree(5, layers=2)
    learner = _student(gain=1.0)  # the teacher's gain is 3
    q, aux = states(256, seed=7)
    with torch.no_grad():
        qd = teacher.overdamped_field(q, aux)
    train, val = (
        _dataset(q[:192], qd[:192], {"goal": aux["goal"][:192]}),
        _dataset(q[192:], qd[192:], {"goal": aux["goal"][192:]}),
    )
    params = FieldParams(optimizer="adam", lr=1e-2, lr_schedule="cosine", iterations=400, snapshots=[0, 400])
    speed = float(train.qd.norm(dim=-1).mean())
    before = float(field_loss(learner, val, None, speed, "mse").detach())
    FieldFit(params).train(learner, MethodContext(data={"train": train, "val": val}, seed=0))
    after = float(field_loss(learner, val, None, speed, "mse").detach())
    assert before > 0.1 and after < 0.05 * before


def flow_spec(layers: int) -> dict:
    return {
        "root": {"name": "x", "dim": 2},
        "nodes": {
            "rel": {"parent": "x", "map": {"type": "offset", "origin": "goal"}},
            "latent": {
                "parent": "rel",
                "map": {"type": "diffeomorphism", "layers": layers, "hidden": [8], "origin": [0.0, 0.0]},
            },
            "attractor": {
                "parent": "latent",
                "map": {"type": "identity"},
                "rmp": {"type": "goal_attractor", "gain": 3.0, "alpha": 2.0, "eta": 4.0, "w_u": 2.0, "w_l": 1.0},
            },
        },
    }


def test_a_learner_without_a_field_is_refused_by_name():
    entry = LEARNERS.get("unstructured")
    learner = entry.obj.from_params(entry.validate({}), None, {"goal": 2}, 2)
    q, aux = states(8)
    train = _dataset(q, q.clone(), aux)
    params = FieldParams(iterations=1, snapshots=[0, 1])
    with pytest.raises(ValueError, match="train.method=field fits a first-order field.*has none"):
        FieldFit(params).train(learner, MethodContext(data={"train": train}, seed=0))


def _speed_over(learner, lo: torch.Tensor, hi: torch.Tensor, goal: torch.Tensor, n: int = 41) -> float:
    """The field's largest speed over an n × n grid of the box [lo, hi]."""
    axes = [torch.linspace(float(a), float(b), n, dtype=torch.float64) for a, b in zip(lo, hi)]
    q = torch.stack(torch.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 2)
    with torch.no_grad():
        return float(learner.first_order_field(q, {"goal": goal.expand(len(q), -1)}).norm(dim=-1).max())


def test_the_speed_bound_is_the_penalty_on_the_fields_excess_speed_at_points_in_the_enlarged_box():
    """SpeedBound's penalty against its definition, computed here from the points it draws: the mean of
    relu(|v|/limit − 1)² with limit = speed_limit × the fastest recorded speed, every point inside the training
    positions' box grown by speed_box of its spread on each side... and zero for a field slower than the limit."""
    from rmpfusion.learn.methods.field import SpeedBound, fitted_rows

    learner = _student(gain=5.0)
    q, aux = states(64, seed=3)
    qd = 0.2 * torch.randn(64, 2, generator=torch.Generator().manual_seed(4), dtype=torch.float64)
    ds = _dataset(q, qd, aux)
    params = FieldParams(speed_limit=1.5, speed_box=0.5, speed_points=256, speed_weight=2.0)
    bound = SpeedBound(ds, fitted_rows(ds, 0.0), params, torch.Generator().manual_seed(0))
    points, point_aux = SpeedBound(ds, fitted_rows(ds, 0.0), params, torch.Generator().manual_seed(0)).draw()
    spread = q.max(0).values - q.min(0).values
    assert (points >= q.min(0).values - 0.25 * spread).all() and (points <= q.max(0).values + 0.25 * spread).all()
    assert all(any(torch.equal(g, h) for h in aux["goal"]) for g in point_aux["goal"][:8])
    limit = 1.5 * float(qd.norm(dim=-1).max())
    speed = learner.first_order_field(points, point_aux).norm(dim=-1)
    expected = 2.0 * (torch.relu(speed / limit - 1) ** 2).mean()
    assert float(expected.detach()) > 0, "the test's field must exceed the limit somewhere"
    torch.testing.assert_close(bound.penalty(learner), expected)
    slow = SpeedBound(_dataset(q, 1e3 * qd, aux), fitted_rows(ds, 0.0), params, torch.Generator().manual_seed(0))
    assert float(slow.penalty(learner)) == 0.0


def _student(gain: float, seed: int = 6, layers: int = 2, init_std: float | None = None):
    """A learner on flow_spec's tree, its attractor's gain learned from ``gain``, its map drawn with ``init_std``."""
    entry = LEARNERS.get("rmp")
    torch.manual_seed(seed)
    spec = flow_spec(layers=layers)
    if init_std is not None:
        spec["nodes"]["latent"]["map"]["init_std"] = init_std
    leaves = {"attractor": {"gain": {"learn": True, "init": gain}}}
    return entry.obj.from_params(entry.validate({"edges": [], "leaves": leaves}), spec, {"goal": 2}, 2).double()


def test_a_field_fitted_with_a_speed_limit_is_brought_down_to_it_away_from_the_recordings():
    """Velocities recorded in a small patch, the student's map drawn steep (init_std 2: its field ten times the
    fastest recorded speed over the box around the patch before training): fitted with speed_limit=1.5 its field
    over that box ends within 1.5 times the limit (it is 10 times before), and its error on the patch's held-out
    points stays within 1.5 times that of the same fit without the bound (0.39 against 0.29 here)."""
    teacher = flow_tree(5, layers=2)
    gen = torch.Generator().manual_seed(7)
    q = torch.tensor([1.0, 1.0], dtype=torch.float64) + 0.2 * torch.rand(256, 2, generator=gen, dtype=torch.float64)
    goal = torch.zeros(1, 2, dtype=torch.float64)
    aux = {"goal": goal.expand(256, -1).clone()}
    with torch.no_grad():
        qd = teacher.overdamped_field(q, aux)
    train = _dataset(q[:192], qd[:192], {"goal": aux["goal"][:192]})
    val = _dataset(q[192:], qd[192:], {"goal": aux["goal"][192:]})
    fastest, speed = float(train.qd.norm(dim=-1).max()), float(train.qd.norm(dim=-1).mean())
    lo, hi = (
        q.min(0).values - 0.2,
        q.max(0).values + 0.2,
    )  # the box speed_box=2 draws from: sides three times the patch's
    fits = {}
    for limit in (None, 1.5):
        learner = _student(gain=3.0, layers=4, init_std=2.0)
        before = _speed_over(learner, lo, hi, goal) / fastest
        params = FieldParams(
            optimizer="adam",
            lr=1e-2,
            lr_schedule="cosine",
            iterations=300,
            snapshots=[0, 300],
            speed_limit=limit,
            speed_box=2.0,
            speed_weight=10.0,
        )
        FieldFit(params).train(learner, MethodContext(data={"train": train}, seed=0))
        fits[limit] = float(field_loss(learner, val, None, speed, "mse").detach())
    after = _speed_over(learner, lo, hi, goal) / fastest
    assert before > 5.0, f"the test needs a field fast away from the patch: {before:.2f}× the fastest"
    assert after <= 1.5 * 1.5, f"{after:.2f}× the fastest recorded speed, over the limit of 1.5"
    assert fits[1.5] <= 1.5 * fits[None], f"the bound costs the fit on the patch too much: {fits}"


def test_where_the_damping_is_singular_the_field_is_nan_and_the_speed_bound_leaves_the_row_out():
    """A root damping that vanishes at some rows (a map that flattens space there, to working precision) has no
    field: those rows are NaN, the others are −B_r⁻¹∇Φ_r as before, and the speed penalty and its gradient stay
    finite."""
    from rmpfusion.learn.methods.field import SpeedBound, fitted_rows

    learner = _student(gain=5.0)
    q, aux = states(8, seed=3)
    reference = learner.first_order_field(q, aux)
    tree = learner.tree
    real_forward = type(tree).forward

    def flattened(self, x, xd, a=None):
        out = real_forward(self, x, xd, a)
        B = out.B.clone()
        B[::2] = 0.0  # every other row: no damping at all
        return dataclasses.replace(out, B=B)

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(type(tree), "forward", flattened)
        v = learner.first_order_field(q, aux)
        assert v[::2].isnan().all() and v[1::2].isfinite().all()
        torch.testing.assert_close(v[1::2], reference[1::2])
        ds = _dataset(q, 1e-3 * torch.ones_like(q), aux)
        params = FieldParams(speed_limit=1.0, speed_points=64)
        penalty = SpeedBound(ds, fitted_rows(ds, 0.0), params, torch.Generator().manual_seed(0)).penalty(learner)
        penalty.backward()
    assert penalty.isfinite() and float(penalty) > 0
    assert all(p.grad is None or p.grad.isfinite().all() for p in learner.parameters())
