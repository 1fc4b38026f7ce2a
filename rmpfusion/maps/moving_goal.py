"""The coordinates of a moving-goal attractor: the offset to the goal and the goal's velocity.

``moving_offset`` maps x to ``y = (x − g, ġ)`` with the goal ``g`` and its velocity ``ġ`` read from aux (or
constants). Like every map it holds aux fixed in its derivatives (docs/math.md §4): ``J = [I; 0]``, ``J̇ẋ = 0``.
The second half carries ``ġ`` to the leaf, which cannot read aux itself: ``moving_goal_attractor`` damps the
velocity relative to the goal with it (docs/math.md §8, "Moving goals").
"""

from __future__ import annotations

from collections.abc import Mapping

import torch

from ..core.auxstate import AuxOrValue, AuxParam
from ..core.taskmap import TaskMap
from ..examples import AuxInput, Example
from ..registry import TASK_MAPS, Params, numbers_repr


@TASK_MAPS.register(
    "moving_offset",
    examples=[
        Example(
            {"origin": "c", "velocity": "goal_velocity"},
            2,
            scale=3.0,
            aux={"c": AuxInput.normal(2), "goal_velocity": AuxInput.normal(2)},
        ),
        Example({"origin": [0.5, -1.0, 0.2], "velocity": [0.1, 0.0, -0.3]}, 3, scale=3.0),
    ],
)
class MovingOffset(TaskMap):
    """y = (x − origin, velocity): an attractor space with the goal at 0, and the goal's velocity alongside."""

    coordinates = "moving_offset"  # only a leaf that reads (offset, velocity) may sit under it

    class Params(Params):
        origin: AuxOrValue
        velocity: AuxOrValue

    def __init__(self, params: Params, in_dim: int, aux_dims: Mapping[str, int] | None = None):
        super().__init__(in_dim, aux_dims)
        self.origin = AuxParam(params.origin, self.aux_dims, "moving_offset.origin")
        self.velocity = AuxParam(params.velocity, self.aux_dims, "moving_offset.velocity")
        for key, p in (("origin", self.origin), ("velocity", self.velocity)):
            if p.dim != in_dim:
                raise ValueError(f"moving_offset.{key} has dimension {p.dim} but the parent space has {in_dim}")
        self.out_dim = 2 * in_dim

    def psi(self, x, aux):
        v = self.velocity(aux).to(x)
        return torch.cat([x - self.origin(aux), v.expand_as(x)], -1)

    def forward(self, x, xd, aux=None):
        B, n = x.shape
        eye = torch.eye(n, dtype=x.dtype, device=x.device)
        J = torch.cat([eye, torch.zeros_like(eye)], 0).expand(B, 2 * n, n)
        return self.psi(x, aux), torch.cat([xd, torch.zeros_like(xd)], -1), J, x.new_zeros(B, 2 * n)

    def extra_repr(self) -> str:
        return numbers_repr({"in_dim": self.in_dim, "out_dim": self.out_dim})
