"""Task maps learned from demonstrations, and the fixed normalisation in front of them.

``diffeomorphism``: y = ψ(x) a composition of affine coupling layers (Dinh et al., "Density estimation using
Real NVP"): each layer keeps one part x_a of the coordinates and maps the other part as
x_b ↦ x_b ⊙ exp(s(x_a)) + t(x_a), with s, t small networks of smooth activations. Each layer is a bijection of
ℝⁿ onto ℝⁿ for any parameters (for fixed x_a it is an affine bijection of x_b, and exp(s) > 0), smooth, with a
smooth inverse, so ψ is a diffeomorphism onto ℝⁿ by construction: an attractor at ψ(goal) in y has ψ⁻¹ of its
single equilibrium as the only equilibrium in x (docs/math.md, "Learned task maps"). ``s`` is bounded by
``scale_bound``·tanh so no layer stretches a direction by more than exp(scale_bound). With ``features: m`` the
networks read m random Fourier features sin(W x_a + b) of the kept coordinates instead of x_a itself (W ~ N(0, 1/σ²)
and b ~ U(0, 2π) drawn once and kept fixed: Rahimi and Recht, "Random features for large-scale kernel machines"),
the coupling networks of Euclideanizing flows (Rana et al. 2020): detail on the scale σ that a small tanh network
only reaches after long training. y, J and J̇ẋ come out of one pass of a second-order jet (``core/jet.py``); the
tests hold them to the autodiff of ``TaskMap``.

``normalize``: y = (x − shift) / scale with constants: the leaves' gains are tuned for coordinates of order one,
so demonstrations in other scales (a handwriting tablet's centimetres, a tabletop's decimetres) are brought to
that scale before any leaf or learned map sees them.
"""

from __future__ import annotations

import itertools
from collections.abc import Mapping
from typing import Literal

import torch
from pydantic import Field, field_validator
from torch import Tensor, nn

from ..core.auxstate import CONSTANT_DTYPE, AuxOrValue, AuxParam, constant
from ..core.jet import SMOOTH, Jet, exp3, sin3, tanh3
from ..core.taskmap import TaskMap
from ..examples import AuxInput, Example
from ..registry import TASK_MAPS, Params, numbers_repr


def coupling_masks(dim: int, layers: int) -> list[Tensor]:
    """Which coordinates each layer keeps (True) and transforms (False): the first ⌊n/2⌋ and then the rest,
    alternating, so that after two layers every coordinate has been transformed."""
    first = torch.arange(dim) < dim // 2
    return [first if k % 2 == 0 else ~first for k in range(layers)]


class RandomFeatures(nn.Module):
    """sin(W a + b) with W (m, k) ~ N(0, 1/σ²) and b ~ U(0, 2π) fixed at construction: m random Fourier features of a
    k-vector, whose inner products approximate a Gaussian kernel of width σ. Buffers, so a checkpoint keeps them."""

    weight: Tensor
    bias: Tensor

    def __init__(self, inputs: int, count: int, scale: float):
        super().__init__()
        self.count = count
        self.register_buffer("weight", torch.randn(count, inputs, dtype=CONSTANT_DTYPE) / scale)
        self.register_buffer("bias", 2 * torch.pi * torch.rand(count, dtype=CONSTANT_DTYPE))

    def forward(self, a: Jet) -> Jet:
        return a.affine(self.weight, self.bias).pointwise(sin3)

    def extra_repr(self) -> str:
        return numbers_repr({"inputs": self.weight.shape[1], "count": self.count})


class Coupling(nn.Module):
    """x_b ↦ x_b ⊙ exp(s(x_a)) + t(x_a) on the coordinates ``~keep``, x_a = x[keep] unchanged; evaluated on a
    ``Jet`` (``core/jet.py``), so y, J and J̇ẋ come out of one pass."""

    kept: Tensor  # buffers (long): the coordinates kept,
    moved: Tensor  # those transformed,
    order: Tensor  # and where [kept, moved] go back to

    def __init__(
        self,
        keep: Tensor,
        hidden: tuple[int, ...],
        activation: str,
        scale_bound: float,
        features: RandomFeatures | None = None,
    ):
        super().__init__()
        self.register_buffer("kept", keep.nonzero().flatten(), persistent=False)
        self.register_buffer("moved", (~keep).nonzero().flatten(), persistent=False)
        self.register_buffer("order", torch.cat([self.kept, self.moved]).argsort(), persistent=False)
        self.features = features
        widths = (len(self.kept) if features is None else features.count, *hidden)
        self.hidden = nn.ModuleList(nn.Linear(a, b, dtype=CONSTANT_DTYPE) for a, b in itertools.pairwise(widths))
        self.head = nn.Linear(widths[-1], 2 * len(self.moved), dtype=CONSTANT_DTYPE)
        self.activation = SMOOTH[activation]
        self.scale_bound = scale_bound

    def _bounded(self, z: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """β·tanh(z/β) and its two derivatives: the log-scale, |s| < β."""
        t, d, dd = tanh3(z / self.scale_bound)
        return self.scale_bound * t, d, dd / self.scale_bound

    def scale_shift(self, a: Jet) -> tuple[Jet, Jet]:
        """(s, t) of the kept coordinates: the log-scale and the shift of the moved ones."""
        h = a if self.features is None else self.features(a)
        for layer in self.hidden:
            assert isinstance(layer, nn.Linear)
            h = h.affine(layer.weight, layer.bias).pointwise(self.activation)
        out = h.affine(self.head.weight, self.head.bias)
        n = len(self.moved)
        s = out.take(torch.arange(n, device=out.value.device)).pointwise(self._bounded)
        return s, out.take(torch.arange(n, 2 * n, device=out.value.device))

    def forward(self, x: Jet) -> Jet:
        a = x.take(self.kept)
        s, t = self.scale_shift(a)
        b = x.take(self.moved) * s.pointwise(exp3) + t
        return Jet.cat([a, b], self.order)

    def inverse(self, y: Tensor) -> Tensor:
        a = y[..., self.kept]
        zero = torch.zeros(*a.shape, 1, dtype=a.dtype, device=a.device)
        s, t = self.scale_shift(Jet(a, zero, torch.zeros_like(a), torch.zeros_like(a)))
        b = (y[..., self.moved] - t.value) * torch.exp(-s.value)
        return torch.cat([a, b], -1)[..., self.order]

    def extra_repr(self) -> str:
        return numbers_repr({"kept": self.kept, "moved": self.moved, "scale_bound": self.scale_bound})


@TASK_MAPS.register(
    "diffeomorphism",
    examples=[
        Example({}, 2, scale=2.0),
        Example(
            {"layers": 3, "hidden": [8], "activation": "softplus", "init_std": 0.5, "origin": "c"},
            2,
            scale=2.0,
            aux={"c": AuxInput.normal(2)},
        ),
        Example(
            {"layers": 2, "hidden": [6, 6], "activation": "silu", "init_std": 0.4, "origin": [0.1, 0.2, 0.3]},
            3,
            scale=2.0,
        ),
        Example({"layers": 4, "hidden": [8], "features": 16, "feature_scale": 0.5, "init_std": 0.3}, 2, scale=2.0),
    ],
)
class Diffeomorphism(TaskMap):
    """y = ψ(x) − ψ(origin): a learnable diffeomorphism of ℝⁿ onto ℝⁿ (coupling layers), shifted so that
    ``origin`` (a goal: constant or aux) maps to 0, where an attractor leaf puts its equilibrium; ``inverse``
    gives x back from y."""

    bijective = True  # coupling layers: a bijection of ℝⁿ for any parameters (docs/math.md §12, premise 1)

    class Params(Params):
        layers: int = Field(4, ge=1, description="coupling layers (alternating halves: ≥ 2 moves every coordinate)")
        hidden: tuple[int, ...] = Field((32, 32), description="hidden widths of each layer's scale/shift network")
        activation: Literal["tanh", "softplus", "silu"] = Field(
            "tanh", description="smooth activations only: J̇ẋ needs the networks' second derivatives"
        )
        scale_bound: float = Field(2.0, gt=0, description="|log-scale| of a layer stays below this (stretch ≤ e^bound)")
        origin: AuxOrValue | None = Field(None, description="the point mapped to 0 (a goal); null: ψ itself")
        features: int | None = Field(
            None,
            ge=1,
            description="random Fourier features the layers' networks read (null: the kept coordinates themselves)",
        )
        feature_scale: float = Field(
            1.0, gt=0, description="σ of the features: the length scale, in the map's input units, they resolve"
        )
        init_std: float = Field(
            0.1,
            ge=0,
            description="std of the output layers' initial weights (0: the identity "
            "map at initialisation; learner-0 is this random map)",
        )

        @field_validator("hidden")
        @classmethod
        def _positive(cls, v: tuple[int, ...]):
            if not v or any(h < 1 for h in v):
                raise ValueError(f"hidden must list at least one width, each ≥ 1; given {list(v)}")
            return v

    def __init__(self, params: Params, in_dim: int, aux_dims: Mapping[str, int] | None = None):
        super().__init__(in_dim, aux_dims)
        if in_dim < 2:
            raise ValueError(
                f"diffeomorphism needs a parent space of dimension ≥ 2 (a coupling layer keeps some "
                f"coordinates to transform the others); the parent has {in_dim}"
            )
        self.out_dim = in_dim
        couplings = [
            Coupling(keep, tuple(params.hidden), params.activation, params.scale_bound, self._features(keep, params))
            for keep in coupling_masks(in_dim, params.layers)
        ]
        self.layers = nn.ModuleList(couplings)
        self.origin = (
            AuxParam(params.origin, self.aux_dims, "diffeomorphism.origin") if params.origin is not None else None
        )
        if self.origin is not None and self.origin.dim != in_dim:
            raise ValueError(f"diffeomorphism.origin has dimension {self.origin.dim} but the parent space has {in_dim}")
        with torch.no_grad():
            for layer in couplings:
                nn.init.normal_(layer.head.weight, std=params.init_std)
                nn.init.normal_(layer.head.bias, std=params.init_std)

    @staticmethod
    def _features(keep: Tensor, params: Params) -> RandomFeatures | None:
        """Each layer's own random features of its kept coordinates, or none."""
        if params.features is None:
            return None
        return RandomFeatures(int(keep.sum()), params.features, params.feature_scale)

    def flow(self, x: Jet) -> Jet:
        """ψ on a jet: the coupling layers in order."""
        for layer in self.layers:
            x = layer(x)
        return x

    def _origin_image(self, x: Tensor, aux) -> Tensor:
        assert self.origin is not None, "only a map given an origin shifts by its image"
        origin = self.origin(aux).to(x).expand_as(x)
        return self.flow(Jet.seed(origin, torch.zeros_like(origin))).value

    def forward(self, x: Tensor, xd: Tensor, aux=None):
        out = self.flow(Jet.seed(x, xd))
        y = out.value if self.origin is None else out.value - self._origin_image(x, aux)
        return y, out.vel, out.jac, out.curv

    def psi(self, x: Tensor, aux) -> Tensor:
        return self.forward(x, torch.zeros_like(x), aux)[0]

    def jacobian(self, x: Tensor, aux) -> Tensor:
        return self.forward(x, torch.zeros_like(x), aux)[2]

    def curvature(self, x: Tensor, xd: Tensor, aux, J: Tensor) -> Tensor:
        return self.forward(x, xd, aux)[3]

    def inverse(self, y: Tensor, aux=None) -> Tensor:
        """x with psi(x, aux) = y."""
        if self.origin is not None:
            y = y + self._origin_image(y, aux)
        for layer in reversed(self.layers):
            assert isinstance(layer, Coupling)
            y = layer.inverse(y)
        return y

    def extra_repr(self) -> str:
        return numbers_repr({"in_dim": self.in_dim, "out_dim": self.out_dim, "layers": len(self.layers)})


@TASK_MAPS.register(
    "normalize", examples=[Example({"shift": [0.1, -0.2], "scale": [0.05, 2.0]}, 2), Example({"scale": 40.0}, 3)]
)
class Normalize(TaskMap):
    """y = (x − shift) / scale: constants (a number for every coordinate, or one per coordinate)."""

    bijective = True  # every scale > 0

    shift: Tensor  # buffers, one number per coordinate
    scale: Tensor

    class Params(Params):
        shift: float | tuple[float, ...] = Field(0.0, description="subtracted first (e.g. the demonstrations' goal)")
        scale: float | tuple[float, ...] = Field(1.0, description="then divided by (e.g. the demonstrations' extent)")

        @field_validator("scale")
        @classmethod
        def _positive(cls, v):
            if any(s <= 0 for s in ((v,) if isinstance(v, (int, float)) else v)):
                raise ValueError(f"scale must be > 0 in every coordinate (the map divides by it); given {v!r}")
            return v

    def __init__(self, params: Params, in_dim: int, aux_dims: Mapping[str, int] | None = None):
        super().__init__(in_dim, aux_dims)
        self.out_dim = in_dim
        for name in ("shift", "scale"):
            v = getattr(params, name)
            v = (float(v),) * in_dim if isinstance(v, (int, float)) else tuple(v)
            if len(v) != in_dim:
                raise ValueError(f"normalize.{name} has {len(v)} entries but the parent space has {in_dim}")
            self.register_buffer(name, constant(v))

    def psi(self, x: Tensor, aux) -> Tensor:
        return (x - self.shift.to(x)) / self.scale.to(x)

    def forward(self, x: Tensor, xd: Tensor, aux=None):
        inv = 1.0 / self.scale.to(x)
        J = torch.diag_embed(inv.expand_as(x))
        return self.psi(x, aux), xd * inv, J, torch.zeros_like(x)

    def extra_repr(self) -> str:
        return numbers_repr({"in_dim": self.in_dim, "out_dim": self.out_dim, "shift": self.shift, "scale": self.scale})
