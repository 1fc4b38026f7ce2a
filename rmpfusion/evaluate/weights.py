"""What the weight functions learned: each weighted edge's w at given states, for the expert and a learner.

A learner can match the expert's accelerations while its weights differ (2d2level's multiplied weights are not
identifiable), or barely change what the tree does; its behaviour alone does not say which. Summaries over the
test states go into metrics.json, and values along one test trajectory into a figure, beside the expert's.
"""

from __future__ import annotations

from collections.abc import Mapping

import torch
from torch import Tensor

from ..core.tree import RMPTree


def learned_edges(tree: RMPTree) -> list[str]:
    """The edges whose weight has trainable parameters, in the tree's breadth-first order."""
    return [n for n in tree.order if n in tree.weights and any(p.requires_grad for p in tree.weights[n].parameters())]


@torch.no_grad()
def edge_weights(
    tree: RMPTree, q: Tensor, qd: Tensor, aux: Mapping[str, Tensor], edges: list[str], chunk: int = 2048
) -> dict[str, Tensor]:
    """``{edge: (B,) w}`` at the states (q, q̇, aux), evaluated through the tree (so shared weights see the aux
    their edge binds and the parent state their edge starts from). Chunked: memory stays flat for big sets. The
    states go to the tree's device, the weights come back to the states'."""
    parts: dict[str, list[Tensor]] = {e: [] for e in edges}
    d = tree.device
    for s in range(0, q.shape[0], chunk):
        sl = slice(s, s + chunk)
        out = tree(q[sl].to(d), qd[sl].to(d), {k: v[sl].to(d) for k, v in aux.items()}, return_nodes=True)
        for e in edges:
            parts[e].append(out.nodes["edge"][e].w.reshape(-1).to(q.device))
    return {e: torch.cat(v) if v else q.new_zeros(0) for e, v in parts.items()}


def summarize_weights(values: Mapping[str, Tensor]) -> dict[str, dict[str, float]]:
    """``{edge: {min, mean, max}}`` of each edge's weight over the states."""
    return {
        e: {"min": float(w.min()), "mean": float(w.mean()), "max": float(w.max())}
        for e, w in values.items()
        if w.numel()
    }
