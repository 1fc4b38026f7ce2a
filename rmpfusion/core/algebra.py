"""RMP-algebra*: pushforward, pullback* and resolve on batched tensors (paper eq. 6).

Shapes: a node's coordinate is (B, m); matrices are (B, m, m); an edge Jacobian is (B, n, m);
the curvature term c = J̇ẋ is (B, n). Scalars (Phi, L, V, weights) are (B,).
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Iterable, Iterator, MutableMapping
from dataclasses import dataclass, fields
from typing import NamedTuple

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
    G: Tensor | None
    B: Tensor | None
    Phi: Tensor | None
    L: Tensor | None
    V: Tensor | None

    @classmethod
    def lean(cls, f: Tensor, M: Tensor) -> NodeRMP:
        """Only the natural form (f, M): all resolve needs, when no varying weight asks for L and G and nobody
        monitors V (``RMPTree.policy``)."""
        return cls(f, M, None, None, None, None, None)

    @classmethod
    def of(cls, values: Iterable[Tensor | None]) -> NodeRMP:
        """An RMP from its fields in declaration order, as ``items`` gives them; f and M are always present."""
        f, M, *rest = values
        assert f is not None and M is not None, "every RMP carries f and M"
        return cls(f, M, *rest)

    def values(self) -> tuple[Tensor | None, ...]:
        """The fields in declaration order (f, M, G, B, Φ, L, V)."""
        return (self.f, self.M, self.G, self.B, self.Phi, self.L, self.V)

    def items(self) -> Iterator[tuple[str, Tensor | None]]:
        return zip(FIELDS, self.values())

    def map(self, fn: Callable[[Tensor], Tensor]) -> NodeRMP:
        """``fn`` applied to every field the RMP carries (a lean RMP stays lean): how a group's RMP is indexed,
        summed or given a member dimension field by field."""
        if self.G is None:
            return NodeRMP.lean(fn(self.f), fn(self.M))
        return NodeRMP.of(None if v is None else fn(v) for v in self.values())

    def monitored(self) -> tuple[Tensor, Tensor, Tensor, Tensor, Tensor]:
        """(G, B, Φ, L, V) of an RMP that carries them: every RMP but a lean one."""
        G, B, Phi, L, V = self.G, self.B, self.Phi, self.L, self.V
        assert G is not None and B is not None and Phi is not None and L is not None and V is not None, (
            "a lean RMP (NodeRMP.lean) has f and M only"
        )
        return G, B, Phi, L, V


#: NodeRMP's fields in declaration order
FIELDS = tuple(f.name for f in fields(NodeRMP))


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
    """A B per sample for the small matrices of a tree, (…, n, k)·(…, k, m): the library's batched product eagerly
    (one call), a broadcast product and sum when traced for a compiler, which fuses it into its kernel instead of
    calling the library for a few multiply-adds per sample (the Franka tree's 18 batched products took half of its
    compiled call at B = 100, ``make bench``)."""
    if torch.compiler.is_compiling():
        return (A.unsqueeze(-1) * Bm.unsqueeze(-3)).sum(-2)
    return A @ Bm


def pushforward(J: Tensor, xd: Tensor) -> Tensor:
    """Child velocity ẏ = J ẋ."""
    return matvec(J, xd)


def _jt(J: Tensor, v: Tensor) -> Tensor:
    """Jᵀ v for J (..., n, m) and v (..., n)."""
    if J.shape[-2] == 1:
        return J[..., 0, :] * v
    return (J * v.unsqueeze(-1)).sum(-2)


class _Pull:
    """Pulls a child's quantities back through one edge: vectors by w Jᵀv, matrices by w JᵀXJ, scalars by w s.
    A 1-D child (distance spaces, the common case) has J = jᵀ, a row: its vectors pull back as v·j and its matrices
    as X·jjᵀ, by broadcasting (the weight folded into j and jjᵀ once); an identity edge skips J."""

    def __init__(self, J: Tensor, w: Tensor | None, identity: bool):
        self.J, self.w, self.identity = J, w, identity
        self.one_d = J.shape[-2] == 1 and not identity
        if self.one_d:
            j, jj = J[..., 0, :], J.mT * J
            self.j, self.jj = (j, jj) if w is None else (w[..., None] * j, w[..., None, None] * jj)

    def scalar(self, s: Tensor) -> Tensor:
        return s if self.w is None else self.w * s

    def vector(self, v: Tensor) -> Tensor:
        if self.one_d:
            return v * self.j
        out = v if self.identity else _jt(self.J, v)
        return out if self.w is None else self.w[..., None] * out

    def matrix(self, X: Tensor) -> Tensor:
        if self.one_d:
            return X * self.jj
        out = X if self.identity else matmul_small(matmul_small(self.J.mT, X), self.J)
        return out if self.w is None else self.w[..., None, None] * out


def _curvature_removed(f: Tensor, M: Tensor, c: Tensor, edge: Edge) -> Tensor:
    """f − M c, the child's force less what the map's curvature accounts for; an identity edge's J is constant, so
    its c = J̇ẋ is 0."""
    if edge.identity:
        return f
    if c.shape[-1] == 1:
        return f - M[..., 0] * c
    return f - matvec(M, c)


def edge_contribution(xd: Tensor, edge: Edge, child: NodeRMP) -> NodeRMP:
    """One child's term of pullback* (paper eq. 6) in the parent's coordinates, h_i included:
    ``w Jᵀ(f − M c) + h``, ``w JᵀMJ``, ``w JᵀGJ``, ``w JᵀBJ``, ``w Φ``, ``w L``, ``w V``.

    Any leading dimensions: a single edge's (B, ...) or a whole group's (G, B, ...) at once (the parent's ``xd``
    may be (1, B, m) when every member has the same parent). h_i = L_i ∇w_i − (ẋᵀ∇w_i) Jᵢᵀ Gᵢ Jᵢ ẋ uses the
    child's own, unweighted L_i and G_i. A child carrying only f and M (``NodeRMP.lean``, no varying weight
    above it) gives only the parent's f and M.
    """
    J, c, yd, w, gw, identity = edge
    pull = _Pull(J, w, identity)
    f = pull.vector(_curvature_removed(child.f, child.M, c, edge))
    M = pull.matrix(child.M)
    if child.G is None:
        return NodeRMP.lean(f, M)
    G, B, Phi, L, V = child.monitored()
    if gw is not None:
        # h_i uses the child's G_i and L_i unweighted (paper eq. 6): Jᵀ G_i (J ẋ) = Jᵀ G_i ẏ
        Gyd = matvec(G, yd)
        JtGyd = Gyd if identity else _jt(J, Gyd)
        f = f + L[..., None] * gw - (xd * gw).sum(-1, keepdim=True) * JtGyd
    return NodeRMP(
        f=f,
        M=M,
        G=pull.matrix(G),
        B=pull.matrix(B),
        Phi=pull.scalar(Phi),
        L=pull.scalar(L),
        V=pull.scalar(V),
    )


def add_rmps(a: NodeRMP | None, b: NodeRMP) -> NodeRMP:
    """Field-wise sum of two RMPs (a None: b); a field either lacks is left out (lean RMPs carry f and M only)."""
    if a is None:
        return b
    return NodeRMP.of(None if x is None or y is None else x + y for (_, x), (_, y) in zip(a.items(), b.items()))


def pullback_star(xd: Tensor, children: Iterable[tuple[Edge, NodeRMP]]) -> NodeRMP:
    """pullback* of paper eq. 6: the sum of every child's ``edge_contribution``.

    With every weight None (constant 1) this is exactly RMPflow's pullback, plus the carried G, B, Φ, L, V.
    """
    total: NodeRMP | None = None
    for edge, child in children:
        total = add_rmps(total, edge_contribution(xd, edge, child))
    if total is None:
        raise ValueError("pullback* needs at least one child")
    return total


class SingularInertiaWarning(RuntimeWarning):
    """``resolve`` met a singular root inertia M and answered with the Moore–Penrose pseudo-inverse there.

    Shown once per calling line by Python's default warning filter; every occurrence is counted in the
    ``events`` counter passed to ``resolve`` (each ``RMPTree`` keeps its own, ``tree.resolve_events``). A controller that must never act on such a state turns it into an exception with
    ``warnings.simplefilter("error", SingularInertiaWarning)``.
    """


#: Up to this many coordinates, a traced solve (``torch.compile``, ``torch.export``) is written out in tensor
#: operations (``_eliminated``) instead of calling LAPACK: a compiled graph fuses them into its kernel, while each
#: LAPACK call leaves the graph through inductor's generic shim, which cost 26 of a 65 µs compiled call of a 2-D tree
#: (``make bench``, latency). Larger roots call LAPACK traced too (an unrolled elimination grows as n²).
TRACED_ELIMINATION_MAX_DIM = 12


def _eliminated(M: Tensor, f: Tensor) -> tuple[Tensor, Tensor]:
    """(M⁻¹f, |pivots|) by Gauss–Jordan elimination of [M | f] with LAPACK's partial pivoting (the row of largest
    |a_ik|, i ≥ k, the first of equals), unrolled over the n columns: the same pivots as an LU factorisation, in
    tensor operations only, so that a compiler fuses the solve with the rest of the tree."""
    n = M.shape[-1]
    A = torch.cat([M, f.unsqueeze(-1)], -1)  # (..., n, n + 1)
    rows = torch.arange(n, device=M.device)
    pivots = []
    for k in range(n):
        p = k + A[..., k:, k].abs().argmax(-1)  # (...,): the pivot's row
        row_p = A.gather(-2, p[..., None, None].expand(*p.shape, 1, n + 1))  # (..., 1, n + 1)
        row_k = A[..., k : k + 1, :]
        at_k = (rows == k)[:, None]
        A = torch.where(at_k, row_p, torch.where((rows == p[..., None])[..., None], row_k, A))  # rows k, p swapped
        pivots.append(row_p[..., 0, k])
        unit = row_p / row_p[..., k : k + 1]
        A = torch.where(at_k, unit, A - A[..., :, k : k + 1] * unit)
    return A[..., n], torch.stack(pivots, -1).abs()


def _factorised(M: Tensor, f: Tensor) -> tuple[Tensor, Tensor]:
    """(M⁻¹f, |pivots|) by LAPACK's LU factorisation and solve (an exact zero pivot, LAPACK's info > 0, is a zero
    among the pivots, which the pivot test refuses)."""
    LU, piv, _ = torch.linalg.lu_factor_ex(M)
    a = torch.linalg.lu_solve(LU, piv, f.unsqueeze(-1)).squeeze(-1)
    return a, LU.diagonal(dim1=-2, dim2=-1).abs()


def lu_solve(M: Tensor, f: Tensor) -> tuple[Tensor, Tensor]:
    """M⁻¹f by LU with partial pivoting, and per sample whether it can be trusted: the result is finite and no
    pivot is negligible (|u_ii| > n·eps·max|u_jj|), so M is not singular up to rounding, where an LU solve would
    return an arbitrary null-space component instead of failing. Eagerly LAPACK's; traced for a compiler, the same
    elimination written out (``TRACED_ELIMINATION_MAX_DIM``)."""
    traced = torch.compiler.is_compiling() and M.shape[-1] <= TRACED_ELIMINATION_MAX_DIM
    a, pivots = _eliminated(M, f) if traced else _factorised(M, f)
    smallest, largest = torch.aminmax(pivots, dim=-1)
    good = torch.isfinite(a).all(-1) & (smallest > M.shape[-1] * torch.finfo(M.dtype).eps * largest)
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
            warnings.warn(
                SingularInertiaWarning(
                    f"resolve: the root inertia M is singular in {n_fix} of {M.shape[0]} samples "
                    f"(samples {idx[:10]}{' …' if n_fix > 10 else ''}); used the Moore–Penrose pseudo-inverse there "
                    "(q̈ = M⁺f has no component along M's null space). Add an identity_metric leaf on the root "
                    "to keep M invertible."
                ),
                stacklevel=2,
            )
    return a
