"""Weight functions on edges: w(x, aux) > 0 and its gradient w.r.t. the parent configuration x only."""
from __future__ import annotations

from typing import Mapping, Sequence

import torch
from torch import Tensor, nn

from . import autodiff
from .auxstate import AuxDict


class WeightFunction(nn.Module):
    """Base of every weight function.

    ``value(x, aux)`` returns (B,) and must be positive by construction. ``forward`` returns the value
    and ∇_x w (aux held fixed); the default gradient is autodiff, which keeps the graph so training
    reaches the parameters through the h_i terms of pullback*. ``is_constant`` weights skip h_i.
    """

    is_constant = False

    def __init__(self, in_dim: int, aux_dims: Mapping[str, int] | None = None):
        super().__init__()
        self.in_dim = int(in_dim)
        self.aux_dims = dict(aux_dims or {})

    def value(self, x: Tensor, aux: AuxDict | None) -> Tensor:  # pragma: no cover - abstract
        raise NotImplementedError

    def forward(self, x: Tensor, aux: AuxDict | None = None) -> tuple[Tensor, Tensor | None]:
        return self.value(x, aux), autodiff.gradient(lambda z: self.value(z, aux), x)


def aux_features(names: Sequence[str], aux: AuxDict | None, batch: int) -> Tensor | None:
    """Concatenate the named aux tensors into (B, k) features (None when there are none)."""
    if not names:
        return None
    if aux is None:
        raise KeyError(f"aux state {list(names)} is required by a weight function but was not passed")
    parts = []
    for n in names:
        if n not in aux:
            raise KeyError(f"aux state '{n}' is required by a weight function but was not passed")
        parts.append(aux[n].expand(batch, -1))
    return torch.cat(parts, dim=-1)
