"""The first-order field of a tree (its overdamped limit −B_r⁻¹∇Φ_r) against independent computations, and the
field-fitting method (train.method=field) recovering a field it was shown."""

from __future__ import annotations

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
    teacher, student = flow_tree(5, layers=2), LEARNERS.get("rmp")
    torch.manual_seed(6)
    leaves = {"attractor": {"gain": {"learn": True, "init": 1.0}}}  # the teacher's is 3
    learner = student.obj.from_params(
        student.validate({"edges": [], "leaves": leaves}), flow_spec(layers=2), {"goal": 2}, 2
    ).double()
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
