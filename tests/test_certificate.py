"""The stability certificate passes on sound trees and catches a tree that breaks Theorem 2."""

import torch
from trees import setup

import rmpfusion
from rmpfusion.evaluate import certify


def test_certificate_passes_on_random_trees_with_neural_weights():
    tree, q, qd, aux = setup(7, 2, B=32)
    cert = certify(tree, q, qd, aux)
    assert cert.ok, cert.summary()
    assert cert.min_weight > 0 and cert.min_inertia_eigenvalue > 0
    assert "PASSED" in cert.summary()


def test_certificate_fails_for_a_leaf_that_is_not_a_gds():
    """RMPflow's collision leaf clips M to ±1e5 and f to ±1e10, so it is not a GDS where a clip is active
    (inside an obstacle, where w = 1e10): the certificate must say so."""
    spec = {
        "root": {"name": "q", "dim": 2},
        "nodes": {
            "o": {
                "parent": "q",
                "map": {"type": "sphere_distance", "center": [0, 0], "radius": 1.0, "normalized": True},
                "weight": {"type": "rbf", "low": 0.5, "high": 2.0, "center": [0.0, 0.0]},
                "rmp": {"type": "rmpflow_collision_avoidance", "alpha": 1.0},
            },
            "i": {"parent": "q", "map": {"type": "identity"}, "rmp": {"type": "identity_metric"}},
        },
    }
    tree = rmpfusion.build_tree(spec)
    q = torch.tensor([[0.5, 0.2], [0.1, -0.3]])  # inside the obstacle: w = 1e10 with ∇w = 0 there
    qd = torch.tensor([[1.0, -0.5], [0.3, 0.8]])
    cert = certify(tree, q, qd)
    assert not cert.ok and not cert.energy_identity_holds
    assert cert.failing_states
