"""A joint-velocity cap as a GDS: a metric that grows without bound as a velocity nears its limit.

Per coordinate i of its space (the joints, or ``velocity_scaled_joints`` where every limit is 1), with the band
``r_i = max(|ẏ_i| − onset·L_i, 0) / ((1 − onset)·L_i)`` (0 below the onset, 1 at the limit L_i):

    G = diag(w·φ(r_i)),   φ(r) = r²/(1 − r²),   B = η·G,   Φ = 0,

so Ξ = diag(½ ẏ_i ∂g_i/∂ẏ_i) and ξ = 0 (G does not depend on y). Below the onset the leaf is absent (G = 0). Its
energy ½ Σ w·φ(r_i)·ẏ_i² grows without bound at the limit, and Theorem 2 bounds it by V_r(0): a velocity can reach
its limit only if the tree started with more energy than the cap holds there (docs/math.md §8, "Velocity limits").
RMP²'s joint-velocity cap (Li et al., 2021) uses w/(1 − r²) in the band, jumping from 0 to w at the onset, with a
damping acceleration and no curvature terms, so it is not a GDS; this metric starts from 0 (C¹ at the onset) and
carries Ξ. From ``linear_from`` of the band on, φ continues along its tangent line, so a state beyond the limit (an
integrator's overshoot, a measured velocity) gets a large but finite metric and the leaf stays an exact GDS.
"""

from __future__ import annotations

import torch
from pydantic import Field, field_validator
from torch import Tensor

from ..core.auxstate import constant
from ..core.gds import GDS
from ..examples import Example, StateSampler
from ..registry import LEAF_RMPS, Params, numbers_repr


def band_metric(r: Tensor, r_linear: float) -> tuple[Tensor, Tensor]:
    """(φ(r), φ'(r)) with φ = r²/(1 − r²) up to ``r_linear`` and its tangent line beyond."""
    rc = torch.clamp(r, max=r_linear)
    phi = rc**2 / (1 - rc**2)
    dphi = 2 * rc / (1 - rc**2) ** 2
    return phi + dphi * (r - rc), dphi


def band_states(limit: tuple[float, ...] = (1.0,), onset: float = 0.8, linear_from: float = 0.99) -> StateSampler:
    """Examples' states of a velocity_limit leaf: each velocity below its onset, inside its band or beyond its
    limit, never within 0.05 band widths of the onset, of the start of the linear continuation or of the limit
    (where its metric is only C¹, or changes fast); positions do not matter. One sample has every coordinate
    inside the band."""

    def states(gen: torch.Generator, n: int, dim: int) -> tuple[Tensor, Tensor]:
        L = torch.tensor(limit).expand(dim)
        on, band = onset * L, (1 - onset) * L
        r_lin = on + linear_from * band
        pick = torch.randint(0, 3, (n, dim), generator=gen)
        lo = torch.stack([torch.zeros_like(on), on + 0.05 * band, L + 0.05 * band])
        hi = torch.stack([on - 0.05 * band, r_lin - 0.05 * band * linear_from, L + 2 * band])
        lo, hi = lo.gather(0, pick), hi.gather(0, pick)
        sign = torch.where(torch.rand(n, dim, generator=gen) < 0.5, -1.0, 1.0)
        yd = sign * (lo + (hi - lo) * torch.rand(n, dim, generator=gen))
        yd[0] = on + band * 0.5
        return torch.randn(n, dim, generator=gen), yd

    return states


@LEAF_RMPS.register(
    "velocity_limit",
    examples=[
        Example({}, 3, band_states()),
        Example(
            {"limit": [2.0, 0.5], "onset": 0.6, "w": 3.0, "eta": 0.5, "linear_from": 0.9},
            2,
            band_states((2.0, 0.5), 0.6, 0.9),
        ),
    ],
)
class VelocityLimit(GDS):
    """Keeps |ẏ_i| below ``limit`` (per coordinate, or one for all): G = diag(w·φ(r_i)), B = η·G, Φ = 0 (module
    docstring); on ``velocity_scaled_joints`` with limit 1 it caps every joint at its URDF velocity limit."""

    class_potential_kind = "none"

    limit: Tensor  # buffers, per coordinate: the limit L_i,
    band: Tensor  # and the width of its band, (1 − onset)·L_i

    class Params(Params):
        limit: float | list[float] = Field(
            1.0, description="> 0: the velocity limit of each coordinate (one value for all, or one per coordinate)"
        )
        onset: float = Field(0.8, gt=0, lt=1, description="fraction of the limit where the cap starts acting")
        w: float = Field(1.0, gt=0, description="metric scale")
        eta: float = Field(1.0, ge=0, description="damping relative to the metric")
        linear_from: float = Field(
            0.99,
            gt=0,
            lt=1,
            description="fraction of the band (onset to limit) from which "
            "the metric grows linearly: finite beyond the limit",
        )

        @field_validator("limit")
        @classmethod
        def _positive(cls, v: float | list[float]) -> float | list[float]:
            values = v if isinstance(v, list) else [v]
            if not values or not all(x > 0 for x in values):
                raise ValueError(
                    f"limit must be > 0 (a velocity limit of 0 or less leaves no velocity allowed); given {v!r}"
                )
            return v

    def __init__(self, params: Params, dim: int):
        super().__init__(dim)
        limit = constant(params.limit).reshape(-1)
        if limit.numel() == 1:
            limit = limit.expand(dim).clone()
        if limit.numel() != dim:
            raise ValueError(
                f"velocity_limit.limit has {limit.numel()} values for a {dim}-dimensional space; give one "
                f"value, or one per coordinate"
            )
        self.register_buffer("limit", limit)
        self.register_buffer("band", (1 - params.onset) * limit)
        self.onset, self.w, self.eta, self.linear_from = params.onset, params.w, params.eta, params.linear_from

    def _g(self, yd: Tensor) -> tuple[Tensor, Tensor]:
        """(g_i, ½ ẏ_i ∂g_i/∂ẏ_i) per coordinate."""
        speed = yd.abs()
        r = torch.clamp(speed - self.onset * self.limit, min=0) / self.band
        phi, dphi = band_metric(r, self.linear_from)
        return self.w * phi, 0.5 * self.w * dphi * speed / self.band

    def metric(self, y, yd):
        return torch.diag_embed(self._g(yd)[0])

    def damping(self, y, yd):
        return self.eta * self.metric(y, yd)

    def potential(self, y):
        return y.new_zeros(y.shape[0])

    def potential_grad(self, y):
        return torch.zeros_like(y)

    def curvature(self, y, yd):
        return torch.diag_embed(self._g(yd)[1]), torch.zeros_like(yd)

    def terms(self, y, yd):
        """All six terms from one evaluation of the band metric."""
        g, half_v_dg = self._g(yd)
        G = torch.diag_embed(g)
        return (
            G,
            self.eta * G,
            y.new_zeros(y.shape[0]),
            torch.zeros_like(y),
            torch.diag_embed(half_v_dg),
            torch.zeros_like(yd),
        )

    def extra_repr(self) -> str:
        return numbers_repr(
            {
                "dim": self.dim,
                "limit": self.limit,
                "onset": self.onset,
                "w": self.w,
                "eta": self.eta,
                "linear_from": self.linear_from,
            }
        )
