"""learner-un: a fully connected network [q, q̇, aux] -> q̈ with no stability or safety structure (paper §4.1),
optionally sized to another learner's parameter count so the comparison is between equal budgets."""

from __future__ import annotations

import math
from collections.abc import Mapping
from itertools import pairwise
from typing import Any, Literal

import torch
from pydantic import Field, field_validator
from torch import Tensor, nn

from .. import registry
from ..core.tree import RMPTree
from ..core.weight import aux_features
from ..registry import LEARNERS
from ..weights.neural import ACTIVATIONS, hidden_widths
from .learner import Learner


@LEARNERS.register("unstructured")
class UnstructuredLearner(Learner["UnstructuredLearner.Params"]):
    """learner-un: a fully connected network [q, q̇, aux] -> q̈ with no stability or safety structure."""

    class Params(registry.Params):  # registry.Params: this class takes its base's name
        hidden: list[int] = Field(
            default_factory=lambda: [64, 64],
            min_length=1,
            description="widths ≥ 1 (with match_parameters_of only the depth counts)",
        )
        activation: Literal["tanh", "relu", "elu", "softplus", "silu"] = "tanh"
        match_parameters_of: str | None = Field(
            None,
            description="another learner's name: hidden widths are chosen so the parameter count is "
            "parameter_ratio × that learner's (depth = len(hidden))",
        )
        parameter_ratio: float = Field(1.0, gt=0)

        @field_validator("hidden")
        @classmethod
        def _widths(cls, v: list[int]) -> list[int]:
            return hidden_widths(v)

    def __init__(
        self,
        params: Params,
        tree_spec: Mapping[str, Any] | None,
        aux_dims: Mapping[str, int],
        dim: int,
        expert: Mapping[str, Any] | None = None,
        target_parameters: int | None = None,
    ):
        super().__init__()
        self.aux_names = sorted(aux_dims)
        n_in = 2 * dim + sum(int(aux_dims[a]) for a in self.aux_names)
        hidden = list(params.hidden)
        if target_parameters is not None:
            hidden = [width_for_parameters(target_parameters, n_in, dim, len(hidden))] * len(hidden)
        elif params.match_parameters_of is not None:
            raise ValueError(
                f"unstructured learner matches the parameters of '{params.match_parameters_of}': "
                "build it through build_learner with the other learners"
            )
        self.hidden = hidden
        sizes = [n_in, *hidden]
        layers: list[nn.Module] = []
        # float64 whatever torch's default dtype: one seed draws one set of initial weights
        for a, b in pairwise(sizes):
            layers += [nn.Linear(a, b, dtype=torch.float64), ACTIVATIONS[params.activation].module()]
        layers.append(nn.Linear(sizes[-1], dim, dtype=torch.float64))
        self.net = nn.Sequential(*layers)
        self.params = params
        self.dim = dim

    @classmethod
    def from_params(
        cls,
        params: Params,
        tree_spec: Mapping[str, Any] | None,
        aux_dims: Mapping[str, int],
        dim: int,
        expert: Mapping[str, Any] | None = None,
        built: Mapping[str, Learner] | None = None,
        where: str = "learners",
    ) -> UnstructuredLearner:
        """``match_parameters_of`` is resolved against ``built``: that learner's count × ``parameter_ratio``."""
        ref, target = params.match_parameters_of, None
        if ref is not None:
            if not built or ref not in built:
                raise ValueError(
                    f"{where}.match_parameters_of: learner '{ref}' is not built (known: {sorted(built or {})})"
                )
            target = round(built[ref].num_parameters() * params.parameter_ratio)
        return cls(params, tree_spec, aux_dims, dim, expert=expert, target_parameters=target)

    @property
    def tree(self) -> RMPTree | None:
        """None: the network has no tree structure (and so no Lyapunov function to monitor)."""
        return None

    def policy(self, q: Tensor, qd: Tensor, aux: Mapping[str, Tensor] | None = None) -> Tensor:
        return self.forward(q, qd, aux)

    def forward(self, q: Tensor, qd: Tensor, aux: Mapping[str, Tensor] | None = None) -> Tensor:
        feats = aux_features(self.aux_names, aux, q.shape[0])
        x = torch.cat([q, qd] + ([feats] if feats is not None else []), dim=-1)
        return self.net(x)

    def describe(self) -> dict[str, Any]:
        """The hidden widths, which ``match_parameters_of`` chooses at build time."""
        return {"hidden": list(self.hidden)}

    def compile(self) -> UnstructuredLearner:  # type: ignore[override]  # as Learner.compile
        """Nothing to do: there is no tree to compile, and a small MLP gains little from torch.compile."""
        return self


def mlp_parameters(n_in: int, n_out: int, widths: list[int]) -> int:
    sizes = [n_in, *widths, n_out]
    return sum(a * b + b for a, b in pairwise(sizes))


def width_for_parameters(target: int, n_in: int, n_out: int, depth: int) -> int:
    """The hidden width (same for all ``depth`` layers) whose MLP parameter count is closest to ``target``."""
    if depth < 1:
        raise ValueError("depth must be at least 1")
    # count(w) = (depth-1)·w² + (n_in + n_out + depth)·w + n_out
    a, b, c = depth - 1, n_in + n_out + depth, n_out - target
    w = -c / b if a == 0 else (-b + math.sqrt(b * b - 4 * a * c)) / (2 * a)
    cands = {max(1, math.floor(w)), max(1, math.ceil(w))}
    return min(cands, key=lambda k: (abs(mlp_parameters(n_in, n_out, [k] * depth) - target), k))
