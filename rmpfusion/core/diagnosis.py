"""Where a non-finite value in a tree evaluation came from.

A tree checks only its answer (one check at the root, so an evaluation pays no per-node synchronisation); when
that answer is not finite it evaluates once more node by node and walks down to the first input, map, weight,
leaf or pullback* that produced a NaN or inf, naming it and the samples affected.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import torch
from torch import Tensor

from .layout import TreeLayout


class NumericalError(FloatingPointError):
    """A non-finite value in a tree evaluation; the message names where it first appeared.

    ``where`` is that place (``q``, ``aux['goal']``, ``weight at node 'o1'``, ...) and ``samples`` the batch
    indices affected there (None when unknown), so a caller can isolate those samples and keep the others.
    """

    def __init__(self, message: str, where: str | None = None, samples: list[int] | None = None):
        super().__init__(message)
        diagnosis = message if isinstance(message, Diagnosis) else None
        self.where = where if where is not None or diagnosis is None else diagnosis.where
        self.samples = samples if samples is not None or diagnosis is None else diagnosis.samples


class Diagnosis(str):
    """A diagnosis message that also carries where and which samples (read by NumericalError)."""

    where: str | None = None
    samples: list[int] | None = None

    @classmethod
    def make(cls, text: str, where: str | None = None, samples: list[int] | None = None) -> Diagnosis:
        d = cls(text)
        d.where, d.samples = where, samples
        return d


def nonfinite_samples(t: Tensor) -> list[int]:
    """Batch indices of the samples of ``t`` holding a non-finite value (all of them for an unbatched t)."""
    bad = ~torch.isfinite(t.detach())
    if bad.dim() == 0:
        return []
    return bad.reshape(bad.shape[0], -1).any(-1).nonzero().flatten().tolist()


def _samples_text(samples: list[int]) -> str:
    if not samples:
        return ""
    shown = ", ".join(map(str, samples[:10])) + (", …" if len(samples) > 10 else "")
    return f" in sample{'s' if len(samples) > 1 else ''} {shown}"


def _first_nonfinite(named) -> str | None:
    for name, t in named:
        if t is not None and not bool(torch.isfinite(t).all()):
            return name
    return None


def bad_input(q: Tensor, qd: Tensor, aux: Mapping[str, Tensor] | None, declared: Sequence[str]) -> Diagnosis | None:
    """A non-finite state or aux entry (only the entries the tree reads can be the cause)."""
    inputs = [("q", q), ("qd", qd), *((f"aux['{k}']", t) for k, t in (aux or {}).items() if k in declared)]
    bad = _first_nonfinite(inputs)
    if bad is None:
        return None
    samples = nonfinite_samples(dict(inputs)[bad])
    return Diagnosis.make(
        f"non-finite input {bad}{_samples_text(samples)}; check the state or aux state passed to "
        "the tree (a NaN here must not become a command)",
        bad,
        samples,
    )


def _scale(q: Tensor, qd: Tensor) -> str:
    """Finite but extreme inputs overflow inside the tree: say how large they were."""
    big = [f"max |{n}| = {float(t.detach().abs().max()):.3g}" for n, t in (("q", q), ("qd", qd)) if t.numel()]
    return "; inputs were finite (" + ", ".join(big) + ")"


def bad_node(
    layout: TreeLayout, order: Sequence[str], nodes: Mapping[str, Any], qdd: Tensor, q: Tensor, qd: Tensor
) -> Diagnosis:
    """The first node in pushforward order with a non-finite state, Jacobian, curvature or weight; else the first
    RMP in pullback* order; else the root; else resolve (a singular root inertia)."""
    for name in order:
        e = nodes["edge"][name]
        named = [
            ("y", nodes["state"][name][0]),
            ("ydot", nodes["state"][name][1]),
            ("J", e.J),
            ("Jdot_xdot", e.c),
            ("weight", e.w),
            ("weight gradient", e.grad_w),
        ]
        where = _first_nonfinite(named)
        if where:
            samples = nonfinite_samples(dict(named)[where])
            label = layout.labels[name]
            origin = f"weight {label.weight}" if where.startswith("weight") else f"map {label.map}"
            return Diagnosis.make(
                f"non-finite {where} at node '{name}' ({origin}){_samples_text(samples)}{_scale(q, qd)}",
                f"{where} at node '{name}'",
                samples,
            )
    for name in reversed(order):
        items = list(nodes["rmp"][name].items())
        where = _first_nonfinite(items)
        if where:
            samples = nonfinite_samples(dict(items)[where])
            rmp = layout.labels[name].rmp
            kind = f"leaf {rmp}" if rmp else "pullback* of its children"
            return Diagnosis.make(
                f"non-finite {where} in the RMP of node '{name}' ({kind}){_samples_text(samples)}{_scale(q, qd)}",
                f"{where} in the RMP of node '{name}'",
                samples,
            )
    items = list(nodes["rmp"][layout.root].items())
    where = _first_nonfinite(items)
    if where:
        samples = nonfinite_samples(dict(items)[where])
        return Diagnosis.make(
            f"non-finite root {where} after pullback*{_samples_text(samples)}{_scale(q, qd)}", f"root {where}", samples
        )
    samples = nonfinite_samples(qdd)
    return Diagnosis.make(
        f"non-finite acceleration from resolve{_samples_text(samples)}: the root inertia M is singular or badly "
        "conditioned there; add an identity_metric leaf on the root",
        "resolve",
        samples,
    )
