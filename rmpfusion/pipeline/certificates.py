"""Theorem 2 checked on a trained tree's rollouts: the certificate both evaluations (the expert's data, recorded
demonstrations) report for a learner that is a tree."""

from __future__ import annotations

from ..evaluate.certificate import certify_rollout
from ..learn.learner import Learner


def certificate(model: Learner, rollout, aux, every: int = 1) -> dict:
    """Theorem 2's premises and identity checked at every (``every``-th) record of the trained tree's test rollouts
    (``evaluate/certificate.py``): positive weights, positive-definite M_r, dV_r/dt = −q̇ᵀB_r q̇ ≤ 0. What a
    trained tree (learned weights, learnable leaf parameters) must still satisfy; the failing records counted."""
    assert model.tree is not None, "only a learner that is a tree has a certificate"
    d = certify_rollout(model.tree, rollout, aux, every=every).as_dict()
    return {
        **d,
        "every_record": every,
        "failing_states": len(d["failing_states"]),
        "non_finite_states": len(d["non_finite_states"]),
    }
