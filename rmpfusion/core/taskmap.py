"""Task maps: the edges of an RMP-tree* (y = ψ(x), ẏ = J ẋ, c = J̇ ẋ)."""

from __future__ import annotations

from collections.abc import Mapping

from torch import Tensor, nn

from . import autodiff
from .auxstate import AuxDict
from .stacking import Stackable


class TaskMap(Stackable, nn.Module):
    """Base of every task map.

    Subclasses implement ``psi(x, aux)``; they may override ``jacobian`` and ``curvature`` with analytic
    forms (the default is exact forward-mode autodiff). ``out_dim`` is fixed at build time from
    ``in_dim`` and the declared aux dimensions, so trees are dimension-checked before they run.

    Maps of one kind under one parent group evaluate as one batch when the class declares how its members stack
    (``core/stacking.py``): then ``forward`` also takes inputs with a leading member dimension, ``(G, B, m)``.
    """

    in_dim: int
    out_dim: int
    #: J = I always (identity, offset), so J̇ẋ = 0 too: pullback* then skips its products with J and the curvature term
    identity_jacobian: bool = False
    # What the output is when it is more than coordinates of a space, e.g. "moving_offset": an offset to a goal
    # followed by the goal's velocity. A leaf reads such an output only if it declares the same (LeafRMP.coordinates),
    # and a leaf that declares one reads nothing else; the tree builder checks both.
    coordinates: str | None = None
    #: A diffeomorphism of ℝⁿ onto ℝⁿ for any parameters (J invertible everywhere, every point reached): premise 1
    #: of docs/math.md §12, read by the premise check (``assembly/premises.py``). False unless a map declares it.
    bijective: bool = False

    def __init__(self, in_dim: int, aux_dims: Mapping[str, int] | None = None):
        super().__init__()
        self.in_dim = int(in_dim)
        self.aux_dims = dict(aux_dims or {})

    def psi(self, x: Tensor, aux: AuxDict | None) -> Tensor:  # pragma: no cover - abstract
        raise NotImplementedError

    def jacobian(self, x: Tensor, aux: AuxDict | None) -> Tensor:
        return autodiff.jacobian(lambda z: self.psi(z, aux), x)

    def curvature(self, x: Tensor, xd: Tensor, aux: AuxDict | None, J: Tensor) -> Tensor:
        """J̇ẋ; never forms J̇."""
        return autodiff.second_directional(lambda z: self.psi(z, aux), x, xd)

    def forward(self, x: Tensor, xd: Tensor, aux: AuxDict | None = None):
        """(y, ẏ, J, J̇ẋ) for a batch of parent states."""
        y = self.psi(x, aux)
        J = self.jacobian(x, aux)
        yd = (J @ xd.unsqueeze(-1)).squeeze(-1)
        c = self.curvature(x, xd, aux, J)
        return y, yd, J, c
