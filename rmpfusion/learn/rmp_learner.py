"""learner-rmp: the expert's tree with a fresh neural weight function on each learned edge (paper §4.1).

Its policy is an RMP tree, so it keeps the tree's Lyapunov function (Theorem 2) whatever the weights learn.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from pydantic import Field
from torch import Tensor, nn

from ..assembly.errors import ConfigError, Issue
from ..assembly.tree import build_tree
from ..assembly.weighting import expand_aux, tree_with_weights
from ..core.learnable import learned_values
from ..core.tree import RMPTree, TreeOutput
from ..registry import LEARNERS, Params
from .learner import Learner

#: Leaf types that only condition or damp the root; learning a weight on them adds nothing the expert has.
REGULARISER_LEAVES = frozenset({"identity_metric", "damper", "rmpflow_damper"})


def _default_weight() -> dict:
    return {"type": "mlp", "hidden": [32, 32], "activation": "tanh", "aux": "all"}


@LEARNERS.register("rmp")
class RMPLearner(Learner["RMPLearner.Params"]):
    """learner-rmp: the given tree with a (fresh, randomly initialised) neural weight on each learned edge."""

    class Params(Params):
        weights: dict[str, Any] = Field(
            default_factory=_default_weight,
            description="weight spec put on every learned edge; aux: all = every aux input",
        )
        edges: list[str] | None = Field(
            None,
            description="edges this learner puts `weights` on; default: those the expert weights, else every edge "
            "except regulariser leaves. Weights the tree spec declares itself (arm_reach's attractor, obstacle and ground "
            "weights) are learned too, whatever this lists: [] removes only the learner's own",
        )
        edge_weights: dict[str, dict[str, Any]] = Field(
            default_factory=dict,
            description="per-edge keys merged over `weights`, e.g. "
            "{obstacle1: {aux: [obstacle1_center, obstacle1_radius]}}",
        )
        leaves: dict[str, dict[str, Any]] = Field(
            default_factory=dict,
            description="per-leaf settings merged over the tree's for this learner only, e.g. "
            "{goal: {gain: {learn: true, init: 0.5}}}: leaf numbers it learns",
        )

    @classmethod
    def from_params(
        cls,
        params: Params,
        tree_spec: Mapping[str, Any] | None,
        aux_dims: Mapping[str, int],
        dim: int,
        expert: Mapping[str, Any] | None = None,
        built=None,
        where: str = "learners.rmp",
    ) -> RMPLearner:
        assert tree_spec is not None, "learner-rmp puts its weights on a tree"
        return cls(params, tree_spec, aux_dims, dim, expert=expert, where=where)

    def __init__(
        self,
        params: Params,
        tree_spec: Mapping[str, Any],
        aux_dims: Mapping[str, int],
        dim: int,
        expert: Mapping[str, Any] | None = None,
        where: str = "learners.rmp",
    ):
        super().__init__()
        self.params = params
        edges = list(params.edges) if params.edges is not None else self.default_edges(tree_spec, expert)
        stray = [e for e in params.edge_weights if e not in edges]
        if stray:
            raise ConfigError(
                [
                    Issue(
                        f"{where}.edge_weights.{e}",
                        f"'{e}' is not a learned edge; learned edges: {', '.join(edges)} "
                        f"(add it to {where}.edges or remove the entry)",
                    )
                    for e in stray
                ]
            )
        per_edge = {e: expand_aux({**params.weights, **params.edge_weights.get(e, {})}, aux_dims) for e in edges}
        spec = tree_with_weights(
            with_leaves(tree_spec, params.leaves, f"{where}.leaves"), per_edge, where=f"{where}.edges"
        )
        self.edges = edges
        tree = build_tree(spec, aux_dims=dict(aux_dims), weight_paths={e: f"{where}.weights" for e in edges})
        # registered as the submodule "tree" (state_dict keys tree.…) by nn.Module's __setattr__, as ``self.tree =``
        # would; read back through the ``tree`` property
        nn.Module.__setattr__(self, "tree", tree)
        if self.tree.dim != dim:
            raise ValueError(f"the tree's root has dimension {self.tree.dim} but the environment has {dim}")

    @property
    def tree(self) -> RMPTree:
        tree = self._modules["tree"]
        assert isinstance(tree, RMPTree), "set once, by __init__"
        return tree

    @staticmethod
    def default_edges(tree_spec: Mapping[str, Any], expert: Mapping[str, Any] | None) -> list[str]:
        nodes = tree_spec["nodes"]
        if expert:
            return [n for n in nodes if n in expert]
        return [n for n, nd in nodes.items() if not ((nd.get("rmp") or {}).get("type") in REGULARISER_LEAVES)]

    def learned_numbers(self) -> dict[str, float]:
        """``<leaf>.<number>`` → value of every leaf number it learns."""
        return {f"{n}.{k}": v for n, leaf in self.tree.rmps.items() for k, v in learned_values(leaf).items()}

    def describe(self) -> dict[str, Any]:
        """The values its learnable leaf numbers have reached (none for a learner of weights only)."""
        learned = self.learned_numbers()
        return {"learned_leaf_parameters": learned} if learned else {}

    has_first_order_field = True

    def first_order_field(self, q: Tensor, aux: Mapping[str, Tensor]) -> Tensor:
        """The tree's overdamped field −B_r⁻¹∇Φ_r (``RMPTree.overdamped_field``)."""
        return self.tree.overdamped_field(q, aux)

    def policy(self, q: Tensor, qd: Tensor, aux: Mapping[str, Tensor] | None = None) -> TreeOutput:
        """The full TreeOutput, so rollouts can record V_r and q̇ᵀBq̇."""
        return self.tree(q, qd, aux)

    def forward(self, q: Tensor, qd: Tensor, aux: Mapping[str, Tensor] | None = None) -> Tensor:
        return self.tree(q, qd, aux).qdd


def with_leaves(tree_spec: Mapping[str, Any], leaves: Mapping[str, Mapping[str, Any]], where: str) -> dict[str, Any]:
    """The tree spec with each named leaf's rmp settings updated by ``leaves`` (a learner's own leaf numbers)."""
    nodes = dict(tree_spec["nodes"])
    issues = []
    for name, settings in leaves.items():
        rmp = (nodes.get(name) or {}).get("rmp")
        if rmp is None:
            leaf_names = [n for n, nd in nodes.items() if nd.get("rmp")]
            issues.append(
                Issue(f"{where}.{name}", f"'{name}' is not a leaf of the tree; leaves: {', '.join(leaf_names)}")
            )
            continue
        nodes[name] = {**nodes[name], "rmp": {**rmp, **settings}}
    if issues:
        raise ConfigError(issues)
    return {**tree_spec, "nodes": nodes}
