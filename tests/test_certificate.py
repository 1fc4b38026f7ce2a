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


def test_a_rollout_certified_in_chunks_and_every_nth_record_is_the_same_certificate(monkeypatch):
    """certify_rollout in chunks of 7 states (of 5 records x 6 samples, one sample ended early) equals certify over
    the finite records at once, the failing indices in the rollout's own numbering; every=2 certifies records 0, 2, 4."""
    from types import SimpleNamespace

    from rmpfusion.evaluate import certificate as cert_module

    tree, q, qd, aux = setup(7, 2, B=30)
    T, B = 5, 6
    ro = SimpleNamespace(q=q.reshape(T, B, -1).clone(), qd=qd.reshape(T, B, -1).clone())
    ro.q[3:, 2] = float("nan")  # sample 2 died after record 2
    per_sample = {k: v[:B] for k, v in aux.items()}
    whole = cert_module.certify_rollout(tree, ro, per_sample)
    monkeypatch.setattr(cert_module, "CHUNK", 7)
    chunked = cert_module.certify_rollout(tree, ro, per_sample)
    assert whole.states == chunked.states == T * B - 2
    a, b = chunked.as_dict(), whole.as_dict()
    # the finite-difference identity error is rounding at eps = 1e-6, which the batch's size moves (BLAS blocking)
    assert abs(a.pop("max_energy_identity_error") - b.pop("max_energy_identity_error")) < 1e-7
    assert a == b
    assert cert_module.certify_rollout(tree, ro, per_sample, every=2).states == 3 * B - 1


def test_a_state_beside_a_seam_of_a_boxs_distance_is_certified_with_a_narrower_stencil(monkeypatch):
    """A box's distance is once differentiable where the regions of its faces and edges meet (its curvature term
    jumps there): Theorem 2 holds on either side, but a central difference across the seam averages the two sides'
    rates. A state 3e-7 from the seam along the flow misses the identity at the 1e-6 step and meets it at a 10 times
    narrower one, while the tree that is not a GDS above misses it at every step."""
    spec = {
        "root": {"name": "q", "dim": 3},
        "nodes": {
            "o": {
                "parent": "q",
                "map": {"type": "box_obstacle", "center": [0.0, 0.0, 0.0], "half_extents": [0.1, 0.1, 0.1]},
                "rmp": {"type": "collision_avoidance", "r_w": 1.0, "sigma": 0.5, "epsilon": 0.2, "alpha": 1.0},
            },
            "d": {"parent": "q", "map": {"type": "identity"}, "rmp": {"type": "damper", "w": 1.0, "eta": 1.0}},
        },
    }
    tree = rmpfusion.build_tree(spec).double()
    q = torch.tensor([[0.15, 0.1 - 3e-7, 0.0]], dtype=torch.float64)  # beside the box's +x face, 3e-7 below its edge
    qd = torch.tensor([[-0.5, 1.0, 0.0]], dtype=torch.float64)  # towards the box, across into the edge's region
    from rmpfusion.evaluate import certificate as cert_module

    cert = certify(tree, q, qd)
    assert cert.ok, cert.summary()
    with monkeypatch.context() as m:
        m.setattr(cert_module, "REFINE", ())
        straddled = certify(tree, q, qd)  # the 1e-6 stencil alone: across the seam, a finite miss
    assert not straddled.ok and straddled.max_energy_identity_error > 100 * cert.max_energy_identity_error
