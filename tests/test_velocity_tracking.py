"""The velocity tracking every first-order baseline is executed by: q̈ = k_v(f − q̇) + (∂f/∂q)q̇, with the derivative
along the motion checked against a central difference of the field, and training's gradient reaching every
parameter through it; an environment without the goal the field needs is refused by name. SEDS's closed-form
derivative equals autograd's and exports for any batch size; a field differentiated by autograd inside the policy
refuses export (torch.export cannot trace that for a batch of any size)."""

from __future__ import annotations

import pytest
import torch

from rmpfusion.learn.export import export_learner
from rmpfusion.learn.velocity_tracking import TrackedField
from rmpfusion.registry import LEARNERS

KINDS = ("first_order", "seds")


def randomised(kind: str, seed: int):
    """The learner with every parameter drawn at random, so no term of the field is trivially zero."""
    entry = LEARNERS.get(kind)
    m = entry.obj(entry.validate({"scale": 0.5, "tracking_gain": 7.0}), None, {"goal": 2}, 2)
    gen = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for p in m.parameters():
            p.copy_(0.3 * torch.randn(p.shape, generator=gen, dtype=p.dtype))
    return m


@pytest.mark.parametrize("kind", KINDS)
def test_the_tracking_acceleration_adds_the_field_derivative_along_the_motion(kind):
    m = randomised(kind, 2)
    gen = torch.Generator().manual_seed(3)
    q = torch.randn(8, 2, generator=gen, dtype=torch.float64)
    qd = torch.randn(8, 2, generator=gen, dtype=torch.float64)
    aux = {"goal": 0.2 * torch.randn(8, 2, generator=gen, dtype=torch.float64)}
    with torch.no_grad():
        qdd = m(q, qd, aux)
        eps = 1e-6
        along = (m.field(q + eps * qd, aux) - m.field(q - eps * qd, aux)) / (2 * eps)
        expected = 7.0 * (m.field(q, aux) - qd) + along
    torch.testing.assert_close(qdd, expected, rtol=1e-6, atol=1e-8)
    assert float(along.abs().max()) > 1e-3  # the derivative term is really there


@pytest.mark.parametrize("kind", KINDS)
def test_training_differentiates_through_the_field_derivative(kind):
    m = randomised(kind, 4)
    q = torch.randn(4, 2, dtype=torch.float64)
    qd = torch.randn(4, 2, dtype=torch.float64)
    m(q, qd, {"goal": torch.zeros(4, 2, dtype=torch.float64)}).square().sum().backward()
    grads = {name: p.grad for name, p in m.named_parameters()}
    assert all(g is not None and torch.isfinite(g).all() for g in grads.values()), grads


@pytest.mark.parametrize("kind", KINDS)
def test_an_environment_without_the_goal_is_refused_by_name(kind):
    entry = LEARNERS.get(kind)
    with pytest.raises(ValueError, match=f"{kind} needs the aux entry 'goal' of dimension 2"):
        entry.obj(entry.validate({}), None, {"target": 2}, 2)


def test_an_autograd_field_refuses_export_with_the_reason_instead_of_a_tracing_error():
    m = randomised("first_order", 5)
    q = torch.randn(4, 2, dtype=torch.float64)
    aux = {"goal": torch.zeros(4, 2, dtype=torch.float64)}
    with pytest.raises(ValueError, match="learner 'first_order' is a first-order field .* cannot trace"):
        export_learner(m, q, torch.zeros_like(q), aux, ["goal"])


def test_seds_closed_form_derivative_equals_autograd_and_exports_for_any_batch():
    m = randomised("seds", 6)
    gen = torch.Generator().manual_seed(7)
    state = lambda b: (
        torch.randn(b, 2, generator=gen, dtype=torch.float64),
        torch.randn(b, 2, generator=gen, dtype=torch.float64),
        {"goal": 0.2 * torch.randn(b, 2, generator=gen, dtype=torch.float64)},
    )
    q, qd, aux = state(9)
    closed = m.field_and_rate(q, qd, aux)
    by_autograd = TrackedField.field_and_rate(m, q, qd, aux)
    for mine, reference in zip(closed, by_autograd):
        torch.testing.assert_close(mine, reference.detach(), rtol=1e-10, atol=1e-12)
    program = export_learner(m, *state(4), ["goal"])
    for b in (2, 13):
        q, qd, aux = state(b)
        with torch.no_grad():
            torch.testing.assert_close(program.module()(q, qd, aux["goal"]), m(q, qd, aux), rtol=1e-12, atol=1e-12)
