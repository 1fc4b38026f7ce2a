"""A leaf RMP tried on sample states when its tree is built, so a plugin leaf that breaks the contract every tree
relies on is refused by name before anything runs, instead of steering a robot the wrong way.

The contract (docs/math.md §3): on a d-dimensional node a leaf returns f (B, d), M, G and B (B, d, d), Φ, L and V
(B,); G and B are symmetric positive semi-definite; the symmetric part of M is positive semi-definite. M itself
need not be symmetric: M = G + Ξ_G, and Ξ_G is not symmetric when G depends on the velocity. These are what make
the root's M_r positive semi-definite and V_r non-increasing (Theorem 2). States where the leaf's answer is not
finite are left out (a barrier at its boundary): a NaN or inf is diagnosed by the tree when it is called.
"""

from __future__ import annotations

import torch
from torch import nn

#: Sample states per leaf, their distribution (y in [0.1, 2], a distance or coordinate ahead of any barrier's
#: boundary; ẏ standard normal) and the relative tolerance of the symmetry and semi-definiteness checks.
SAMPLES = 16
TOLERANCE = 1e-8


def _shape_problem(out, batch: int, dim: int) -> str | None:
    want = {
        "f": (batch, dim),
        "M": (batch, dim, dim),
        "G": (batch, dim, dim),
        "B": (batch, dim, dim),
        "Phi": (batch,),
        "L": (batch,),
        "V": (batch,),
    }
    for name, shape in want.items():
        t = getattr(out, name, None)
        if t is not None and tuple(t.shape) != shape:
            return (
                f"it returns {name} of shape {tuple(t.shape)} on a {dim}-dimensional node, where it must be "
                f"{shape} for a batch of {batch}"
            )
    return None


def _definiteness_problem(name: str, A: torch.Tensor, symmetric: bool) -> str | None:
    scale = 1.0 + float(A.abs().amax())
    if symmetric and float((A - A.transpose(-1, -2)).abs().amax()) > TOLERANCE * scale:
        return f"{name} is not symmetric (|{name} − {name}ᵀ| = {float((A - A.transpose(-1, -2)).abs().amax()):.3g})"
    low = float(torch.linalg.eigvalsh(0.5 * (A + A.transpose(-1, -2))).amin())
    if low < -TOLERANCE * scale:
        part = name if symmetric else f"the symmetric part of {name}"
        return f"{part} has the negative eigenvalue {low:.3g}, so it is not positive semi-definite"
    return None


def leaf_problem(leaf: nn.Module, dim: int) -> str | None:
    """Why ``leaf`` breaks the leaf contract on a ``dim``-dimensional node at the sample states, or None."""
    g = torch.Generator().manual_seed(0)
    y = 0.1 + 1.9 * torch.rand(SAMPLES, dim, generator=g, dtype=torch.float64)
    yd = torch.randn(SAMPLES, dim, generator=g, dtype=torch.float64)
    out = leaf.to(torch.float64)(y, yd)
    if (shape := _shape_problem(out, SAMPLES, dim)) is not None:
        return shape
    fields = [t for t in (out.f, out.M, out.G, out.B) if t is not None]
    finite = torch.stack([t.reshape(SAMPLES, -1).isfinite().all(-1) for t in fields]).all(0)
    if not bool(finite.any()):
        return None
    for name, A, symmetric in (("G", out.G, True), ("B", out.B, True), ("M", out.M, False)):
        if A is not None and (why := _definiteness_problem(name, A.detach()[finite], symmetric)) is not None:
            return why
    return None


def leaf_contract_message(leaf_type: str, why: str) -> str:
    return (
        f"the leaf '{leaf_type}' fails the leaf contract at sample states: {why}; a leaf must give symmetric positive semi-definite G and "
        "B and an M whose symmetric part is positive semi-definite, with f (B, d), M, G, B (B, d, d), Φ, L, V "
        "(B,) (docs/math.md §3), or the tree's q̈ = M⁺f and Theorem 2 do not hold; fix the leaf"
    )
