"""A linear spring-damper as a leaf RMP: importing this module registers it as ``spring``.

rmpfusion imports it on the first registry lookup because pyproject.toml names it under the
``rmpfusion.plugins`` entry-point group; the decorator is the one rmpfusion's built-ins use.

The plugin ships its own derivative checks: the ``examples`` of its register call are the configurations
rmpfusion's finite-difference tests (tests/test_registry_derivatives.py) build it with, as they do every built-in
(its M and f against the GDS definitions, its analytic curvature against autodiff). A plugin entry without
examples fails those tests, naming itself.
"""

from __future__ import annotations

import torch
from pydantic import Field

from rmpfusion.core.gds import GDS
from rmpfusion.examples import Example
from rmpfusion.registry import LEAF_RMPS, Params


@LEAF_RMPS.register("spring", examples=[Example({"gain": 3.0, "eta": 0.5, "w": 2.0}, dim=2)])
class Spring(GDS):
    """Φ = ½·gain·|y|², G = w·I, B = eta·w·I: a GDS with a constant metric, so its curvature terms vanish."""

    class Params(Params):
        gain: float = Field(1.0, gt=0, description="spring stiffness")
        eta: float = Field(2.0, ge=0, description="damping relative to the metric")
        w: float = Field(1.0, gt=0, description="metric scale (importance) of this leaf")

    def __init__(self, params: Params, dim: int):
        super().__init__(dim)
        self.gain, self.eta, self.w = params.gain, params.eta, params.w

    def _eye(self, y):
        return torch.eye(y.shape[-1], dtype=y.dtype, device=y.device).expand(y.shape[0], -1, -1)

    def metric(self, y, yd):
        return self.w * self._eye(y)

    def damping(self, y, yd):
        return self.eta * self.w * self._eye(y)

    def potential(self, y):
        return 0.5 * self.gain * (y * y).sum(-1)

    def potential_grad(self, y):
        return self.gain * y

    def curvature(self, y, yd):
        return torch.zeros_like(self._eye(y)), torch.zeros_like(yd)
