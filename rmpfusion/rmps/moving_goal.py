"""The moving-goal attractor: tracks a goal that moves, from the coordinates (e, ġ) of the ``moving_offset`` map.

In the goal's frame, e = x − g, the tracker is the GDS ``w·ë = −∇Φ₀(e) − η·w·ė`` with Φ₀ = gain·log cosh(α|e|)/α:
it damps the velocity relative to the goal, ė = ẋ − ġ, so a goal moving at constant velocity is followed without
lag (an attractor that damps ẋ instead trails it by the distance where its pull equals η·w·|ġ|). With a constant
metric that force is, in x,

    f = −∇Φ₀(e) + η·w·ġ − η·w·ẋ = −∇_e Φ − B ẋ,      Φ(e, ġ) = Φ₀(e) − η·w·ġᵀe,

so for aux held fixed the leaf is an exact GDS on y = (e, ġ) with G = diag(w·I, 0), B = η·G and this Φ, and
Theorem 2 holds as for any leaf. What holds while the goal moves is in docs/math.md §8 ("Moving goals").
"""

from __future__ import annotations

import torch
from pydantic import Field

from .. import registry
from ..core.gds import GDS
from ..examples import Example
from ..registry import LEAF_RMPS, numbers_repr
from .potentials import soft_norm, soft_norm_grad


@LEAF_RMPS.register(
    "moving_goal_attractor", examples=[Example({}, 4), Example({"gain": 2.0, "alpha": 4.0, "eta": 3.0, "w": 0.5}, 6)]
)
class MovingGoalAttractor(GDS):
    """Tracks a moving goal: on y = (e, ġ) (``moving_offset``), G = diag(w·I, 0), B = η·G,
    Φ = gain·log cosh(α|e|)/α − η·w·ġᵀe (module docstring)."""

    coordinates = "moving_offset"  # the tree builder puts it under a moving_offset map only
    class_potential_kind = "other"  # its Φ has the goal's velocity in it: not one fixed minimum

    class Params(registry.Params):  # registry.Params: this class takes its base's name
        gain: float = Field(1.0, gt=0, description="potential gain: the pull towards the goal is at most gain")
        alpha: float = Field(1.0, gt=0, description="softness: 1/alpha is the distance where the pull saturates")
        eta: float = Field(2.0, ge=0, description="damping of the velocity relative to the goal, per unit metric")
        w: float = Field(1.0, gt=0, description="metric scale")

    def __init__(self, params: Params, dim: int):
        if dim % 2:
            raise ValueError(
                f"moving_goal_attractor works on (offset to the goal, goal velocity), an even dimension, "
                f"but its space has dimension {dim}; put it under a moving_offset map"
            )
        super().__init__(dim)
        self.gain, self.alpha, self.eta, self.w = params.gain, params.alpha, params.eta, params.w
        self.n = dim // 2

    def _split(self, y):
        return y[:, : self.n], y[:, self.n :]

    def metric(self, y, yd):
        diagonal = torch.cat([torch.full_like(y[:, : self.n], self.w), torch.zeros_like(y[:, self.n :])], -1)
        return torch.diag_embed(diagonal)

    def damping(self, y, yd):
        return self.eta * self.metric(y, yd)

    def potential(self, y):
        e, v = self._split(y)
        return self.gain * soft_norm(e, self.alpha) - self.eta * self.w * (v * e).sum(-1)

    def potential_grad(self, y):
        e, v = self._split(y)
        drift = self.eta * self.w
        return torch.cat([self.gain * soft_norm_grad(e, self.alpha) - drift * v, -drift * e], -1)

    def curvature(self, y, yd):
        return torch.zeros(y.shape[0], self.dim, self.dim, dtype=y.dtype, device=y.device), torch.zeros_like(yd)

    def extra_repr(self) -> str:
        return numbers_repr({"dim": self.dim, "gain": self.gain, "alpha": self.alpha, "eta": self.eta, "w": self.w})
