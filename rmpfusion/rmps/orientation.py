"""The orientation attractor: a GDS on the error of ``link_axis`` / ``link_orientation``, e = (R a_k − d_k)_k."""

from __future__ import annotations

from pydantic import Field

from ..core.stacking import spread
from ..examples import Example
from ..registry import LEAF_RMPS, numbers_repr
from .gds_leaves import RadialMetricAttractor
from .learnable import LeafParams


@LEAF_RMPS.register(
    "orientation_attractor",
    examples=[Example({}, 3), Example({"gain": 3.0, "eta": 1.5, "w_u": 5.0, "w_l": 1.0, "sigma": 0.4}, 9)],
)
class OrientationAttractor(RadialMetricAttractor):
    """Pulls link axes onto their target directions: Φ = gain·½|e|², G = w(|e|)·I, B = η·G.

    For unit vectors ``½|R a − d|² = 1 − cos θ`` (θ the angle between the axis and its target), so Φ is
    gain·Σ_k (1 − cos θ_k); with the three axes of a frame it is gain·2(1 − cos φ), φ the angle of the rotation
    from the link's orientation to the target's. The error is bounded (|e_k| ≤ 2), so unlike ``goal_attractor`` the
    potential needs no soft normalisation. Its pull on each axis, gain·sin θ_k, vanishes only at the target and
    at the opposite direction (θ = π), an unstable equilibrium every smooth potential on a sphere has.
    The metric rises from w_l to w_u within σ of the target (|e| = 2 sin(θ/2) ≈ θ).
    """

    class_potential_kind = "other"  # on directions: bounded, not radially unbounded (premise 2)

    class Params(LeafParams):
        gain: float = Field(1.0, gt=0, description="potential gain: the pull on an axis is gain·sin θ")
        eta: float = Field(2.0, ge=0, description="damping relative to the metric")
        w_u: float = Field(1.0, gt=0, description="metric scale at the target")
        w_l: float = Field(1.0, gt=0, description="metric scale far from the target")
        sigma: float = Field(
            0.5, gt=0, description="|e| (≈ angle in rad near the target) over which the metric changes from w_l to w_u"
        )

    stack_fields = ("gain", "eta", "w_u", "w_l", "sigma")

    def __init__(self, params: Params, dim: int):
        super().__init__(params, dim)
        self.gain = params.gain

    def potential(self, y):
        return 0.5 * self.gain * (y * y).sum(-1)

    def potential_grad(self, y):
        return spread(self.gain, 1) * y

    def extra_repr(self) -> str:
        return numbers_repr(
            {"dim": self.dim, "gain": self.gain, "eta": self.eta, "w_u": self.w_u, "w_l": self.w_l, "sigma": self.sigma}
        )
