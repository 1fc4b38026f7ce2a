"""Second-order forward-mode derivatives along one trajectory, in closed form: a ``Jet`` carries a quantity p
together with its Jacobian P = ∂p/∂x, its velocity ṗ = P ẋ and its curvature term c = J̇ẋ-part d²p/dt² at
ẍ = 0, for a root state (x, ẋ).

Task maps built from elementary pieces (affine layers, smooth activations, products, exponentials) return
(y, J, J̇ẋ) by pushing a jet through them: one pass, no nested autodiff. The rules are the chain and product rules
written out once here (with ẍ = 0):

* affine   q = W p + b:   Q = W P,        q̇ = W ṗ,        c_q = W c_p
* pointwise q = σ(p):     Q = σ'(p) P,    q̇ = σ'(p) ṗ,    c_q = σ''(p) ṗ² + σ'(p) c_p
* product  q = u ⊙ w:     Q = U w + u W,  q̇ = u̇ w + u ẇ,  c_q = c_u w + 2 u̇ ẇ + u c_w

The autodiff of ``core/autodiff.py`` is the reference the tests hold every map built this way to.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import torch
from torch import Tensor


@dataclass
class Jet:
    """p (B, k), P (B, k, n), ṗ (B, k), c (B, k) for a root of dimension n."""

    value: Tensor
    jac: Tensor
    vel: Tensor
    curv: Tensor

    @staticmethod
    def seed(x: Tensor, xd: Tensor) -> Jet:
        """The root coordinates themselves: P = I, ṗ = ẋ, c = 0."""
        n = x.shape[-1]
        eye = torch.eye(n, dtype=x.dtype, device=x.device).expand(*x.shape[:-1], n, n)
        return Jet(x, eye, xd, torch.zeros_like(x))

    def take(self, index: Tensor) -> Jet:
        """The coordinates ``index`` of the quantity."""
        return Jet(self.value[..., index], self.jac[..., index, :], self.vel[..., index], self.curv[..., index])

    def affine(self, weight: Tensor, bias: Tensor | None = None) -> Jet:
        """W p + b for W (k', k)."""
        value = self.value @ weight.T + (bias if bias is not None else 0)
        return Jet(value, weight @ self.jac, self.vel @ weight.T, self.curv @ weight.T)

    def pointwise(self, f: Callable[[Tensor], tuple[Tensor, Tensor, Tensor]]) -> Jet:
        """σ(p) elementwise, ``f(p) = (σ, σ', σ'')``."""
        s, ds, dds = f(self.value)
        return Jet(s, ds[..., None] * self.jac, ds * self.vel, dds * self.vel * self.vel + ds * self.curv)

    def __mul__(self, other: Jet) -> Jet:
        u, w = self, other
        return Jet(
            u.value * w.value,
            u.jac * w.value[..., None] + u.value[..., None] * w.jac,
            u.vel * w.value + u.value * w.vel,
            u.curv * w.value + 2 * u.vel * w.vel + u.value * w.curv,
        )

    def __add__(self, other: Jet) -> Jet:
        return Jet(self.value + other.value, self.jac + other.jac, self.vel + other.vel, self.curv + other.curv)

    def __sub__(self, other: Jet) -> Jet:
        return Jet(self.value - other.value, self.jac - other.jac, self.vel - other.vel, self.curv - other.curv)

    @staticmethod
    def cat(parts: list[Jet], index: Tensor | None = None) -> Jet:
        """The parts' coordinates side by side, then reordered by ``index`` (None: as they come)."""
        out = Jet(
            torch.cat([p.value for p in parts], -1),
            torch.cat([p.jac for p in parts], -2),
            torch.cat([p.vel for p in parts], -1),
            torch.cat([p.curv for p in parts], -1),
        )
        return out if index is None else out.take(index)


def tanh3(z: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    t = torch.tanh(z)
    d = 1 - t * t
    return t, d, -2 * t * d


def softplus3(z: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    s = torch.sigmoid(z)
    return torch.nn.functional.softplus(z), s, s * (1 - s)


def silu3(z: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    s = torch.sigmoid(z)
    return z * s, s * (1 + z * (1 - s)), s * (1 - s) * (2 + z * (1 - 2 * s))


def sin3(z: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    s = torch.sin(z)
    return s, torch.cos(z), -s


def exp3(z: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    e = torch.exp(z)
    return e, e, e


#: smooth activations with their first two derivatives, by the name configs give them
SMOOTH = {"tanh": tanh3, "softplus": softplus3, "silu": silu3}
