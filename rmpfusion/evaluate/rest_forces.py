"""Which leaves hold a tree where it comes to rest: each leaf's force at q̇ = 0, in the root's coordinates.

A rollout that stops away from the goal sits where the root's force vanishes, so some leaves' forces cancel
there. At q̇ = 0 a GDS leaf's damping and curvature terms vanish, and a weight contributes −Φ∇w beside w's share
of −∇Φ (docs/math.md §12, premise 3), so a leaf's share of the root force is −∇_q(W Φ): Φ its potential, W the
product of the weights on the edges from the root down to it. Summed over the leaves this is the root's force;
what the sum misses (leaves that are not GDSs, e.g. a velocity cap) is returned as the residual, so a caller can
tell a complete account from a partial one.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import torch
from torch import Tensor

from ..core.algebra import Edge
from ..core.tree import RMPTree


@dataclass
class RestForces:
    """Per leaf, its force at rest on the root (B, n) and the part of it its path weight's gradient makes
    (−Φ∇W: zero for constant weights); the root's own force there and what the leaves' sum misses."""

    leaves: dict[str, Tensor]
    weight_gradient: dict[str, Tensor]
    root: Tensor
    residual: Tensor

    def strongest(self, top: int = 4) -> list[tuple[str, float]]:
        """The ``top`` leaves by the median over the samples of their force's size, strongest first."""
        sizes = {n: float(f.norm(dim=-1).median()) for n, f in self.leaves.items()}
        return sorted(((n, s) for n, s in sizes.items() if s > 0), key=lambda kv: -kv[1])[:top]


def _path_weight(tree: RMPTree, edges: Mapping[str, Edge], leaf: str, batch: int, like: Tensor) -> Tensor:
    """The product of the weights on the edges from the root down to ``leaf`` (1 where an edge has none)."""
    w = torch.ones(batch, dtype=like.dtype, device=like.device)
    node = leaf
    while node != tree.root_name:
        edge_w = edges[node].w
        if edge_w is not None:
            w = w * edge_w.reshape(batch)
        node = tree.parent_of[node]
    return w


def rest_forces(tree: RMPTree, q: Tensor, aux: Mapping[str, Tensor] | None = None) -> RestForces:
    """Each leaf's force on the root at the configurations ``q`` (B, n), at rest."""
    q = q.detach().clone().requires_grad_(True)
    with torch.enable_grad():
        out = tree(q, torch.zeros_like(q), dict(aux) if aux is not None else None, return_nodes=True)
        assert out.nodes is not None, "asked for with return_nodes"
        rmps, edges = out.nodes["rmp"], out.nodes["edge"]
        B = q.shape[0]
        forces: dict[str, Tensor] = {}
        by_weight: dict[str, Tensor] = {}
        for leaf in tree.rmps:
            phi = rmps[leaf].Phi
            if phi is None:
                continue
            W, phi = _path_weight(tree, edges, leaf, B, q), phi.reshape(B)
            weighted = W * phi
            if not weighted.requires_grad:  # a potential that does not depend on q (none, or constant)
                continue
            forces[leaf] = -_grad(weighted.sum(), q)
            by_weight[leaf] = -_grad((W * phi.detach()).sum(), q)
    root = out.f.detach()
    total = torch.stack(list(forces.values())).sum(0) if forces else torch.zeros_like(root)
    return RestForces(forces, by_weight, root, root - total)


def _grad(value: Tensor, q: Tensor) -> Tensor:
    """d value / d q, zero where value does not depend on q; the graph is kept for the next leaf."""
    if not value.requires_grad:
        return torch.zeros_like(q)
    (grad,) = torch.autograd.grad(value, q, retain_graph=True, allow_unused=True)
    return torch.zeros_like(q) if grad is None else grad.detach()
