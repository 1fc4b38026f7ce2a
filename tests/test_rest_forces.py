"""Which leaves hold a tree at rest: each leaf's force at q̇ = 0 adds up to the root's, and removing a leaf from the
tree removes exactly its force from the root's."""

from __future__ import annotations

import copy

import pytest
import torch

from rmpfusion import build_tree
from rmpfusion.evaluate.rest_forces import rest_forces


def spec_with(leaves: list[str]) -> dict:
    """A planar tree whose attractor sits behind a learned map under a configuration-dependent weight (an MLP of x),
    beside a disc obstacle under an RBF weight, a posture-like second attractor and a damper."""
    nodes = {
        "latent": {
            "parent": "x",
            "map": {"type": "diffeomorphism", "origin": "goal", "layers": 2, "hidden": [8], "init_std": 0.3},
        },
        "attractor": {
            "parent": "latent",
            "map": {"type": "identity"},
            "weight": {"type": "mlp", "hidden": [8], "aux": ["goal"], "positivity": "exp"},
            "rmp": {"type": "goal_attractor", "gain": 2.0, "eta": 1.0},
        },
        "obstacle": {
            "parent": "x",
            "map": {"type": "sphere_distance", "center": [0.3, 0.1], "radius": 0.2},
            "weight": {"type": "rbf", "low": 0.5, "high": 2.0, "center": [0.3, 0.1]},
            "rmp": {"type": "collision_avoidance", "r_w": 2.0, "alpha": 0.1},
        },
        "home": {
            "parent": "x",
            "map": {"type": "offset", "origin": [0.5, -0.5]},
            "rmp": {"type": "goal_attractor", "gain": 1.0, "eta": 1.0},
        },
        "damper": {"parent": "x", "map": {"type": "identity"}, "rmp": {"type": "damper", "w": 1.0, "eta": 2.0}},
    }
    keep = {*leaves, *(["latent"] if "attractor" in leaves else [])}
    return {"root": {"name": "x", "dim": 2}, "aux": {"goal": 2}, "nodes": {n: v for n, v in nodes.items() if n in keep}}


def states(n: int = 12):
    gen = torch.Generator().manual_seed(3)
    q = torch.rand(n, 2, generator=gen, dtype=torch.float64) * 1.6 - 0.8
    q = q[(q - torch.tensor([0.3, 0.1], dtype=torch.float64)).norm(dim=-1) > 0.3]  # outside the disc
    return q, {"goal": torch.zeros(len(q), 2, dtype=torch.float64)}


def test_the_leaves_forces_at_rest_add_up_to_the_roots():
    torch.manual_seed(0)
    tree = build_tree(spec_with(["attractor", "obstacle", "home", "damper"])).double()
    q, aux = states()
    forces = rest_forces(tree, q, aux)
    assert set(forces.leaves) == {"attractor", "obstacle", "home"}  # the damper has no potential
    torch.testing.assert_close(forces.residual, torch.zeros_like(q), atol=1e-12, rtol=0)
    torch.testing.assert_close(forces.root, tree(q, torch.zeros_like(q), aux).f, atol=1e-12, rtol=1e-12)
    # the weight-gradient part: zero for the unweighted leaf, not for the two whose weights vary with x
    assert float(forces.weight_gradient["home"].abs().max()) == 0.0
    assert all(float(forces.weight_gradient[n].norm(dim=-1).max()) > 1e-6 for n in ("attractor", "obstacle"))


def test_the_weight_gradient_part_is_minus_phi_times_the_weight_s_gradient():
    """Against finite differences of the weight alone, at fixed potential."""
    torch.manual_seed(0)
    tree = build_tree(spec_with(["obstacle", "damper"])).double()
    q, aux = states(4)
    forces = rest_forces(tree, q, aux)
    rest = torch.zeros_like(q)

    def weight_and_phi(x):
        nodes = tree(x, rest, aux, return_nodes=True).nodes
        return nodes["edge"]["obstacle"].w.reshape(-1), nodes["rmp"]["obstacle"].Phi.reshape(-1)

    _, phi = weight_and_phi(q)
    h = 1e-6
    for k in range(2):
        step = torch.zeros_like(q)
        step[:, k] = h
        dw = (weight_and_phi(q + step)[0] - weight_and_phi(q - step)[0]) / (2 * h)
        torch.testing.assert_close(
            forces.weight_gradient["obstacle"][:, k], -phi.detach() * dw.detach(), atol=1e-7, rtol=1e-6
        )


@pytest.mark.parametrize("removed", ["attractor", "obstacle", "home"])
def test_a_leaf_s_force_is_what_its_removal_takes_from_the_root(removed):
    """Independent of the path-weight bookkeeping: the same modules without one leaf."""
    torch.manual_seed(0)
    full = build_tree(spec_with(["attractor", "obstacle", "home", "damper"])).double()
    kept = [n for n in ("attractor", "obstacle", "home", "damper") if n != removed]
    without = build_tree(copy.deepcopy(spec_with(kept))).double()
    without.load_state_dict(full.state_dict(), strict=False)  # the same map and weights
    q, aux = states()
    forces = rest_forces(full, q, aux)
    rest = torch.zeros_like(q)
    taken = full(q, rest, aux).f - without(q, rest, aux).f
    torch.testing.assert_close(forces.leaves[removed], taken, atol=1e-10, rtol=1e-10)
    assert float(taken.detach().norm(dim=-1).min()) > 1e-6, "the removed leaf pushes somewhere: the check can fail"


def test_strongest_ranks_leaves_by_their_median_force():
    torch.manual_seed(0)
    tree = build_tree(spec_with(["attractor", "obstacle", "home", "damper"])).double()
    q, aux = states()
    forces = rest_forces(tree, q, aux)
    ranked = forces.strongest(top=2)
    sizes = {n: float(f.norm(dim=-1).median()) for n, f in forces.leaves.items()}
    assert [n for n, _ in ranked] == sorted(sizes, key=lambda n: -sizes[n])[:2]
