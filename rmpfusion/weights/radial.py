"""A learned weight that never decreases with the distance from a centre: speed shaping that adds no equilibrium.

A weight w(x) on an attractor's edge adds −Φ∇w to the attractor's force at rest (docs/math.md §12, premise 3). A
weight of the whole configuration can point that term anywhere, and balance the attractor short of the goal (the
LASA ``both`` variant, the recorded arm's with ``learned_leaves=arm_reach``). A weight of the distance ρ from the
attractor's own centre, never decreasing in it, has ∇w along the attractor's ∇Φ (both radial about the same point),
so the two add and the goal stays the only equilibrium, while the weight still sets how the metric and the pull grow
with the distance.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import torch
import torch.nn.functional as F
from pydantic import Field
from torch import Tensor, nn

from ..core.auxstate import CONSTANT_DTYPE, AuxOrValue, AuxParam
from ..core.weight import WeightFunction
from ..examples import AuxInput, Example
from ..registry import WEIGHTS, Params, numbers_repr


def _inverse_softplus(y: float) -> float:
    return math.log(math.expm1(y))


@WEIGHTS.register(
    "radial",
    examples=[
        Example({"center": [0.5, -0.5], "steps": 4, "reach": 2.0}, 2, scale=2.0),
        Example({"center": "goal", "smoothing": 0.1}, 3, scale=1.5, aux={"goal": AuxInput.normal(3)}),
    ],
)
class Radial(WeightFunction):
    """w = floor + softplus(b) + Σ_k softplus(a_k)·σ(softplus(s_k)·(ρ − c_k)), ρ = √(|x − center|² + ε²).

    Every term is non-decreasing in ρ whatever the learned numbers (a_k, s_k, c_k, b), so w is; ε smooths the cone
    at the centre (ρ is smooth everywhere, with ∇ρ = (x − center)/ρ). The steps start evenly spread over [0, reach],
    each as wide as their spacing and of equal height, the whole weight at ``init`` near the centre.
    """

    class Params(Params):
        center: AuxOrValue = Field(
            description="the attractor's centre: a point, or an aux name (a latent map's origin is its 0)"
        )
        steps: int = Field(8, ge=1, description="how many learned steps make up the profile")
        reach: float = Field(1.0, gt=0, description="the steps start spread over distances 0 to reach")
        init: float = Field(1.0, gt=0, description="w at the centre before training (it doubles out to reach)")
        smoothing: float = Field(1e-3, gt=0, description="ε: rounds the profile's cone at the centre")
        floor: float = Field(1e-3, gt=0, description="lower bound of w: keeps the edge strictly positive")

    def __init__(self, params: Params, in_dim: int, aux_dims: Mapping[str, int] | None = None):
        super().__init__(in_dim, aux_dims)
        p = params
        self.center = AuxParam(p.center, self.aux_dims, "radial.center")
        if self.center.dim != in_dim:
            raise ValueError(f"radial.center has dimension {self.center.dim}, the parent space has {in_dim}")
        K, spacing = p.steps, p.reach / max(p.steps - 1, 1)
        full = lambda v: nn.Parameter(torch.full((K,), v, dtype=CONSTANT_DTYPE))
        self.base = nn.Parameter(torch.tensor(_inverse_softplus(p.init), dtype=CONSTANT_DTYPE))
        self.heights = full(_inverse_softplus(p.init / K))
        self.slopes = full(_inverse_softplus(4.0 / spacing))
        self.positions = nn.Parameter(torch.linspace(0.0, p.reach, K, dtype=CONSTANT_DTYPE))
        self.smoothing, self.floor = p.smoothing, p.floor

    reads = "radial"  # w(ρ) non-decreasing in ρ = |x − center| by construction (docs/math.md §12, premise 3)

    @property
    def radial_center(self) -> AuxParam:  # type: ignore[override]
        """The point w is radial about: numbers or an aux name (what the premise check compares with the
        attractor's centre)."""
        return self.center

    def profile(self, rho: Tensor) -> tuple[Tensor, Tensor]:
        """w(ρ) and dw/dρ ≥ 0, for ρ of any shape."""
        h, s = F.softplus(self.heights), F.softplus(self.slopes)
        sig = torch.sigmoid(s * (rho[..., None] - self.positions))
        w = self.floor + F.softplus(self.base) + (h * sig).sum(-1)
        return w, (h * s * sig * (1 - sig)).sum(-1)

    def forward(self, x: Tensor, aux=None) -> tuple[Tensor, Tensor]:
        d = x - self.center(aux)
        rho = torch.sqrt((d * d).sum(-1) + self.smoothing**2)
        w, dw = self.profile(rho)
        return w, (dw / rho)[..., None] * d

    def value(self, x, aux):
        return self.forward(x, aux)[0]

    def extra_repr(self) -> str:
        return numbers_repr({"in_dim": self.in_dim, "steps": self.heights.numel(), "floor": self.floor})
