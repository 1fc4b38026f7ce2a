"""RMP-algebra*: pushforward, pullback* and resolve on batched tensors (paper eq. 6).

Shapes: a node's coordinate is (B, m); matrices are (B, m, m); an edge Jacobian is (B, n, m);
the curvature term c = J̇ẋ is (B, n). Scalars (Phi, L, V, weights) are (B,).
"""
from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Iterable, NamedTuple

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


def pushforward(J: Tensor, xd: Tensor) -> Tensor:
    """Child velocity ẏ = J ẋ."""
    return torch.einsum("bnm,bm->bn", J, xd)


def _congruence(J: Tensor, A: Tensor) -> Tensor:
    """Jᵀ A J, with a cheap path for 1-D children (the common case of distance spaces)."""
    if A.shape[-1] == 1:
        j = J[:, 0, :]
        return A[:, 0, 0, None, None] * (j[:, :, None] * j[:, None, :])
    return J.transpose(-1, -2) @ A @ J


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
        J, c, yd, w, gw = edge
        fi = ch.f - (ch.M @ c.unsqueeze(-1)).squeeze(-1)
        f_i = _jt(J, fi)
        M_i = _congruence(J, ch.M)
        G_i = _congruence(J, ch.G)
        B_i = _congruence(J, ch.B)
        Phi_i, L_i, V_i = ch.Phi, ch.L, ch.V
        if w is not None:
            wc = w[:, None]
            f_i = wc * f_i
            M_i = w[:, None, None] * M_i
            G_i_w = w[:, None, None] * G_i
            B_i = w[:, None, None] * B_i
            Phi_i, L_i, V_i = w * Phi_i, w * L_i, w * V_i
        else:
            G_i_w = G_i
        if gw is not None:
            # h_i uses the child's G_i and L_i unweighted (paper eq. 6): Jᵀ G_i (J ẋ) = Jᵀ G_i ẏ
            JtGyd = _jt(J, (ch.G @ yd.unsqueeze(-1)).squeeze(-1))
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


def resolve(f: Tensor, M: Tensor, method: str = "solve") -> Tensor:
    """Canonical-form acceleration a = M⁺ f.

    ``pinv``: the Moore–Penrose inverse, always defined. ``solve``: an LU solve, which equals the
    Moore–Penrose answer whenever M is invertible; samples whose M is singular (or whose solve is not
    finite) fall back to the pseudo-inverse, so the result is always M⁺ f.
    """
    if method == "pinv":
        return (torch.linalg.pinv(M) @ f.unsqueeze(-1)).squeeze(-1)
    if method != "solve":
        raise ValueError(f"resolve method must be 'solve' or 'pinv', got {method!r}")
    a, info = torch.linalg.solve_ex(M, f.unsqueeze(-1))
    a = a.squeeze(-1)
    bad = (info != 0) | ~torch.isfinite(a).all(-1)
    if bool(bad.any()):
        # pseudo-inverse only where it is defined; a non-finite M stays non-finite for the caller to report
        fix = bad & torch.isfinite(M).flatten(1).all(-1) & torch.isfinite(f).all(-1)
        a = a.clone()
        a[bad] = float("nan")
        if bool(fix.any()):
            a[fix] = (torch.linalg.pinv(M[fix]) @ f[fix].unsqueeze(-1)).squeeze(-1)
    return a
