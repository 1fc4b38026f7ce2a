"""Learners for behavior cloning: learner-rmp (the expert's tree with neural weight functions) and
learner-un (an unstructured MLP from state and aux to acceleration), registered in ``LEARNERS``.

Both map (q, q̇, aux) -> q̈ so training and evaluation treat them alike; only learner-rmp also exposes
the tree's TreeOutput (``policy``), which is what lets rollouts monitor its Lyapunov function.
"""
from __future__ import annotations

import math
from typing import Any, Literal, Mapping

import torch
from pydantic import Field
from torch import Tensor, nn

from ..build.errors import ConfigError, Issue
from ..build.tree import build_tree
from ..core.tree import RMPTree
from ..core.weight import aux_features
from ..registry import LEARNERS, Params
from ..build.weighting import expand_aux, tree_with_weights

#: Leaf types that only condition or damp the root; learning a weight on them adds nothing the expert has.
REGULARISER_LEAVES = frozenset({"identity_metric", "damper", "rmpflow_damper"})


def _default_weight() -> dict:
    return {"type": "mlp", "hidden": [32, 32], "activation": "tanh", "aux": "all"}


@LEARNERS.register("rmp")
class RMPLearner(nn.Module):
    """learner-rmp: the given tree with a (fresh, randomly initialised) neural weight on each learned edge."""

    has_lyapunov = True

    class Params(Params):
        weights: dict[str, Any] = Field(default_factory=_default_weight,
                                        description="weight spec put on every learned edge; aux: all = every aux input")
        edges: list[str] | None = Field(None, description="edges to learn; default: those the expert weights, "
                                                          "else every edge except regulariser leaves")
        edge_weights: dict[str, dict[str, Any]] = Field(
            default_factory=dict, description="per-edge keys merged over `weights`, e.g. "
                                              "{obstacle1: {aux: [obstacle1_center, obstacle1_radius]}}")

    def __init__(self, params: Params, tree_spec: Mapping[str, Any], aux_dims: Mapping[str, int], dim: int,
                 expert: Mapping[str, Any] | None = None):
        super().__init__()
        self.params = params
        edges = list(params.edges) if params.edges is not None else self.default_edges(tree_spec, expert)
        stray = [e for e in params.edge_weights if e not in edges]
        if stray:
            raise ConfigError([Issue(f"learners.rmp.edge_weights.{e}",
                                     f"'{e}' is not a learned edge; learned edges: {', '.join(edges)} "
                                     "(add it to learners.rmp.edges or remove the entry)") for e in stray])
        per_edge = {e: expand_aux({**params.weights, **params.edge_weights.get(e, {})}, aux_dims) for e in edges}
        spec = tree_with_weights(tree_spec, per_edge, where="learners.rmp.edges")
        self.edges = edges
        self.tree: RMPTree = build_tree(spec, aux_dims=dict(aux_dims))
        if self.tree.dim != dim:
            raise ValueError(f"the tree's root has dimension {self.tree.dim} but the environment has {dim}")

    @staticmethod
    def default_edges(tree_spec: Mapping[str, Any], expert: Mapping[str, Any] | None) -> list[str]:
        nodes = tree_spec["nodes"]
        if expert:
            return [n for n in nodes if n in expert]
        return [n for n, nd in nodes.items()
                if not ((nd.get("rmp") or {}).get("type") in REGULARISER_LEAVES)]

    def policy(self, q: Tensor, qd: Tensor, aux: Mapping[str, Tensor] | None = None):
        """The full TreeOutput, so rollouts can record V_r and q̇ᵀBq̇."""
        return self.tree(q, qd, aux)

    def forward(self, q: Tensor, qd: Tensor, aux: Mapping[str, Tensor] | None = None) -> Tensor:
        return self.tree(q, qd, aux).qdd

    def num_parameters(self) -> int:
        return sum(p.numel() for p in self.parameters() if p.requires_grad)


_ACTS = {"tanh": nn.Tanh, "relu": nn.ReLU, "elu": nn.ELU, "softplus": nn.Softplus, "silu": nn.SiLU}


@LEARNERS.register("unstructured")
class UnstructuredLearner(nn.Module):
    """learner-un: a fully connected network [q, q̇, aux] -> q̈ with no stability or safety structure."""

    has_lyapunov = False

    class Params(Params):
        hidden: list[int] = Field(default_factory=lambda: [64, 64], min_length=1)
        activation: Literal["tanh", "relu", "elu", "softplus", "silu"] = "tanh"
        match_parameters_of: str | None = Field(
            None, description="another learner's name: hidden widths are chosen so the parameter count is "
                              "parameter_ratio × that learner's (depth = len(hidden))")
        parameter_ratio: float = Field(1.0, gt=0)

    def __init__(self, params: Params, tree_spec: Mapping[str, Any] | None, aux_dims: Mapping[str, int], dim: int,
                 expert: Mapping[str, Any] | None = None, target_parameters: int | None = None):
        super().__init__()
        self.aux_names = sorted(aux_dims)
        n_in = 2 * dim + sum(int(aux_dims[a]) for a in self.aux_names)
        hidden = list(params.hidden)
        if target_parameters is not None:
            hidden = [width_for_parameters(target_parameters, n_in, dim, len(hidden))] * len(hidden)
        elif params.match_parameters_of is not None:
            raise ValueError(f"unstructured learner matches the parameters of '{params.match_parameters_of}': "
                             "build it through build_learner with the other learners")
        self.hidden = hidden
        sizes = [n_in, *hidden]
        layers: list[nn.Module] = []
        for a, b in zip(sizes[:-1], sizes[1:]):
            layers += [nn.Linear(a, b), _ACTS[params.activation]()]
        layers.append(nn.Linear(sizes[-1], dim))
        self.net = nn.Sequential(*layers)
        self.params = params
        self.dim = dim

    def policy(self, q: Tensor, qd: Tensor, aux: Mapping[str, Tensor] | None = None) -> Tensor:
        return self.forward(q, qd, aux)

    def forward(self, q: Tensor, qd: Tensor, aux: Mapping[str, Tensor] | None = None) -> Tensor:
        feats = aux_features(self.aux_names, aux, q.shape[0])
        x = torch.cat([q, qd] + ([feats] if feats is not None else []), dim=-1)
        return self.net(x)

    def num_parameters(self) -> int:
        return sum(p.numel() for p in self.parameters() if p.requires_grad)


def mlp_parameters(n_in: int, n_out: int, widths: list[int]) -> int:
    sizes = [n_in, *widths, n_out]
    return sum(a * b + b for a, b in zip(sizes[:-1], sizes[1:]))


def width_for_parameters(target: int, n_in: int, n_out: int, depth: int) -> int:
    """The hidden width (same for all ``depth`` layers) whose MLP parameter count is closest to ``target``."""
    if depth < 1:
        raise ValueError("depth must be at least 1")
    # count(w) = (depth-1)·w² + (n_in + n_out + depth)·w + n_out
    a, b, c = depth - 1, n_in + n_out + depth, n_out - target
    w = -c / b if a == 0 else (-b + math.sqrt(b * b - 4 * a * c)) / (2 * a)
    cands = {max(1, math.floor(w)), max(1, math.ceil(w))}
    return min(cands, key=lambda k: (abs(mlp_parameters(n_in, n_out, [k] * depth) - target), k))


def build_learner(block: Mapping[str, Any], tree_spec: Mapping[str, Any], aux_dims: Mapping[str, int], dim: int,
                  expert: Mapping[str, Any] | None = None, built: Mapping[str, nn.Module] | None = None,
                  where: str = "learners") -> nn.Module:
    """Validate ``{type: ..., **params}`` with the learner's own model and build it.

    ``built`` holds learners already constructed, so ``match_parameters_of`` can be resolved.
    """
    block = dict(block)
    entry = LEARNERS.get(block.pop("type"))
    params = entry.validate(block)
    kwargs: dict[str, Any] = {"expert": expert}
    ref = getattr(params, "match_parameters_of", None)
    if ref is not None:
        if not built or ref not in built:
            raise ValueError(f"{where}.match_parameters_of: learner '{ref}' is not built (known: {sorted(built or {})})")
        kwargs["target_parameters"] = round(built[ref].num_parameters() * params.parameter_ratio)
    # initial weights drawn in float64 whatever torch's global default is, so one seed gives one learner
    old = torch.get_default_dtype()
    torch.set_default_dtype(torch.float64)
    try:
        return entry.obj(params, tree_spec, aux_dims, dim, **kwargs)
    finally:
        torch.set_default_dtype(old)


def compile_learner(model: nn.Module) -> nn.Module:
    """Route a learner's tree through torch.compile (same numbers, fused kernels); other learners are left
    as they are (a plain MLP gains little)."""
    tree = getattr(model, "tree", None)
    if isinstance(tree, RMPTree) and tree._compile_args is None:
        tree.compile()
    return model


def build_order(blocks: Mapping[str, Mapping[str, Any]]) -> list[str]:
    """Learner names in an order where every ``match_parameters_of`` target comes first."""
    order: list[str] = []
    visiting: set[str] = set()

    def visit(n: str) -> None:
        if n in order:
            return
        if n in visiting:
            raise ValueError(f"learners: match_parameters_of forms a cycle through '{n}'")
        visiting.add(n)
        ref = blocks[n].get("match_parameters_of")
        if ref is not None:
            if ref not in blocks:
                raise ValueError(f"learners.{n}.match_parameters_of: no learner named '{ref}' (have: {sorted(blocks)})")
            visit(ref)
        visiting.discard(n)
        order.append(n)

    for n in blocks:
        visit(n)
    return order
