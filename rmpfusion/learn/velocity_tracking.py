"""First-order learners executed on a second-order plant: the part every velocity-field baseline shares.

A first-order dynamical system ẋ = f(x) is what most of the learning-from-demonstration literature learns (SEDS,
CLF-DM, Euclideanizing Flows). The plants here are second order, so the field is executed by velocity tracking,

    q̈ = k_v·(f(q) − q̇) + (∂f/∂q)·q̇,

the usual way a first-order system drives a double integrator: q̇ follows f with time constant 1/k_v, and on a
motion that already follows the field (q̇ = f) the acceleration is exactly the field's own along the motion.
Behavior cloning on recorded accelerations therefore fits f to the recorded velocities (weighted by k_v²) beside
that acceleration. A subclass supplies the field; this class supplies the execution, so every baseline is run and
trained the same way and differs only in its field.
"""

from __future__ import annotations

from abc import abstractmethod
from collections.abc import Mapping
from typing import Any, ClassVar, TypeVar

import torch
from pydantic import Field
from torch import Tensor

from ..core.tree import RMPTree
from ..registry import Params
from .learner import Learner


class TrackedFieldParams(Params):
    """What every tracked field is configured by: the tracking gain, where the goal is, and the scale its field
    works at."""

    scale: float = Field(0.02, gt=0, description="the normalising map's scale (m), as tree=lasa's")
    tracking_gain: float = Field(10.0, gt=0, le=10000, description="k_v (1/s): how fast q̇ follows the field")
    goal: str = Field("goal", description="the aux entry holding the goal")


PT = TypeVar("PT", bound=TrackedFieldParams)


class TrackedField(Learner[PT]):
    """q̈ = k_v(f(q) − q̇) + (∂f/∂q)q̇ for the field ``f`` a subclass defines. Not an RMP tree: no V_r, no metric."""

    #: the registered name, for errors
    kind: ClassVar[str]

    def __init__(
        self,
        params: PT,
        tree_spec: Mapping[str, Any] | None,
        aux_dims: Mapping[str, int],
        dim: int,
        expert: Mapping[str, Any] | None = None,
    ):
        super().__init__()
        self.params, self.dim = params, dim
        if params.goal not in aux_dims or int(aux_dims[params.goal]) != dim:
            raise ValueError(
                f"{self.kind} needs the aux entry '{params.goal}' of dimension {dim} (the goal); the environment "
                f"gives {dict(aux_dims)}"
            )

    @abstractmethod
    def field(self, q: Tensor, aux: Mapping[str, Tensor]) -> Tensor:
        """f(q) (B, d): the velocity the field asks for at q."""

    has_first_order_field = True

    def first_order_field(self, q: Tensor, aux: Mapping[str, Tensor]) -> Tensor:
        """The field itself: what the tracking follows."""
        return self.field(q, aux)

    def normalised(self, q: Tensor, aux: Mapping[str, Tensor]) -> Tensor:
        """n = (q − goal)/scale: where every field is computed (the leaves' numbers suit coordinates of order one)."""
        return (q - aux[self.params.goal].to(q)) / self.params.scale

    @property
    def tree(self) -> RMPTree | None:
        return None

    def forward(self, q: Tensor, qd: Tensor, aux: Mapping[str, Tensor] | None = None) -> Tensor:
        f, along = self.field_and_rate(q, qd, aux or {})
        return self.params.tracking_gain * (f - qd) + along

    def field_and_rate(self, q: Tensor, qd: Tensor, aux: Mapping[str, Tensor]) -> tuple[Tensor, Tensor]:
        """(f(q), (∂f/∂q)q̇), the derivative by autograd, one row of ∂f/∂q at a time. A field with a closed form
        for it overrides this (its policy is then plain tensor algebra, which torch.export traces)."""
        keep_graph = torch.is_grad_enabled()  # training differentiates through (∂f/∂q)q̇; a rollout does not
        with torch.enable_grad():
            x = q if q.requires_grad else q.detach().requires_grad_(True)
            f = self.field(x, aux)
            rows = [
                torch.autograd.grad(f[:, i].sum(), x, create_graph=keep_graph, retain_graph=True)[0]
                for i in range(self.dim)
            ]
            along = torch.stack([(r * qd).sum(-1) for r in rows], -1)
        return (f, along) if keep_graph else (f.detach(), along.detach())

    def policy(self, q: Tensor, qd: Tensor, aux: Mapping[str, Tensor] | None = None) -> Tensor:
        return self(q, qd, aux)

    def export_refusal(self) -> str | None:
        return (
            f"learner '{self.kind}' is a first-order field executed by velocity tracking: its policy differentiates "
            "the field inside the call ((∂f/∂q)q̇), which torch.export cannot trace for a batch of any size (it "
            "fixes the batch, reverse or forward mode alike); run it in Python (rmpfusion-evaluate, or the learner "
            "loaded from its checkpoint) instead"
        )
