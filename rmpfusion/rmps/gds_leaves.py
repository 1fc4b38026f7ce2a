"""GDS leaves: (G, B, Φ) given, M, f, L, V derived by the GDS base (analytic curvature where cheap).

Every leaf here is a true GDS, so Theorem 2 holds exactly for trees built from them with positive
weights; the autodiff curvature of the base class is the reference the tests compare against.

Their numbers (gains, radii, ...) only ever meet per-sample scalars, so leaves of one type evaluate as one batch
with their numbers stacked (``core/stacking.py``); on its own a leaf computes with plain floats.
"""

from __future__ import annotations

from typing import Protocol

import torch
from pydantic import Field, model_validator
from torch import Tensor

from ..core.gds import GDS, positive
from ..core.learnable import learned_ranges
from ..core.stacking import spread
from ..examples import Example
from ..registry import LEAF_RMPS, numbers_repr
from .learnable import LeafParams
from .potentials import soft_norm, soft_norm_grad


def _eye_like(y: Tensor) -> Tensor:
    """The identity of y's space, for every sample: (..., n, n)."""
    n = y.shape[-1]
    return torch.eye(n, dtype=y.dtype, device=y.device).expand(*y.shape[:-1], n, n)


class RadialMetricParams(Protocol):
    """The numbers of a radial metric and its damping, which the ``Params`` of every ``RadialMetricAttractor`` have."""

    @property
    def eta(self) -> float: ...
    @property
    def w_u(self) -> float: ...
    @property
    def w_l(self) -> float: ...
    @property
    def sigma(self) -> float: ...


class RadialMetricAttractor(GDS):
    """An attractor to the origin of its space with metric G = w(|y|)·I, w = (w_u − w_l)·exp(−|y|²/2σ²) + w_l
    (constant when w_u = w_l), and damping B = η·G; subclasses choose the potential Φ(y) (``potential`` and
    ``potential_grad``) and list their numbers in ``stack_fields``."""

    def __init__(self, params: RadialMetricParams, dim: int):
        super().__init__(dim)
        self.eta, self.w_u, self.w_l, self.sigma = params.eta, params.w_u, params.w_l, params.sigma

    def damps(self) -> bool:
        """B = η·w·I with w ≥ min(w_u, w_l) > 0: positive definite when η > 0."""
        return positive(self.eta)

    def _w(self, y: Tensor) -> tuple[Tensor, Tensor]:
        beta = torch.exp(-(y * y).sum(-1) / (2 * self.sigma**2))
        w = (self.w_u - self.w_l) * beta + self.w_l
        grad_w = -((self.w_u - self.w_l) * beta / self.sigma**2)[..., None] * y
        return w, grad_w

    def metric(self, y, yd):
        return self._w(y)[0][..., None, None] * _eye_like(y)

    def damping(self, y, yd):
        return (self.eta * self._w(y)[0])[..., None, None] * _eye_like(y)

    def curvature(self, y, yd):
        return self._curvature(y, yd, self._w(y)[1])

    @staticmethod
    def _curvature(y: Tensor, yd: Tensor, grad_w: Tensor) -> tuple[Tensor, Tensor]:
        xi = yd * (yd * grad_w).sum(-1, keepdim=True) - 0.5 * (yd * yd).sum(-1, keepdim=True) * grad_w
        return torch.zeros_like(_eye_like(y)), xi

    def terms(self, y, yd):
        """All six terms from one evaluation of the metric scale w(|y|)."""
        w, grad_w = self._w(y)
        eye = _eye_like(y)
        Xi, xi = self._curvature(y, yd, grad_w)
        return (
            w[..., None, None] * eye,
            (self.eta * w)[..., None, None] * eye,
            self.potential(y),
            self.potential_grad(y),
            Xi,
            xi,
        )


@LEAF_RMPS.register(
    "goal_attractor",
    examples=[
        Example({}, 2),
        Example({"w_u": 10.0, "w_l": 1.0, "sigma": 0.7, "gain": 2.0, "alpha": 3.0, "eta": 1.0}, 3),
        Example(
            {
                "w_u": {"learn": True, "init": 10.0},
                "sigma": {"learn": True, "init": 0.7},  # learned
                "gain": {"learn": True, "init": 2.0, "max": 5.0},
            },
            3,
        ),
    ],
)
class GoalAttractor(RadialMetricAttractor):
    """Soft-normalised attractor to the origin of its space (use an ``offset`` map to place the goal).

    Φ = gain·log cosh(α|y|)/α (its gradient has norm gain·tanh(α|y|): linear near the goal, constant
    far away). Metric G = w(|y|)·I with w = (w_u − w_l)·exp(−|y|²/2σ²) + w_l (constant when w_u = w_l);
    damping B = η·w·I.
    """

    class_potential_kind = "attractor"  # gain, α > 0: log cosh(α|y|) grows without bound, its only minimum at y = 0

    class Params(LeafParams):
        gain: float = Field(1.0, gt=0)
        alpha: float = Field(1.0, gt=0, description="softness: 1/alpha is the distance where Φ turns linear")
        eta: float = Field(2.0, ge=0, description="damping relative to the metric")
        w_u: float = Field(1.0, gt=0, description="metric scale at the goal")
        w_l: float = Field(1.0, gt=0, description="metric scale far from the goal")
        sigma: float = Field(1.0, gt=0)

    stack_fields = ("gain", "alpha", "eta", "w_u", "w_l", "sigma")

    def __init__(self, params: Params, dim: int):
        super().__init__(params, dim)
        self.gain, self.alpha = params.gain, params.alpha

    def potential(self, y):
        return self.gain * soft_norm(y, self.alpha)

    def potential_grad(self, y):
        return spread(self.gain, 1) * soft_norm_grad(y, self.alpha)

    def extra_repr(self) -> str:
        return numbers_repr(
            {
                "dim": self.dim,
                "gain": self.gain,
                "alpha": self.alpha,
                "eta": self.eta,
                "w_u": self.w_u,
                "w_l": self.w_l,
                "sigma": self.sigma,
            }
        )


class Barrier1D(GDS):
    """1-D barrier GDS on a distance coordinate x ≥ 0 (RMPflow paper, §obstacle avoidance).

    g(x, ẋ) = w(x)·u(ẋ) with w(x) = max(r_w − x, 0)²/x (zero beyond the support r_w) and velocity
    gating u(ẋ) = ε + (1 − exp(−ẋ²/2σ²)) for ẋ < 0 (approaching), ε otherwise.
    Φ = ½·α·w(x)², B = η·g. Below min_distance (inside an obstacle) w continues along its tangent line:
    finite, growing, still pushing outward, and still an exact GDS so Theorem 2 keeps holding.
    """

    dim = 1
    class_potential_kind = "other"  # a barrier: its force can balance an attractor's (docs/math.md §12, premise 5)

    @property
    def potential_kind(self) -> str:
        """ "none" when the potential gain α is fixed at 0: Φ = ½·α·w(x)² vanishes and the barrier is one of metric
        and damping only (its velocity-gated metric still grows without bound toward the obstacle, but no force of
        it can balance an attractor's at rest: premise 5 of docs/math.md §12 holds). A learned α lives in (0, ∞),
        so it has a potential whatever its current value; so has a fixed α > 0."""
        if "alpha" in learned_ranges(self) or float(self.alpha) != 0.0:
            return self.class_potential_kind
        return "none"

    class Params(LeafParams):
        r_w: float = Field(1.0, gt=0, description="support radius: no effect beyond this distance")
        sigma: float = Field(0.5, gt=0, description="velocity gating scale")
        epsilon: float = Field(0.2, ge=0, description="metric floor (always-on part of the gating)")
        alpha: float = Field(1e-5, ge=0, description="potential gain")
        eta: float = Field(0.0, ge=0, description="damping gain")
        min_distance: float = Field(
            1e-3, gt=0, description="< r_w: where the barrier's tangent-line continuation inside an obstacle starts"
        )

        @model_validator(mode="after")
        def _acts_somewhere(self):
            if not self.min_distance < self.r_w:
                raise ValueError(
                    f"min_distance must be < r_w (w(x) is evaluated at x ≥ min_distance and is zero "
                    f"from r_w on, so the barrier would never act); given min_distance={self.min_distance}, "
                    f"r_w={self.r_w}"
                )
            return self

    stack_fields = ("r_w", "sigma", "epsilon", "alpha", "eta", "min_distance")

    def __init__(self, params: Params, dim: int = 1):
        super().__init__(dim)
        p = params
        self.r_w, self.sigma, self.epsilon = p.r_w, p.sigma, p.epsilon
        self.alpha, self.eta, self.min_distance = p.alpha, p.eta, p.min_distance

    def _w(self, x: Tensor) -> tuple[Tensor, Tensor]:
        xc = x.clamp(min=self.min_distance)
        d = (self.r_w - xc).clamp(min=0.0)
        w = d**2 / xc
        grad_w = (-2.0 * d * xc - d**2) / xc**2
        # below min_distance: the tangent line, so w stays positive, finite and consistent with ∇w
        # (the leaf remains an exact GDS even when a control sphere penetrates an obstacle)
        inside = x < self.min_distance
        w = torch.where(inside, w + grad_w * (x - self.min_distance), w)
        return w, grad_w

    def _u(self, xd: Tensor) -> tuple[Tensor, Tensor]:
        approaching = xd < 0
        e = torch.exp(-(xd**2) / (2 * self.sigma**2))
        u = self.epsilon + torch.where(approaching, 1.0 - e, torch.zeros_like(xd))
        du = torch.where(approaching, xd / self.sigma**2 * e, torch.zeros_like(xd))
        return u, du

    def metric(self, y, yd):
        w, _ = self._w(y[..., 0])
        u, _ = self._u(yd[..., 0])
        return (w * u)[..., None, None]

    def damping(self, y, yd):
        w, _ = self._w(y[..., 0])
        u, _ = self._u(yd[..., 0])
        return (self.eta * w * u)[..., None, None]

    def potential(self, y):
        w, _ = self._w(y[..., 0])
        return 0.5 * self.alpha * w**2

    def potential_grad(self, y):
        w, gw = self._w(y[..., 0])
        return (self.alpha * w * gw)[..., None]

    def curvature(self, y, yd):
        return self.terms(y, yd)[4:]

    def terms(self, y, yd):
        """All six terms from one evaluation of w(x) and u(ẋ) (the methods above are views of it)."""
        x, xd = y[..., 0], yd[..., 0]
        w, gw = self._w(x)
        u, du = self._u(xd)
        g = w * u
        Xi = 0.5 * xd * w * du
        xi = 0.5 * xd**2 * u * gw
        return (
            g[..., None, None],
            (self.eta * g)[..., None, None],
            0.5 * self.alpha * w**2,
            (self.alpha * w * gw)[..., None],
            Xi[..., None, None],
            xi[..., None],
        )

    def extra_repr(self) -> str:
        return numbers_repr(
            {
                "dim": self.dim,
                "r_w": self.r_w,
                "sigma": self.sigma,
                "epsilon": self.epsilon,
                "alpha": self.alpha,
                "eta": self.eta,
                "min_distance": self.min_distance,
            }
        )


def barrier_states(gen: torch.Generator, n: int, dim: int) -> tuple[Tensor, Tensor]:
    """Examples' states of a barrier: distances inside its support (and inside the obstacle), approaching and
    receding."""
    y = -0.3 + 0.6 * torch.rand(n, dim, generator=gen)
    y[0, 0] = 0.25
    return y, torch.randn(n, dim, generator=gen)


@LEAF_RMPS.register(
    "collision_avoidance",
    examples=[
        Example({"r_w": 2.0, "eta": 0.5, "alpha": 0.1}, 1, barrier_states),
        Example(
            {
                "r_w": {"learn": True, "init": 2.0},
                "eta": {"learn": True, "init": 0.5},
                "sigma": {"learn": True, "init": 0.5},
            },
            1,
            barrier_states,
        ),
    ],
)
class CollisionAvoidance(Barrier1D):
    """Obstacle barrier on a distance space (velocity-gated, as in RMPflow)."""


@LEAF_RMPS.register("joint_limit", examples=[Example({}, 1, barrier_states)])
class JointLimitBarrier(Barrier1D):
    """Barrier on a 1-D joint-limit space (``upper − q`` or ``q − lower``), with joint-scale defaults."""

    class Params(Barrier1D.Params):
        r_w: float = Field(0.3, gt=0, description="support (rad or m): no effect further from the limit")
        sigma: float = Field(0.3, gt=0)
        epsilon: float = Field(0.1, ge=0)
        alpha: float = Field(1e-3, ge=0)


@LEAF_RMPS.register("damper", examples=[Example({"w": 2.0, "eta": 3.0}, 2)])
class Damper(GDS):
    """G = w·I, B = η·w·I, Φ = 0: damps motion in its space."""

    class_potential_kind = "none"

    def damps(self) -> bool:
        """B = η·w·I: positive definite when η > 0 (an identity metric's η is 0)."""
        return positive(self.eta) and positive(self.w)

    class Params(LeafParams):
        w: float = Field(1.0, gt=0)
        eta: float = Field(1.0, ge=0)

    stack_fields = ("w", "eta")

    def __init__(self, params: Params, dim: int):
        super().__init__(dim)
        self.w, self.eta = params.w, params.eta

    def metric(self, y, yd):
        return spread(self.w, 2) * _eye_like(y)

    def damping(self, y, yd):
        return spread(self.eta * self.w, 2) * _eye_like(y)

    def potential(self, y):
        return y.new_zeros(y.shape[:-1])

    def potential_grad(self, y):
        return torch.zeros_like(y)

    def curvature(self, y, yd):
        return torch.zeros_like(_eye_like(y)), torch.zeros_like(yd)

    def terms(self, y, yd):
        G = self.metric(y, yd)
        return G, self.damping(y, yd), self.potential(y), torch.zeros_like(y), torch.zeros_like(G), torch.zeros_like(yd)

    def stack_key(self):
        return (Damper, self.stack_settings(), self.learned_signature())  # identity metric: a damper, undamped

    def extra_repr(self) -> str:
        return numbers_repr({"dim": self.dim, "w": self.w, "eta": self.eta})


@LEAF_RMPS.register("identity_metric", examples=[Example({}, 3)])
class IdentityMetric(Damper):
    """G = scale·I, no force: keeps the root inertia well conditioned so resolve is numerically stable."""

    class Params(LeafParams):
        scale: float = Field(1e-2, gt=0)

    def __init__(self, params: Params, dim: int):
        super().__init__(Damper.Params(w=params.scale, eta=0.0), dim)

    def extra_repr(self) -> str:
        return numbers_repr({"dim": self.dim, "scale": self.w})
