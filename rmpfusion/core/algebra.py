"""RMP-algebra*: pushforward, pullback* and resolve on batched tensors (paper eq. 6).

Shapes: a node's coordinate is (B, m); matrices are (B, m, m); an edge Jacobian is (B, n, m);
the curvature term c = J̇ẋ is (B, n). Scalars (Phi, L, V, weights) are (B,).
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass, fields
from typing import Iterable, MutableMapping, NamedTuple

import torch
from torch import Tensor


@dataclass
class NodeRMP:
    """A node's RMP in natural form plus what pullback* and the Lyapunov monitor need.

    f, M: the natural-form RMP; G: metric; B: damping; Phi: potential;
    L = ½ẏᵀGẏ − Φ (Lagrangian-like); V = ½ẏᵀGẏ + Φ (Lyapunov).
    """

    f: Tensor
    M: Tensor
    G: Tensor
    B: Tensor
    Phi: Tensor
    L: Tensor
    V: Tensor

    def items(self):
        return ((f.name, getattr(self, f.name)) for f in fields(self))


class Edge(NamedTuple):
    """What pushforward computed for one parent→child edge, and the weight on it."""

    J: Tensor  # (B, n, m)
    c: Tensor  # (B, n)  = J̇ ẋ
    yd: Tensor  # (B, n)  = J ẋ
    w: Tensor | None  # (B,) or None for the constant 1
    grad_w: Tensor | None  # (B, m) gradient w.r.t. the parent's configuration, None if constant
    identity: bool = False  # J is the identity (identity/offset maps): pullback* skips the products with J


def matvec(A: Tensor, v: Tensor) -> Tensor:
    """A v per sample, (B, n, m)·(B, m) → (B, n), as a broadcast product and sum: for the small matrices of
    RMP trees this beats a batched matrix product (and fuses under torch.compile instead of a library call)."""
    return (A * v.unsqueeze(-2)).sum(-1)


def matmul_small(A: Tensor, Bm: Tensor) -> Tensor:
    """A B per sample for small matrices, (…, n, k)·(…, k, m), as a broadcast product and sum (see ``matvec``)."""
    return (A.unsqueeze(-1) * Bm.unsqueeze(-3)).sum(-2)


def pushforward(J: Tensor, xd: Tensor) -> Tensor:
    """Child velocity ẏ = J ẋ."""
    return torch.einsum("bnm,bm->bn", J, xd)


def _jt(J: Tensor, v: Tensor) -> Tensor:
    """Jᵀ v for v of shape (B, n)."""
    if J.shape[1] == 1:
        return J[:, 0, :] * v
    return torch.einsum("bnm,bn->bm", J, v)


def pullback_star(xd: Tensor, children: Iterable[tuple[Edge, NodeRMP]]) -> NodeRMP:
    """pullback* of paper eq. 6, including h_i = L_i ∇w_i − (ẋᵀ∇w_i) Jᵢᵀ Gᵢ Jᵢ ẋ.

    With every weight None (constant 1) this is exactly RMPflow's pullback, plus the carried G, B, Φ, L, V.
    """
    f = M = G = Bm = Phi = L = V = None
    for edge, ch in children:
        J, c, yd, w, gw, identity = edge
        fi = ch.f - matvec(ch.M, c)
        Phi_i, L_i, V_i = ch.Phi, ch.L, ch.V
        if identity:
            f_i, M_i, G_i_w, B_i = fi, ch.M, ch.G, ch.B
            if w is not None:
                ww = w[:, None, None]
                f_i, M_i, G_i_w, B_i = w[:, None] * f_i, ww * M_i, ww * G_i_w, ww * B_i
        elif J.shape[1] == 1:
            # 1-D child (distance spaces, the common case): one outer product jjᵀ serves M, G and B,
            # and the weight multiplies the scalars before they are spread over the matrix
            j = J[:, 0, :]
            jj = j[:, :, None] * j[:, None, :]
            m, g, b, fs = ch.M[:, 0, 0], ch.G[:, 0, 0], ch.B[:, 0, 0], fi[:, 0]
            if w is not None:
                m, g, b, fs = w * m, w * g, w * b, w * fs
            f_i = fs[:, None] * j
            M_i, G_i_w, B_i = m[:, None, None] * jj, g[:, None, None] * jj, b[:, None, None] * jj
        else:
            Jt = J.transpose(-1, -2)
            f_i = (Jt @ fi.unsqueeze(-1)).squeeze(-1)
            M_i, G_i_w, B_i = Jt @ ch.M @ J, Jt @ ch.G @ J, Jt @ ch.B @ J
            if w is not None:
                ww = w[:, None, None]
                f_i, M_i, G_i_w, B_i = w[:, None] * f_i, ww * M_i, ww * G_i_w, ww * B_i
        if w is not None:
            Phi_i, L_i, V_i = w * Phi_i, w * L_i, w * V_i
        if gw is not None:
            # h_i uses the child's G_i and L_i unweighted (paper eq. 6): Jᵀ G_i (J ẋ) = Jᵀ G_i ẏ
            Gyd = matvec(ch.G, yd)
            JtGyd = Gyd if identity else _jt(J, Gyd)
            h = ch.L[:, None] * gw - (xd * gw).sum(-1, keepdim=True) * JtGyd
            f_i = f_i + h
        if f is None:
            f, M, G, Bm, Phi, L, V = f_i, M_i, G_i_w, B_i, Phi_i, L_i, V_i
        else:
            f, M, G, Bm = f + f_i, M + M_i, G + G_i_w, Bm + B_i
            Phi, L, V = Phi + Phi_i, L + L_i, V + V_i
    if f is None:
        raise ValueError("pullback* needs at least one child")
    return NodeRMP(f=f, M=M, G=G, B=Bm, Phi=Phi, L=L, V=V)


class SingularInertiaWarning(RuntimeWarning):
    """``resolve`` met a singular root inertia M and answered with the Moore–Penrose pseudo-inverse there.

    Shown once per calling line by Python's default warning filter; every occurrence is counted in the
    ``events`` counter passed to ``resolve`` (each ``RMPTree`` keeps its own, ``tree.resolve_events``). A controller that must never act on such a state turns it into an exception with
    ``warnings.simplefilter("error", SingularInertiaWarning)``.
    """


def lu_solve(M: Tensor, f: Tensor) -> tuple[Tensor, Tensor]:
    """M⁻¹f by an LU factorisation, and per sample whether it can be trusted: the factorisation succeeded, the
    result is finite, and no pivot is negligible (|u_ii| > n·eps·max|u_jj|), so M is not singular up to rounding,
    where an LU solve would return an arbitrary null-space component instead of failing."""
    LU, piv, info = torch.linalg.lu_factor_ex(M)
    a = torch.linalg.lu_solve(LU, piv, f.unsqueeze(-1)).squeeze(-1)
    pivots = LU.diagonal(dim1=-2, dim2=-1).abs()
    tiny = M.shape[-1] * torch.finfo(M.dtype).eps * pivots.amax(-1)
    good = (info == 0) & torch.isfinite(a).all(-1) & (pivots.amin(-1) > tiny)
    return a, good


def resolve(f: Tensor, M: Tensor, method: str = "solve", events: MutableMapping[str, int] | None = None) -> Tensor:
    """Canonical-form acceleration a = M⁺ f.

    ``pinv``: the Moore–Penrose inverse, always defined. ``solve``: an LU solve, which equals the
    Moore–Penrose answer whenever M is invertible; samples whose M is singular (or whose solve is not
    finite) fall back to the pseudo-inverse, so the result is always M⁺ f. Each fallback is reported by a
    ``SingularInertiaWarning`` naming the samples and, when ``events`` is given (a tree passes its own
    counter), counted there in samples: ``pinv_fallback`` (singular M, M⁺f used) and ``unsolvable``
    (non-finite M or f, left non-finite for the caller to report). Nothing is counted process-wide.
    """
    if method == "pinv":
        return (torch.linalg.pinv(M) @ f.unsqueeze(-1)).squeeze(-1)
    if method != "solve":
        raise ValueError(f"resolve method must be 'solve' or 'pinv', got {method!r}")
    a, good = lu_solve(M, f)
    bad = ~good
    if bool(bad.any()):
        # pseudo-inverse only where it is defined; a non-finite M stays non-finite for the caller to report
        fix = bad & torch.isfinite(M).flatten(1).all(-1) & torch.isfinite(f).all(-1)
        a = a.clone()
        a[bad] = float("nan")
        n_fix, n_bad = int(fix.sum()), int(bad.sum())
        if events is not None:
            events["pinv_fallback"] = events.get("pinv_fallback", 0) + n_fix
            events["unsolvable"] = events.get("unsolvable", 0) + n_bad - n_fix
        if n_fix:
            a[fix] = (torch.linalg.pinv(M[fix]) @ f[fix].unsqueeze(-1)).squeeze(-1)
            idx = fix.nonzero().flatten().tolist()
            warnings.warn(SingularInertiaWarning(
                f"resolve: the root inertia M is singular in {n_fix} of {M.shape[0]} samples "
                f"(samples {idx[:10]}{' …' if n_fix > 10 else ''}); used the Moore–Penrose pseudo-inverse there "
                "(q̈ = M⁺f has no component along M's null space). Add an identity_metric leaf on the root "
                "to keep M invertible."), stacklevel=2)
    return a
