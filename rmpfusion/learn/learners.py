"""Learners from their config blocks: learner-rmp (``rmp_learner``) and learner-un (``unstructured``) are
registered in ``LEARNERS`` like a plugin's, and every one is built the same way (``build_learner``), in an
order where a learner sized after another comes after it (``build_order``).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from ..registry import LEARNERS
from . import first_order, rmp_learner, seds, unstructured  # noqa: F401  (the built-in learners register themselves)
from .learner import Learner


def build_learner(
    block: Mapping[str, Any],
    tree_spec: Mapping[str, Any],
    aux_dims: Mapping[str, int],
    dim: int,
    expert: Mapping[str, Any] | None = None,
    built: Mapping[str, Learner] | None = None,
    where: str = "learners",
) -> Learner:
    """Validate ``{type: ..., **params}`` with the learner's own model and build it.

    ``built`` holds learners already constructed, so ``match_parameters_of`` can be resolved. Initial weights
    are drawn in float64 whatever torch's default dtype (every learner builds its layers in float64), so one
    seed gives one learner.
    """
    block = dict(block)
    entry = LEARNERS.get(block.pop("type"))
    if not (isinstance(entry.obj, type) and issubclass(entry.obj, Learner)):
        raise TypeError(f"learner '{entry.name}' ({entry.owner}) is not a subclass of rmpfusion.learn.learner.Learner")
    params = entry.validate(block)
    return entry.obj.from_params(params, tree_spec, aux_dims, dim, expert=expert, built=built, where=where)


def build_order(blocks: Mapping[str, Mapping[str, Any]]) -> list[str]:
    """Learner names in an order where every ``match_parameters_of`` target comes first."""
    order: list[str] = []
    visiting: set[str] = set()

    def visit(n: str) -> None:
        if n in order:
            return
        if n in visiting:
            raise ValueError(f"learners: match_parameters_of forms a cycle through '{n}'")
        visiting.add(n)
        ref = blocks[n].get("match_parameters_of")
        if ref is not None:
            if ref not in blocks:
                raise ValueError(f"learners.{n}.match_parameters_of: no learner named '{ref}' (have: {sorted(blocks)})")
            visit(ref)
        visiting.discard(n)
        order.append(n)

    for n in blocks:
        visit(n)
    return order
