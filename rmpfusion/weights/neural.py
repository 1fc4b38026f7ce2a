"""Neural weight functions: an MLP of the parent configuration and chosen aux features, positive by construction.

∇_x w is computed by forward-mode propagation through the layers alongside the value (the input
dimension is small), so it needs no double backward and stays differentiable in the parameters.

The math is written for D networks of one architecture at once (``mlp_with_gradient``: one batched matrix
product per layer), which is how a tree evaluates all its weight networks of one kind (``core/stacking.py``);
a single network is the case D = 1.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Literal

import torch
import torch.nn.functional as F
from pydantic import Field, field_validator, model_validator
from torch import Tensor, nn

from ..core.auxstate import CONSTANT_DTYPE, AuxDict, AuxParam, StackedAux
from ..core.stacking import shallow_clone
from ..core.weight import WeightFunction, aux_features
from ..examples import AuxInput, Example
from ..registry import WEIGHTS, Params, numbers_repr


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
        raise ValueError(
            f"hidden widths must be ≥ 1 (a layer of width {bad[0]} cuts the output off from the inputs, "
            f"so nothing could be learned); given {list(v)}"
        )
    return v


@WEIGHTS.register(
    "mlp",
    examples=[
        Example(
            {"hidden": [16, 16], "aux": ["goal", "obstacle_center", "obstacle_radius"]},
            2,
            scale=2.0,
            aux={
                "goal": AuxInput.normal(2),
                "obstacle_center": AuxInput.normal(2),
                "obstacle_radius": AuxInput.radius(),
            },
        ),
        Example({"hidden": [8], "activation": "softplus", "positivity": "exp"}, 2, scale=2.0),
        Example({"hidden": [8, 8, 8], "activation": "elu"}, 2, scale=2.0),
        Example({"hidden": [8], "activation": "silu", "aux": ["goal"]}, 2, scale=2.0, aux={"goal": AuxInput.normal(2)}),
        Example({"hidden": [8], "activation": "sigmoid"}, 2, scale=2.0),
    ],
)
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
                raise ValueError(
                    f"init_bias must be > floor (w = floor + a positive term never reaches floor or "
                    f"below); given init_bias={self.init_bias}, floor={self.floor}"
                )
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
        linears = [nn.Linear(a, b, dtype=CONSTANT_DTYPE) for a, b in itertools.pairwise(sizes)]
        self.layers = nn.ModuleList(linears)
        self.act = ACTIVATIONS[p.activation].with_derivative
        self.activation = p.activation
        self.positivity, self.floor = p.positivity, p.floor
        if p.init_bias is not None:
            target = max(p.init_bias - p.floor, 1e-6)
            b = math.log(target) if p.positivity == "exp" else math.log(math.expm1(target))
            nn.init.zeros_(linears[-1].weight)
            nn.init.constant_(linears[-1].bias, b)

    def stack_key(self):
        """Networks of one architecture reading inputs of the same sizes evaluate as one batch."""
        dims = tuple(self.aux_dims[a] for a in self.aux_names)
        sizes = tuple((l.in_features, l.out_features) for l in self.layers)
        return (MLPWeight, self.in_dim, dims, sizes, self.activation, self.positivity, self.floor, self.use_config)

    def with_bind(self, bind: Mapping[str, str]) -> MLPWeight:
        if not bind:
            return self
        view = shallow_clone(self)
        view.aux_names = [bind.get(a, a) for a in self.aux_names]
        return view

    @classmethod
    def stacked(cls, members, like: Tensor) -> StackedMLP:
        return StackedMLP(members)

    def linears(self) -> list[nn.Linear]:
        """The network's layers, input first (every layer is an ``nn.Linear``)."""
        return [l for l in self.layers if isinstance(l, nn.Linear)]

    def layer_parameters(self) -> list[tuple[Tensor, Tensor]]:
        """Each layer's (W (1, out, in), b (1, out)): this network as a stack of one."""
        return [(l.weight.unsqueeze(0), l.bias.unsqueeze(0)) for l in self.linears()]

    def forward(self, x: Tensor, aux: AuxDict | None = None):
        lead = x.shape[:-1]  # (B,), or (1, B) as a group of one
        feats = aux_features(self.aux_names, aux, lead)
        parts = ([x] if self.use_config else []) + ([feats] if feats is not None else [])
        h = torch.cat(parts, dim=-1) if len(parts) > 1 else parts[0]
        w, grad = mlp_with_gradient(
            self.layer_parameters(),
            h.reshape(1, -1, h.shape[-1]),
            self.in_dim if self.use_config else 0,
            self.act,
            self.positivity,
            self.floor,
        )
        return w.reshape(lead), None if grad is None else grad.reshape(*lead, -1)

    @property
    def reads(self) -> str:  # type: ignore[override]
        """Reads "aux" only when the configuration is not among the network's inputs (``use_config: false``)."""
        return "configuration" if self.use_config else "aux"

    def value(self, x, aux):
        return self.forward(x, aux)[0]

    def extra_repr(self) -> str:
        return numbers_repr(
            {
                "in_dim": self.in_dim,
                "use_config": self.use_config,
                "aux": self.aux_names,
                "hidden": [l.out_features for l in self.linears()[:-1]],
                "activation": self.activation,
                "positivity": self.positivity,
                "floor": self.floor,
            }
        )


def mlp_with_gradient(
    layers: list[tuple[Tensor, Tensor]], h: Tensor, n_config: int, act, positivity: str, floor: float
) -> tuple[Tensor, Tensor | None]:
    """w = floor + pos(MLP(h)) and ∇w with respect to the first ``n_config`` inputs, for D networks at once.

    ``layers``: per layer (W (D, out, in), b (D, out)); ``h``: (D, N, in), network d's inputs. The tangent
    (dh/dx)ᵀ is carried forward as (D, N, n_config, width), seeded by the first layer's configuration columns, so
    each layer maps it by one batched matrix product (no per-sample copies of the weights). Returns w (D, N) and
    ∇w (D, N, n_config) (None without configuration inputs)."""
    (W0, b0), rest = layers[0], layers[1:]
    D, N = h.shape[0], h.shape[1]
    z = torch.baddbmm(b0.unsqueeze(1), h, W0.transpose(1, 2))
    dz = W0[:, :, :n_config].transpose(1, 2).unsqueeze(1) if n_config else None  # (D, 1, n_config, width)
    for W, b in rest:
        a, da = act(z)
        if dz is not None:
            t = da.unsqueeze(2) * dz  # (D, N, n_config, width)
            dz = torch.bmm(t.reshape(D, N * n_config, -1), W.transpose(1, 2)).reshape(D, N, n_config, -1)
        z = torch.baddbmm(b.unsqueeze(1), a, W.transpose(1, 2))
    out = z[..., 0]
    if positivity == "exp":
        pos = torch.exp(out)
        dpos = pos
    else:
        pos = F.softplus(out)
        dpos = torch.sigmoid(out)
    grad = dpos[..., None] * dz[..., 0] if dz is not None else None
    return floor + pos, grad


class StackedMLP(nn.Module):
    """Weight networks of one architecture evaluated as one batch: the group's edges in member order, the edges of
    one network contiguous and every network used equally often (the tree plans them so), each edge reading its
    own aux entries. Parameters are read from the members at every call, so gradients reach each network."""

    networks: list[MLPWeight]  # the distinct networks, in member order (not submodules: the members own them)

    def __init__(self, members):
        super().__init__()
        first = members[0]
        distinct = list({id(m.layers): m for m in members}.values())
        if len(members) % len(distinct) or any(
            id(m.layers) != id(distinct[i // (len(members) // len(distinct))].layers) for i, m in enumerate(members)
        ):
            raise ValueError("stacked weight networks must be contiguous and equally often used")
        object.__setattr__(self, "networks", distinct)  # the members own the parameters
        self.size, self.in_dim, self.use_config = len(members), first.in_dim, first.use_config
        self.act, self.positivity, self.floor = first.act, first.positivity, first.floor
        self.features = nn.ModuleList(
            StackedAux([AuxParam(m.aux_names[k], m.aux_dims, "mlp.aux") for m in members])
            for k in range(len(first.aux_names))
        )

    def forward(self, x: Tensor, aux: AuxDict | None = None):
        G, B = self.size, x.shape[1]
        parts = [x.expand(G, B, -1)] if self.use_config else []
        parts += [f(aux).expand(G, B, -1) for f in self.features]
        h = torch.cat(parts, -1) if len(parts) > 1 else parts[0]
        D = len(self.networks)
        layers = [
            (torch.stack([l.weight for l in same_layer]), torch.stack([l.bias for l in same_layer]))
            for same_layer in zip(*(net.linears() for net in self.networks))
        ]
        w, grad = mlp_with_gradient(
            layers,
            h.reshape(D, -1, h.shape[-1]),
            self.in_dim if self.use_config else 0,
            self.act,
            self.positivity,
            self.floor,
        )
        return w.reshape(G, B), None if grad is None else grad.reshape(G, B, -1)
