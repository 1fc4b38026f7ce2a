"""An independent, node-by-node evaluation of a built tree: the reference level-batched evaluation is held to.

Every node's own map, weight and leaf module runs on its own (B, ...) batch, in breadth-first order, and
pullback* (paper eq. 6, with the recursion of Theorem 2 for G, B, Φ, L, V) is written out here per node with
einsum, without rmpfusion.core.algebra:

    f = Σ_i w_i J_iᵀ (f_i − M_i c_i) + L_i ∇w_i − (ẋᵀ∇w_i) J_iᵀ G_i J_i ẋ
    M = Σ_i w_i J_iᵀ M_i J_i,   G, B likewise,   Φ = Σ_i w_i Φ_i,   L, V likewise

then q̈ = M⁻¹ f by torch.linalg.solve.
"""

from __future__ import annotations

import torch

FIELDS = ("f", "M", "G", "B", "Phi", "L", "V")


def _pull(xd, J, c, w, gw, child):
    """Child i's term of each field in the parent's coordinates."""
    B = xd.shape[0]
    w = torch.ones(B, dtype=xd.dtype) if w is None else w
    JT = J.transpose(-1, -2)
    f = w[:, None] * torch.einsum("bmn,bn->bm", JT, child["f"] - torch.einsum("bij,bj->bi", child["M"], c))
    if gw is not None:
        JGJxd = torch.einsum(
            "bmn,bn->bm", JT, torch.einsum("bij,bj->bi", child["G"], torch.einsum("bnm,bm->bn", J, xd))
        )
        f = f + child["L"][:, None] * gw - (xd * gw).sum(-1, keepdim=True) * JGJxd
    out = {"f": f}
    for k in ("M", "G", "B"):
        out[k] = w[:, None, None] * torch.einsum("bmn,bnk,bkl->bml", JT, child[k], J)
    for k in ("Phi", "L", "V"):
        out[k] = w * child[k]
    return out


def node_by_node(tree, q, qd, aux=None) -> dict[str, torch.Tensor]:
    """The root's f, M, G, B, Φ, L, V and q̈ of ``tree`` at (q, q̇, aux), one node at a time."""
    aux = tree._normalise_aux(aux, q.shape[0], q.dtype)
    state, edges, rmp = {tree.root_name: (q, qd)}, {}, {}
    for n in tree.order:
        x, xd = state[tree.parent_of[n]]
        y, yd, J, c = tree.maps[n](x, xd, aux)
        w, gw = tree.weights[n](x, aux) if n in tree.weights else (None, None)
        state[n], edges[n] = (y, yd), (J, c, w, gw)
    for n in [*reversed(tree.order), tree.root_name]:
        kids = tree.children_of[n]
        if not kids:
            leaf = tree.rmps[n](*state[n])
            rmp[n] = {k: getattr(leaf, k) for k in FIELDS}
            continue
        xd = state[n][1]
        terms = [_pull(xd, *edges[k], rmp[k]) for k in kids]
        rmp[n] = {k: sum(t[k] for t in terms) for k in FIELDS}
    root = rmp[tree.root_name]
    root["qdd"] = torch.linalg.solve(root["M"], root["f"])
    return root
