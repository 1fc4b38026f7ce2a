"""Neural weight functions: an MLP of the parent configuration and chosen aux features, positive by construction.

∇_x w is computed by forward-mode propagation through the layers alongside the value (the input
dimension is small), so it needs no double backward and stays differentiable in the parameters.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Literal, Mapping

import torch
import torch.nn.functional as F
from pydantic import Field, field_validator, model_validator
from torch import Tensor, nn

from ..core.auxstate import CONSTANT_DTYPE, AuxDict
from ..core.weight import WeightFunction, aux_features
from ..registry import WEIGHTS, Params


def _tanh(z: Tensor) -> tuple[Tensor, Tensor]:
    t = torch.tanh(z)
    return t, 1 - t * t


def _softplus(z: Tensor) -> tuple[Tensor, Tensor]:
    return F.softplus(z), torch.sigmoid(z)


def _sigmoid(z: Tensor) -> tuple[Tensor, Tensor]:
    s = torch.sigmoid(z)
    return s, s * (1 - s)


def _elu(z: Tensor) -> tuple[Tensor, Tensor]:
    return F.elu(z), torch.where(z > 0, torch.ones_like(z), torch.exp(z.clamp(max=0)))


def _silu(z: Tensor) -> tuple[Tensor, Tensor]:
    s = torch.sigmoid(z)
    return z * s, s * (1 + z * (1 - s))


@dataclass(frozen=True)
class Activation:
    """One activation two ways: a layer, for networks evaluated plainly (the unstructured learner), and
    (σ(z), σ'(z)), for networks whose input gradient is propagated forward (weight functions need ∇_x w, so
    only activations smooth everywhere have one)."""

    module: type[nn.Module]
    with_derivative: Callable[[Tensor], tuple[Tensor, Tensor]] | None


#: The activations networks in rmpfusion use, by the name configs give them.
ACTIVATIONS: dict[str, Activation] = {
    "tanh": Activation(nn.Tanh, _tanh),
    "softplus": Activation(nn.Softplus, _softplus),
    "sigmoid": Activation(nn.Sigmoid, _sigmoid),
    "elu": Activation(nn.ELU, _elu),
    "silu": Activation(nn.SiLU, _silu),
    "relu": Activation(nn.ReLU, None),  # a kink at 0: no weight function uses it
}


def hidden_widths(v: list[int]) -> list[int]:
    """Hidden-layer widths are ≥ 1: a layer of width 0 cuts the output off from every input."""
    bad = [w for w in v if w < 1]
    if bad:
        raise ValueError(f"hidden widths must be ≥ 1 (a layer of width {bad[0]} cuts the output off from the inputs, "
                         f"so nothing could be learned); given {list(v)}")
    return v


@WEIGHTS.register("mlp")
class MLPWeight(WeightFunction):
    """w = floor + pos(MLP([x, aux features])) with pos = softplus or exp.

    ``aux`` lists aux names whose values join the input (held fixed in ∇_x w). ``init_bias`` sets the
    output bias so an untrained network starts near a chosen weight.
    """

    class Params(Params):
        hidden: list[int] = Field(default_factory=lambda: [64, 64], description="widths ≥ 1; [] = no hidden layer")
        activation: Literal["tanh", "softplus", "sigmoid", "elu", "silu"] = "tanh"
        positivity: Literal["softplus", "exp"] = "softplus"
        floor: float = Field(1e-3, gt=0, description="lower bound of w: keeps every edge strictly positive")
        aux: list[str] = Field(default_factory=list)
        use_config: bool = Field(True, description="feed the parent configuration to the network")
        init_bias: float | None = Field(None, description="initial w before training, > floor (default: random)")

        @field_validator("hidden")
        @classmethod
        def _widths(cls, v: list[int]) -> list[int]:
            return hidden_widths(v)

        @model_validator(mode="after")
        def _reachable_start(self):
            if self.init_bias is not None and not self.init_bias > self.floor:
                raise ValueError(f"init_bias must be > floor (w = floor + a positive term never reaches floor or "
                                 f"below); given init_bias={self.init_bias}, floor={self.floor}")
            return self

    def __init__(self, params: Params, in_dim: int, aux_dims: Mapping[str, int] | None = None):
        super().__init__(in_dim, aux_dims)
        p = params
        missing = [a for a in p.aux if a not in self.aux_dims]
        if missing:
            raise ValueError(f"mlp.aux names {missing} are not declared (declared aux: {sorted(self.aux_dims)})")
        self.aux_names = list(p.aux)
        self.use_config = p.use_config
        n_in = (in_dim if p.use_config else 0) + sum(self.aux_dims[a] for a in p.aux)
        if n_in == 0:
            raise ValueError("mlp weight has no inputs: set use_config or list aux features")
        sizes = [n_in, *p.hidden, 1]
        # float64 like every constant (init_bias exact; one seed, one network, whatever torch's default dtype)
        self.layers = nn.ModuleList(nn.Linear(a, b, dtype=CONSTANT_DTYPE) for a, b in zip(sizes[:-1], sizes[1:]))
        self.act = ACTIVATIONS[p.activation].with_derivative
        self.activation = p.activation
        self.positivity, self.floor = p.positivity, p.floor
        if p.init_bias is not None:
            target = max(p.init_bias - p.floor, 1e-6)
            b = math.log(target) if p.positivity == "exp" else math.log(math.expm1(target))
            nn.init.zeros_(self.layers[-1].weight)
            nn.init.constant_(self.layers[-1].bias, b)

    def forward(self, x: Tensor, aux: AuxDict | None = None):
        B = x.shape[0]
        feats = aux_features(self.aux_names, aux, B)
        parts = ([x] if self.use_config else []) + ([feats] if feats is not None else [])
        h = torch.cat(parts, dim=-1) if len(parts) > 1 else parts[0]
        # tangent (dh/dx)ᵀ, (B, in_dim, width), seeded only on the configuration inputs: with the width last,
        # each layer maps it by one plain matrix product (no batched copies of the weight matrices)
        W0 = self.layers[0].weight
        z = F.linear(h, W0, self.layers[0].bias)
        dz = W0[:, : self.in_dim].T.unsqueeze(0) if self.use_config else None
        for layer in self.layers[1:]:
            a, da = self.act(z)
            dz = F.linear(da.unsqueeze(1) * dz, layer.weight) if dz is not None else None
            z = layer(a)
        out = z[:, 0]
        if self.positivity == "exp":
            pos = torch.exp(out)
            dpos = pos
        else:
            pos = F.softplus(out)
            dpos = torch.sigmoid(out)
        w = self.floor + pos
        grad = dpos[:, None] * dz[..., 0] if dz is not None else None  # no config input: ∇_x w = 0
        return w, grad

    def value(self, x, aux):
        return self.forward(x, aux)[0]
