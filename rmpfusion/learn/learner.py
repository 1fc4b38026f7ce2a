"""What every learner is to the code that trains, evaluates and reports it.

Training only needs (q, q̇, aux) -> q̈; evaluation also rolls out ``policy`` (a TreeOutput when the learner is a
tree, so its Lyapunov function is monitored); the pipeline asks for the tree (weight reports, figures), for
what to write about the learner into metrics.json, and to compile it. These are members of one base class so
that a learner states what it offers instead of callers probing for attributes.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any, ClassVar, Generic, TypeVar

from torch import Tensor, nn

from ..core.tree import RMPTree, TreeOutput
from ..registry import Params

if TYPE_CHECKING:
    from ..envs.demonstrations import Dataset

P = TypeVar("P", bound=Params)


class Learner(nn.Module, ABC, Generic[P]):
    """A learner of behavior cloning: a module (q, q̇, aux) -> q̈ built from its config block.

    Subclasses register with ``LEARNERS`` and carry a ``Params`` model of their block (``P``); ``build_learner``
    validates the block and calls ``from_params``.
    """

    @classmethod
    def from_params(
        cls,
        params: P,
        tree_spec: Mapping[str, Any] | None,
        aux_dims: Mapping[str, int],
        dim: int,
        expert: Mapping[str, Any] | None = None,
        built: Mapping[str, Learner] | None = None,
        where: str = "learners",
    ) -> Learner[P]:
        """Build from a validated block. ``built`` holds the learners built before this one (by name), for a
        learner sized after another; ``where`` is the block's config path, for errors."""
        return cls(params, tree_spec, aux_dims, dim, expert=expert)

    @abstractmethod
    def policy(self, q: Tensor, qd: Tensor, aux: Mapping[str, Tensor] | None = None) -> TreeOutput | Tensor:
        """What a rollout records: the tree's TreeOutput for a tree learner (V_r is monitored), else q̈."""

    @abstractmethod
    def forward(self, q: Tensor, qd: Tensor, aux: Mapping[str, Tensor] | None = None) -> Tensor:
        """q̈ (B, d) at the states: what the training objective compares with the expert's."""

    @property
    @abstractmethod
    def tree(self) -> RMPTree | None:
        """The RMP tree the learner's policy is, or None for a network with no tree structure."""

    #: whether ``first_order_field`` gives a field (a tree's overdamped one, a first-order learner's own); the
    #: field-fitting method (``train.method=field``) refuses a learner without one before it trains
    has_first_order_field: ClassVar[bool] = False

    def first_order_field(self, q: Tensor, aux: Mapping[str, Tensor]) -> Tensor:
        """v(q) (B, d): the velocity field the policy's motion follows, which ``train.method=field`` fits to
        recorded velocities. Only learners with ``has_first_order_field`` have one."""
        raise NotImplementedError(f"{type(self).__name__} has no first-order field (has_first_order_field is False)")

    def initialise(self, train: Dataset) -> None:
        """Set what the learner starts from that is made from its training data (SEDS's mixture, fitted by EM);
        nothing by default: most learners start at a random draw. Every training method calls it before its
        first step and before a resumed run loads its checkpoint over it, so it must be a deterministic function
        of the data."""

    def export_refusal(self) -> str | None:
        """Why torch.export cannot trace this learner's policy (said to whoever asks for an export), or None."""
        return None

    def num_parameters(self) -> int:
        """The number of trained scalars (what parameter matching and metrics.json count)."""
        return sum(p.numel() for p in self.parameters() if p.requires_grad)

    def describe(self) -> dict[str, Any]:
        """What metrics.json reports about this learner beside its metrics (JSON-ready); nothing by default."""
        return {}

    def learned_numbers(self) -> dict[str, float]:
        """Named numbers of its policy it learns besides network weights (a tree's learnable leaf parameters);
        reported at every evaluated snapshot. None by default."""
        return {}

    def compile(self) -> Learner:  # type: ignore[override]  # not nn.Module.compile: compiles the tree, returns self
        """Route the learner's tree through torch.compile (same numbers, fused kernels); calling it again keeps
        the compiled tree. A learner without a tree is left eager: a plain network gains little from it."""
        tree = self.tree
        if tree is not None and tree._compile_args is None:
            tree.compile()
        return self
