"""Scalar helpers shared by leaves: a stable log-cosh, the soft norm built on it, and radial integrals by
Gauss–Legendre quadrature."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import torch
from torch import Tensor

# torch constants (not numpy arrays): torch.compile treats them as graph constants instead of re-reading numpy
_GL_NODES, _GL_WEIGHTS = (torch.from_numpy(a) for a in np.polynomial.legendre.leggauss(16))


def logcosh(z: Tensor) -> Tensor:
    """log(cosh z) without overflow: |z| + log1p(e^{−2|z|}) − log 2."""
    a = z.abs()
    return a + torch.log1p(torch.exp(-2.0 * a)) - math.log(2.0)


def soft_norm(y: Tensor, alpha: float | Tensor) -> Tensor:
    """log cosh(α|y|)/α per sample: ½α|y|² near 0, |y| − log 2/α far away (an attractor's potential per unit gain).
    ``alpha`` is a number, or a group's (G, 1) numbers for y of shape (G, B, n)."""
    return logcosh(alpha * y.norm(dim=-1)) / alpha


def soft_norm_grad(y: Tensor, alpha: float | Tensor) -> Tensor:
    """∇_y of ``soft_norm``: tanh(α|y|)·y/|y|, of norm < 1; at y = 0 the limit α·y keeps it finite and smooth."""
    r = y.norm(dim=-1)
    small = r < 1e-8
    ratio = torch.where(
        small, alpha + torch.zeros_like(r), torch.tanh(alpha * r) / torch.where(small, torch.ones_like(r), r)
    )
    return ratio[..., None] * y


def radial_integral(integrand: Callable[[Tensor], Tensor], lo: Tensor, hi: Tensor, panels: int = 8) -> Tensor:
    """∫_lo^hi integrand(s) ds per sample (lo, hi of one shape, e.g. (B,)), composite 16-point Gauss–Legendre.
    ``integrand`` receives the nodes as (..., panels, 16).

    Accurate to rounding for the smooth, Gaussian-decaying integrands the attractors use.
    """
    t = _GL_NODES.to(dtype=lo.dtype, device=lo.device)
    wq = _GL_WEIGHTS.to(dtype=lo.dtype, device=lo.device)
    k = torch.arange(panels, dtype=lo.dtype, device=lo.device)
    width = (hi - lo) / panels  # (...,)
    # panel p spans [lo + p·width, lo + (p+1)·width]; node = panel centre + ½ width · t
    centers = lo[..., None] + (k + 0.5) * width[..., None]  # (..., P)
    s = centers[..., None] + 0.5 * width[..., None, None] * t  # (..., P, 16)
    vals = integrand(s)
    return 0.5 * width * (vals * wq).sum(dim=(-1, -2))
