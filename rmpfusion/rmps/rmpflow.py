"""Exact ports of the three leaves of RMPflow's reference implementation.

An RMPflow user can move a tree here and get identical accelerations. Beyond RMPflow's (f, M), each
leaf also reports G, B, Φ so L and V exist for pullback* and for the Lyapunov monitor. Their numbers only
meet per-sample scalars, so leaves of one type stack (``core/stacking.py``).
"""

from __future__ import annotations

import torch
from pydantic import Field
from torch import Tensor

from ..core.algebra import NodeRMP
from ..core.gds import LeafRMP
from ..core.stacking import spread
from ..examples import Example
from ..registry import LEAF_RMPS, numbers_repr
from .learnable import LeafParams
from .potentials import logcosh, radial_integral


def positive_distance_states(gen: torch.Generator, n: int, dim: int) -> tuple[Tensor, Tensor]:
    """Examples' states of RMPflow's 1/x⁴ barrier: distances in [0.3, 2], away from its clipping and from x = 0."""
    return 0.3 + 1.7 * torch.rand(n, dim, generator=gen), torch.randn(n, dim, generator=gen)


@LEAF_RMPS.register(
    "rmpflow_collision_avoidance", examples=[Example({"alpha": 1e-3, "eta": 0.5}, 1, positive_distance_states)]
)
class RMPflowCollisionAvoidance(LeafRMP):
    """RMPflow's CollisionAvoidance on a distance coordinate x.

    w = 1/x⁴ (w = 1e10, ∇w = 0 if x < 0), u = ε + min(0, ẋ)ẋ, G = w·u, M = G + ½ẋ·w·∂u/∂ẋ clipped to
    ±1e5, Φ = ½αw², ξ = ½ẋ²·u·∇w, f = −∇Φ − ξ − η·G·ẋ clipped to ±1e10.
    """

    dim = 1

    class Params(LeafParams):
        epsilon: float = Field(0.2, gt=0)
        alpha: float = Field(1e-5, ge=0)
        eta: float = Field(0.0, ge=0)

    stack_fields = ("epsilon", "alpha", "eta")

    def __init__(self, params: Params, dim: int = 1):
        super().__init__(dim)
        self.epsilon, self.alpha, self.eta = params.epsilon, params.alpha, params.eta

    def _natural(self, y: Tensor, yd: Tensor) -> tuple[Tensor, Tensor, Tensor, Tensor, Tensor]:
        """(f, M, w, G = w·u, ẋ) on per-sample scalars: RMPflow's natural form and what B, Φ, L, V are made of."""
        x, xd = y[..., 0], yd[..., 0]
        inside = x < 0
        xs = torch.where(inside, 1.0, x)  # keeps the unused branch finite
        w = torch.where(inside, 1e10, torch.pow(xs, -4))
        grad_w = torch.where(inside, 0.0, -4.0 * torch.pow(xs, -5))
        braking = torch.clamp(xd, max=0.0) * xd  # min(0, ẋ)·ẋ
        u = self.epsilon + braking
        g = w * u
        M = (g + w * braking).clamp(-1e5, 1e5)  # G + ½ẋ·w·∂u/∂ẋ with ∂u/∂ẋ = 2 min(0, ẋ)
        # −∇Φ − ξ − ηGẋ with ∇Φ = αw∇w and ξ = ½ẋ²u∇w
        f = (-(self.alpha * w + 0.5 * xd * xd * u) * grad_w - self.eta * g * xd).clamp(-1e10, 1e10)
        return f, M, w, g, xd

    def forward(self, y: Tensor, yd: Tensor) -> NodeRMP:
        f, M, w, g, xd = self._natural(y, yd)
        Phi = 0.5 * self.alpha * w * w
        K = 0.5 * xd * xd * g
        as_mat = lambda s: s[..., None, None]
        return NodeRMP(f=f[..., None], M=as_mat(M), G=as_mat(g), B=as_mat(self.eta * g), Phi=Phi, L=K - Phi, V=K + Phi)

    def force(self, y: Tensor, yd: Tensor) -> NodeRMP:
        f, M, *_ = self._natural(y, yd)
        return NodeRMP.lean(f[..., None], M[..., None, None])  # no Φ, K: only for L and V

    def extra_repr(self) -> str:
        return numbers_repr({"dim": self.dim, "epsilon": self.epsilon, "alpha": self.alpha, "eta": self.eta})


@LEAF_RMPS.register(
    "rmpflow_goal_attractor",
    examples=[Example({}, 2, scale=2.0), Example({"gain": 1.5, "sigma": 0.8, "eta": 1.0}, 3, scale=2.0)],
)
class RMPflowGoalAttractor(LeafRMP):
    """RMPflow's GoalAttractorUni on x = y − goal.

    β = exp(−|x|²/2σ²), w = (w_u − w_l)β + w_l, G = M = wI, ∇Φ = gain·w·tanh(α|x|)·x/|x| (0 when
    |x| ≤ tol), f = −∇Φ − η·w·ẋ − ξ_G. Φ is the radial integral of |∇Φ| from tol, by quadrature.
    """

    class Params(LeafParams):
        w_u: float = Field(10.0, gt=0)
        w_l: float = Field(1.0, gt=0)
        sigma: float = Field(1.0, gt=0)
        alpha: float = Field(1.0, gt=0)
        eta: float = Field(2.0, ge=0)
        gain: float = Field(1.0, ge=0)
        tol: float = Field(0.005, ge=0)

    stack_fields = ("w_u", "w_l", "sigma", "alpha", "eta", "gain", "tol")

    def __init__(self, params: Params, dim: int):
        super().__init__(dim)
        p = params
        self.w_u, self.w_l, self.sigma, self.alpha = p.w_u, p.w_l, p.sigma, p.alpha
        self.eta, self.gain, self.tol = p.eta, p.gain, p.tol

    def potential(self, r: Tensor) -> Tensor:
        """Φ(r) = ∫_tol^r gain·w(s)·tanh(αs) ds for r > tol, else 0."""
        lo = self.tol + torch.zeros_like(r)
        hi = torch.maximum(r, lo)
        base = self.w_l / self.alpha * (logcosh(self.alpha * hi) - logcosh(self.alpha * lo))
        # the Gaussian part is negligible beyond 12σ: integrate it only there, so panels stay fine
        hi_g = torch.minimum(hi, lo + 12.0 * self.sigma)
        a, s2 = spread(self.alpha, 2), spread(self.sigma**2, 2)  # beside the (…, panel, node) grid
        bump = radial_integral(lambda s: torch.exp(-(s**2) / (2 * s2)) * torch.tanh(a * s), lo, hi_g)
        return self.gain * (base + (self.w_u - self.w_l) * bump)

    def _natural(self, y: Tensor, yd: Tensor) -> tuple[Tensor, Tensor, Tensor, Tensor, Tensor]:
        """(f, M = G, w, |ẏ|², |y|): everything but the potential."""
        r = torch.linalg.vector_norm(y, dim=-1)
        beta = torch.exp(r * r * (-0.5 / self.sigma**2))
        w = (self.w_u - self.w_l) * beta + self.w_l
        far = r > self.tol
        s = torch.tanh(self.alpha * r)
        # ∇Φ = gain·w·tanh(α|y|)·y/|y|, 0 within tol of the goal (where |y| may vanish)
        grad_Phi = torch.where(far, self.gain * w * s / torch.where(far, r, 1.0), 0.0)[..., None] * y
        grad_w = (beta * (-(self.w_u - self.w_l) / self.sigma**2))[..., None] * y
        yd2 = (yd * yd).sum(-1)
        xi = yd * (yd * grad_w).sum(-1, keepdim=True) - (0.5 * yd2)[..., None] * grad_w
        f = -grad_Phi - (self.eta * w)[..., None] * yd - xi
        G = w[..., None, None] * torch.eye(y.shape[-1], dtype=y.dtype, device=y.device)
        return f, G, w, yd2, r

    def forward(self, y: Tensor, yd: Tensor) -> NodeRMP:
        f, G, w, yd2, r = self._natural(y, yd)
        Phi = self.potential(r)
        K = 0.5 * w * yd2
        eye = torch.eye(y.shape[-1], dtype=y.dtype, device=y.device)
        return NodeRMP(f=f, M=G, G=G, B=(self.eta * w)[..., None, None] * eye, Phi=Phi, L=K - Phi, V=K + Phi)

    def force(self, y: Tensor, yd: Tensor) -> NodeRMP:
        f, G, *_ = self._natural(y, yd)
        return NodeRMP.lean(f, G)  # no quadrature: Φ is only for L and V

    def extra_repr(self) -> str:
        return numbers_repr(
            {
                "dim": self.dim,
                "w_u": self.w_u,
                "w_l": self.w_l,
                "sigma": self.sigma,
                "alpha": self.alpha,
                "eta": self.eta,
                "gain": self.gain,
                "tol": self.tol,
            }
        )


@LEAF_RMPS.register("rmpflow_damper", examples=[Example({"w": 2.0, "eta": 0.5}, 3)])
class RMPflowDamper(LeafRMP):
    """RMPflow's Damper: G = M = wI, f = −η·w·ẋ, in any dimension."""

    class Params(LeafParams):
        w: float = Field(1.0, gt=0)
        eta: float = Field(1.0, ge=0)

    stack_fields = ("w", "eta")

    def __init__(self, params: Params, dim: int):
        super().__init__(dim)
        self.w, self.eta = params.w, params.eta

    def forward(self, y: Tensor, yd: Tensor) -> NodeRMP:
        n = y.shape[-1]
        eye = torch.eye(n, dtype=y.dtype, device=y.device).expand(*yd.shape[:-1], n, n)
        G = spread(self.w, 2) * eye
        K = 0.5 * self.w * (yd * yd).sum(-1)
        Phi = torch.zeros_like(K)
        return NodeRMP(
            f=-spread(self.eta * self.w, 1) * yd, M=G, G=G, B=spread(self.eta * self.w, 2) * eye, Phi=Phi, L=K, V=K
        )

    def extra_repr(self) -> str:
        return numbers_repr({"dim": self.dim, "w": self.w, "eta": self.eta})
