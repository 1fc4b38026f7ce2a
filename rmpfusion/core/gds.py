"""Leaf RMPs as geometric dynamical systems (G, B, Φ) with M, f, L, V derived per docs/math.md §3.

Ξ_G = ½ Σ_i ẏ_i ∂_ẏ g_i          (the ½ is part of the definition)
ξ_G = Ġ_y ẏ − ½ ∇_y(ẏᵀ G ẏ),   Ġ_y = [∂_y g_i ẏ]_i
M = G + Ξ_G,   f = −∇Φ − B ẏ − ξ_G,   L = ½ ẏᵀGẏ − Φ,   V = ½ ẏᵀGẏ + Φ
"""

from __future__ import annotations

from typing import ClassVar

import torch
from torch import Tensor, nn

from . import autodiff
from .algebra import NodeRMP, matvec
from .learnable import Number, assign_number, install_numbers
from .stacking import Stackable


class LeafRMP(Stackable, nn.Module):
    """A leaf of the tree: anything that returns a NodeRMP for a batch of (y, ẏ).

    Leaves of one kind evaluate as one batch when the class declares how its members stack (``core/stacking.py``):
    then ``forward`` also takes ``(G, B, n)`` inputs, its numbers broadcasting as ``(G, 1)``."""

    dim: int | None = None  # None: any dimension
    coordinates: str | None = None  # the map output it reads when not plain coordinates (TaskMap.coordinates)
    #: The potential every leaf of the class has (what ``potential_kind`` says unless a leaf's numbers decide it).
    class_potential_kind: ClassVar[str] = "unknown"

    @property
    def potential_kind(self) -> str:
        """Its potential Φ, for the premise check of docs/math.md §12 (``assembly/premises.py``): "none" (Φ = 0),
        "attractor" (radially unbounded, its only minimum at the origin of its space, for any numbers: premise 2),
        "other" (a barrier's, a moving goal's, ...) or "unknown" (undeclared, or not a GDS: the check assumes the
        worst). The class's ``class_potential_kind``; a leaf whose potential vanishes for some fixed numbers (a
        barrier whose potential gain is fixed at 0) says so for itself."""
        return self.class_potential_kind

    def damps(self) -> bool:
        """Whether its damping B is positive definite on its whole space with its numbers as they are (premise 4
        of docs/math.md §12); False unless a leaf says otherwise."""
        return False

    def __init_subclass__(cls, **kwargs):
        """Each number the class declares (``stack_fields``) may be learned (``core/learnable.py``): reading it
        computes it from its raw parameter when the config made it learnable, and gives the constant otherwise."""
        super().__init_subclass__(**kwargs)
        install_numbers(cls, cls.__dict__.get("stack_fields"))

    def __setattr__(self, name: str, value) -> None:
        if isinstance(getattr(type(self), name, None), Number) and assign_number(self, name, value):
            return
        super().__setattr__(name, value)

    def __init__(self, dim: int):
        super().__init__()
        if self.dim is not None and dim != self.dim:
            raise ValueError(f"{type(self).__name__} is {self.dim}-dimensional but its space has dimension {dim}")
        self.dim = int(dim)

    def forward(self, y: Tensor, yd: Tensor) -> NodeRMP:  # pragma: no cover - abstract
        raise NotImplementedError

    def force(self, y: Tensor, yd: Tensor) -> NodeRMP:
        """Only the natural form (f, M) (``NodeRMP.lean``): what a tree's policy needs when nothing asks for the
        leaf's L, V. A leaf whose potential is costly overrides it to skip that."""
        r = self.forward(y, yd)  # the tree's leaves take no hooks: no nn.Module call machinery
        return NodeRMP.lean(r.f, r.M)


def quad(v: Tensor, A: Tensor) -> Tensor:
    """vᵀ A v per sample (any leading dimensions)."""
    return (matvec(A, v) * v).sum(-1)


def positive(number) -> bool:
    """A leaf's number (a float, or a learned number's current value) > 0 everywhere."""
    return bool((torch.as_tensor(number) > 0).all())


class GDS(LeafRMP):
    """A leaf defined by metric G(y, ẏ), damping B(y, ẏ) and potential Φ(y).

    Subclasses implement ``metric``, ``damping`` and ``potential``; ``potential_grad`` and ``curvature``
    default to autodiff and may be overridden analytically (tests compare both to finite differences).
    """

    def metric(self, y: Tensor, yd: Tensor) -> Tensor:  # pragma: no cover - abstract
        raise NotImplementedError

    def damping(self, y: Tensor, yd: Tensor) -> Tensor:  # pragma: no cover - abstract
        raise NotImplementedError

    def potential(self, y: Tensor) -> Tensor:  # pragma: no cover - abstract
        raise NotImplementedError

    def potential_grad(self, y: Tensor) -> Tensor:
        return autodiff.gradient(self.potential, y)

    def curvature(self, y: Tensor, yd: Tensor) -> tuple[Tensor, Tensor]:
        """(Ξ_G, ξ_G) by autodiff of the metric."""
        v = yd  # the vector G multiplies: a constant for the derivatives of G below

        def Gv_of_yd(z: Tensor) -> Tensor:
            return (self.metric(y, z) @ v.unsqueeze(-1)).squeeze(-1)

        Xi = 0.5 * autodiff.jacobian(Gv_of_yd, yd)
        Gdot_yd = autodiff.directional(lambda z: (self.metric(z, yd) @ v.unsqueeze(-1)).squeeze(-1), y, yd)
        grad_quad = autodiff.gradient(lambda z: quad(v, self.metric(z, yd)), y)
        xi = Gdot_yd - 0.5 * grad_quad
        return Xi, xi

    def terms(self, y: Tensor, yd: Tensor) -> tuple[Tensor, Tensor, Tensor, Tensor, Tensor, Tensor]:
        """(G, B, Φ, ∇Φ, Ξ_G, ξ_G) from the methods above; a leaf may override it to share intermediate
        values between them (tests hold the override to the separate methods)."""
        Xi, xi = self.curvature(y, yd)
        return self.metric(y, yd), self.damping(y, yd), self.potential(y), self.potential_grad(y), Xi, xi

    def forward(self, y: Tensor, yd: Tensor) -> NodeRMP:
        G, Bm, Phi, dPhi, Xi, xi = self.terms(y, yd)
        K = 0.5 * quad(yd, G)
        return NodeRMP(f=-dPhi - matvec(Bm, yd) - xi, M=G + Xi, G=G, B=Bm, Phi=Phi, L=K - Phi, V=K + Phi)

    def force(self, y: Tensor, yd: Tensor) -> NodeRMP:
        G, Bm, _, dPhi, Xi, xi = self.terms(y, yd)
        return NodeRMP.lean(-dPhi - matvec(Bm, yd) - xi, G + Xi)
