"""A first-order baseline for recorded demonstrations: a velocity field through a learned diffeomorphism
(Euclideanizing-Flows style: Rana, Li, Wang, Ratliff & Boots, L4DC 2020), the kind of learner the LASA literature
compares against. It is not an RMP tree: it has no V_r and no metric, and it is here to be compared with one.

The field: with n = (x − g)/scale (the normalising map of tree=lasa) and ψ a diffeomorphism of the plane onto
itself (the coupling layers of ``maps/learned.py``) shifted so ψ(0) = 0, the latent motion is ż = −r·z, so

    ẋ = f(x) = −r · scale · J_ψ(n)⁻¹ ψ(n),

which has the goal as its only equilibrium and reaches it from everywhere (ψ is onto ℝⁿ; z decays
exponentially). The plant is second order, so the field is executed by velocity tracking (``velocity_tracking.py``) and trained
by the same behavior cloning on the recorded accelerations as the trees.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any, Literal

import torch
from pydantic import Field, field_validator
from torch import Tensor, nn

from ..maps.learned import Diffeomorphism
from ..registry import LEARNERS
from .velocity_tracking import TrackedField, TrackedFieldParams


@LEARNERS.register("first_order")
class FirstOrderLearner(TrackedField["FirstOrderLearner.Params"]):
    """ẋ = −r·scale·J_ψ⁻¹ψ((x − goal)/scale), tracked by q̈ = k_v(f − q̇) + (∂f/∂q)q̇."""

    kind = "first_order"

    class Params(TrackedFieldParams):
        layers: int = Field(4, ge=1, le=64, description="coupling layers of ψ")
        hidden: tuple[int, ...] = Field((32, 32), description="hidden widths of each layer's networks")
        activation: Literal["tanh", "softplus", "silu"] = "tanh"
        scale_bound: float = Field(2.0, gt=0, le=20, description="|log-scale| of a layer stays below this")
        init_std: float = Field(0.1, ge=0, le=10, description="std of the output layers' initial weights")
        rate: float = Field(1.0, gt=0, le=1000, description="the latent decay rate r (1/s) at the start; learned")

        @field_validator("hidden")
        @classmethod
        def _widths(cls, v: tuple[int, ...]) -> tuple[int, ...]:
            if not v or any(h < 1 for h in v):
                raise ValueError(f"hidden must list at least one width, each ≥ 1; given {list(v)}")
            return v

    def __init__(
        self,
        params: Params,
        tree_spec: Mapping[str, Any] | None,
        aux_dims: Mapping[str, int],
        dim: int,
        expert: Mapping[str, Any] | None = None,
    ):
        super().__init__(params, tree_spec, aux_dims, dim, expert)
        psi = Diffeomorphism.Params(
            layers=params.layers,
            hidden=params.hidden,
            activation=params.activation,
            scale_bound=params.scale_bound,
            origin=[0.0] * dim,
            init_std=params.init_std,
        )
        self.psi = Diffeomorphism(psi, dim).double()
        self.log_rate = nn.Parameter(torch.tensor(math.log(params.rate), dtype=torch.float64))

    def field(self, q: Tensor, aux: Mapping[str, Tensor]) -> Tensor:
        """f(q) (B, d): the velocity the field asks for at q."""
        s, n = self.params.scale, self.normalised(q, aux)
        z, _, J, _ = self.psi(n, torch.zeros_like(n))
        return -self.log_rate.exp() * s * torch.linalg.solve(J, z.unsqueeze(-1)).squeeze(-1)

    def learned_numbers(self) -> dict[str, float]:
        return {"rate": float(self.log_rate.detach().exp())}
