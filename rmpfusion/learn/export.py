"""A trained learner as one file that needs only torch: what ``rmpfusion-export`` writes.

A learner whose policy is a tree is exported through ``core/export.py`` (q̈, and M and f on request); any other
learner as its ``forward`` (q̈ only). The program takes ``(q, q̇, *aux)`` with the aux entries in a fixed order,
for any batch size; ``metadata`` says which, and is stored in the file.
"""
from __future__ import annotations

import json
import platform
from typing import Any, Mapping, Sequence

import torch
from torch import Tensor, nn

from ..core.export import export_tree
from .learner import Learner

#: The name of the metadata an exported file carries (``torch.export.save``'s extra files; AOTInductor metadata).
METADATA = "rmpfusion.json"


class LearnerProgram(nn.Module):
    """``forward(q, q̇, *aux)`` -> q̈ of a learner without a tree, the aux entries in ``aux_names`` order."""

    def __init__(self, learner: Learner, aux_names: Sequence[str]):
        super().__init__()
        self.learner = learner
        self.aux_names = list(aux_names)

    def forward(self, q: Tensor, qd: Tensor, *aux: Tensor) -> Tensor:
        return self.learner(q, qd, dict(zip(self.aux_names, aux)))


def export_learner(learner: Learner, q: Tensor, qd: Tensor, aux: Mapping[str, Tensor], aux_names: Sequence[str],
                   with_rmp: bool = False) -> torch.export.ExportedProgram:
    """The learner's policy for any batch size, traced at the example states (B ≥ 2)."""
    learner.eval()
    if learner.tree is not None:
        return export_tree(learner.tree, q, qd, aux, aux_names, with_rmp=with_rmp)
    if with_rmp:
        raise ValueError("M and f exist for learners whose policy is an RMP tree; this learner has none (export q̈ "
                         "only: leave out --with-rmp)")
    batch = torch.export.Dim("batch", min=1)
    entries = tuple(aux[n].expand(q.shape[0], -1).contiguous() for n in aux_names)
    shapes = ({0: batch}, {0: batch}) + ((tuple({0: batch} for _ in entries),) if entries else ())
    with torch.no_grad():
        return torch.export.export(LearnerProgram(learner, aux_names), (q, qd, *entries), dynamic_shapes=shapes)


def metadata(aux_dims: Mapping[str, int], aux_names: Sequence[str], dim: int, dtype: torch.dtype, with_rmp: bool,
             **about: Any) -> dict[str, Any]:
    """What a caller needs to call the program, and where it came from (``about``: learner, checkpoint, ...)."""
    inputs = [f"q ({{B}}, {dim})", f"qd ({{B}}, {dim})"] + [f"{n} ({{B}}, {aux_dims[n]})" for n in aux_names]
    return {"format": "rmpfusion-exported-policy/1", "inputs": inputs, "aux_names": list(aux_names),
            "aux_dims": {n: int(aux_dims[n]) for n in aux_names}, "dim": int(dim), "dtype": str(dtype).split(".")[-1],
            "outputs": ["qdd", "M", "f"] if with_rmp else ["qdd"], "torch": torch.__version__,
            "python": platform.python_version(), **about}


def metadata_text(meta: Mapping[str, Any]) -> str:
    return json.dumps(meta, indent=1, default=str)
