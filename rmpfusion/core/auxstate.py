"""Parameters that are either constants or named auxiliary state (docs/math.md §10).

A YAML value like ``center: [0, 0]`` is a constant; ``center: obstacle_center`` names a per-sample aux
tensor of shape (B, k) passed at call time. Both resolve to something broadcastable against (B, k).

Constants are built in float64 (``constant``), the precision of the Python numbers they come from, whatever
torch's default dtype is; ``build_tree`` then casts the whole tree to its dtype (float64 unless asked), so a
YAML number is rounded at most once, to the dtype the tree computes in.
"""
from __future__ import annotations

from typing import Mapping, Sequence, Union

import torch
from torch import Tensor, nn

AuxOrValue = Union[str, float, Sequence[float]]
AuxDict = Mapping[str, Tensor]

CONSTANT_DTYPE = torch.float64  # what every registered class builds its constants in (build_tree casts after)


def constant(value) -> Tensor:
    """A Python number, or nested lists of them, as an exact float64 tensor: the one way a registered map, leaf
    or weight turns a parameter into a tensor (a buffer the tree's ``.to(dtype)`` then casts)."""
    return torch.as_tensor(value, dtype=CONSTANT_DTYPE)


class AuxParam(nn.Module):
    """A constant buffer or a reference to an aux entry; ``dim`` is known at build time."""

    def __init__(self, value: AuxOrValue, aux_dims: Mapping[str, int], what: str):
        super().__init__()
        if isinstance(value, str):
            if value not in aux_dims:
                known = ", ".join(sorted(aux_dims)) or "none declared"
                raise ValueError(f"{what}: aux name '{value}' is not declared (declared aux: {known})")
            self.name: str | None = value
            self.dim = int(aux_dims[value])
            self.register_buffer("const", None)
        else:
            t = constant(value).reshape(-1)
            self.name = None
            self.dim = t.numel()
            self.register_buffer("const", t)

    def forward(self, aux: AuxDict | None) -> Tensor:
        """(B, k) for aux, (k,) for a constant: both broadcast against a (B, k) coordinate."""
        if self.name is None:
            return self.const
        if aux is None or self.name not in aux:
            raise KeyError(f"aux state '{self.name}' is required by this tree but was not passed")
        return aux[self.name]

    def extra_repr(self) -> str:
        return f"aux={self.name!r}" if self.name else f"const={self.const.tolist()}"
