"""A tree as a program that needs only torch: ``(q, q̇, aux...) -> q̈`` (and ``M``, ``f`` on request).

``TreeProgram`` is the tree's policy as a pure function of tensors, the aux entries positional in a fixed order,
so ``torch.export`` traces it into one graph of aten operations: fixed to the tree's structure and weights, free
in the batch size. Where the LU solve of M q̈ = f is not good for some sample, the program answers with the
pseudo-inverse there, as the tree does (``core/algebra.py::resolve``), through ``torch.cond``, so a regular state
pays for the solve alone. ``export_tree`` makes the ``ExportedProgram``; ``torch.export.save`` writes it and
``torch.export.load(path).module()`` runs it, with no rmpfusion installed. An AOTInductor package of it
(``torch._inductor.aoti_compile_and_package``) runs from Python or C++ (``docs/architecture.md §8``).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import torch
from torch import Tensor, nn

from .algebra import lu_solve
from .passes import evaluate
from .tree import RMPTree


def _solved(a: Tensor, M: Tensor, f: Tensor, good: Tensor) -> Tensor:
    return a.clone()


def _pinv_where_singular(a: Tensor, M: Tensor, f: Tensor, good: Tensor) -> Tensor:
    return torch.where(good[:, None], a, (torch.linalg.pinv(M) @ f.unsqueeze(-1)).squeeze(-1))


class TreeProgram(nn.Module):
    """``forward(q, q̇, *aux)`` with the aux entries in ``aux_names`` order: q̈, or (q̈, M, f) with ``with_rmp``."""

    def __init__(self, tree: RMPTree, aux_names: Sequence[str], with_rmp: bool = False):
        super().__init__()
        self.tree = tree
        self.aux_names = list(aux_names)
        self.with_rmp = with_rmp

    def forward(self, q: Tensor, qd: Tensor, *aux: Tensor):
        plan = self.tree.plan
        given = self.tree.aux_with_source(q, dict(zip(self.aux_names, aux)))  # a tree's AuxSource makes its entries
        root = evaluate(plan, q, qd, given, lean=plan.lean and not self.with_rmp).root
        a, good = lu_solve(root.M, root.f)
        qdd = torch.cond(good.all(), _solved, _pinv_where_singular, (a, root.M, root.f, good))
        return (qdd, root.M, root.f) if self.with_rmp else qdd


def export_policy(
    program: nn.Module, q: Tensor, qd: Tensor, aux: Mapping[str, Tensor], aux_names: Sequence[str]
) -> torch.export.ExportedProgram:
    """``program(q, q̇, *aux)`` exported for any batch size, traced at the example state (the batch dimension of
    every input is one dynamic size)."""
    batch = torch.export.Dim("batch", min=1)
    entries = tuple(aux[n].expand(q.shape[0], -1).contiguous() for n in aux_names)
    shapes = ({0: batch}, {0: batch}) + ((tuple({0: batch} for _ in entries),) if entries else ())  # (q, q̇, *aux)
    with torch.no_grad():
        return torch.export.export(program, (q, qd, *entries), dynamic_shapes=shapes)


def export_tree(
    tree: RMPTree, q: Tensor, qd: Tensor, aux: Mapping[str, Tensor], aux_names: Sequence[str], with_rmp: bool = False
) -> torch.export.ExportedProgram:
    """The tree's policy exported for any batch size, traced at the example state (q, q̇, aux) (B ≥ 2, so the batch
    dimension is not specialised to 1). ``aux_names``: the aux entries the program takes, in order."""
    if q.shape[0] < 2:
        raise ValueError("export_tree traces at an example batch of at least 2 states (1 would fix the batch size)")
    _ = tree.plan  # planned before tracing
    return export_policy(TreeProgram(tree, aux_names, with_rmp).eval(), q, qd, aux, aux_names)
