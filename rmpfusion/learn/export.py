"""A trained learner as one file that needs only torch: what ``rmpfusion-export`` writes.

A learner whose policy is a tree is exported through ``core/export.py`` (q̈, and M and f on request); any other
learner as its ``forward`` (q̈ only). The program takes ``(q, q̇, *aux)`` with the aux entries in a fixed order,
for any batch size; ``metadata`` says which, and is stored in the file.
"""

from __future__ import annotations

import json
import platform
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import torch
from torch import Tensor, nn

from ..core.export import TreeProgram, export_policy, export_tree
from ..core.tree import RMPTree
from ..scenes.sets import ObstacleSet, with_slots
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


def export_learner(
    learner: Learner, q: Tensor, qd: Tensor, aux: Mapping[str, Tensor], aux_names: Sequence[str], with_rmp: bool = False
) -> torch.export.ExportedProgram:
    """The learner's policy for any batch size, traced at the example states (B ≥ 2)."""
    if (refusal := learner.export_refusal()) is not None:
        raise ValueError(refusal)
    learner.eval()
    if learner.tree is not None:
        return export_tree(learner.tree, q, qd, aux, aux_names, with_rmp=with_rmp)
    if with_rmp:
        raise ValueError(
            "M and f exist for learners whose policy is an RMP tree; this learner has none (export q̈ "
            "only: leave out --with-rmp)"
        )
    if q.shape[0] < 2:
        raise ValueError("export_learner traces at an example batch of at least 2 states (1 would fix the batch size)")
    return export_policy(LearnerProgram(learner, aux_names), q, qd, aux, aux_names)


class SetsProgram(nn.Module):
    """``forward(q, q̇, *inputs)`` -> q̈ of a tree holding obstacle sets, the inputs in ``input_names`` order: the plain
    aux entries (the goal) and every set's ``(B, N_max, k)`` tensors and ``(B, N_max)`` mask, what
    ``scenes.World.set_aux()`` holds. The slots the tree reads are made inside the program, so the number of obstacles
    present is an input (the masks), not part of the traced graph."""

    def __init__(
        self,
        tree: RMPTree,
        sets: Sequence[ObstacleSet],
        input_names: Sequence[str],
        tree_aux_names: Sequence[str],
        centres: Callable[[Tensor], Tensor] | None = None,
    ):
        super().__init__()
        self.sets = list(sets)
        self.input_names = list(input_names)
        self.tree_aux_names = list(tree_aux_names)
        self.program = TreeProgram(tree, tree_aux_names)
        self.centres = centres

    def forward(self, q: Tensor, qd: Tensor, *inputs: Tensor) -> Tensor:
        points = None if self.centres is None else self.centres(q)
        aux = with_slots(self.sets, dict(zip(self.input_names, inputs)), points)
        return self.program(q, qd, *(aux[n] for n in self.tree_aux_names))


def export_with_sets(
    tree: RMPTree,
    sets: Sequence[ObstacleSet],
    q: Tensor,
    qd: Tensor,
    inputs: Mapping[str, Tensor],
    centres: Callable[[Tensor], Tensor] | None = None,
) -> torch.export.ExportedProgram:
    """A tree holding obstacle sets exported for any obstacles present (0 … N_max of each set): the program takes
    ``inputs`` (``World.set_aux()``: the goal, the set tensors and masks) in their order, at the example's batch size
    (a controller's 1). A set with ``nearest`` is selected inside the program from the control spheres' centres,
    ``centres(q)`` (``Robot.sphere_centres``). The batch size is fixed: torch.export cannot yet prove the stride guards
    of a shared weight stacked over several members for a symbolic batch (the same holds for a tree of several fixed
    obstacles)."""
    names = list(inputs)
    tree_names = [
        n for n in with_slots(list(sets), inputs, None if centres is None else centres(q)) if n in tree.aux_dims
    ]
    program = SetsProgram(tree, sets, names, tree_names, centres).eval()
    _ = tree.plan  # planned before tracing
    entries = tuple(inputs[n].expand(q.shape[0], *inputs[n].shape[1:]).contiguous() for n in names)
    with torch.no_grad():
        return torch.export.export(program, (q, qd, *entries))


def metadata(
    aux_dims: Mapping[str, int], aux_names: Sequence[str], dim: int, dtype: torch.dtype, with_rmp: bool, **about: Any
) -> dict[str, Any]:
    """What a caller needs to call the program, and where it came from (``about``: learner, checkpoint, ...)."""
    inputs = [f"q ({{B}}, {dim})", f"qd ({{B}}, {dim})"] + [f"{n} ({{B}}, {aux_dims[n]})" for n in aux_names]
    return {
        "format": "rmpfusion-exported-policy/1",
        "inputs": inputs,
        "aux_names": list(aux_names),
        "aux_dims": {n: int(aux_dims[n]) for n in aux_names},
        "dim": int(dim),
        "dtype": str(dtype).split(".")[-1],
        "outputs": ["qdd", "M", "f"] if with_rmp else ["qdd"],
        "torch": torch.__version__,
        "python": platform.python_version(),
        **about,
    }


def metadata_text(meta: Mapping[str, Any]) -> str:
    return json.dumps(meta, indent=1, default=str)
