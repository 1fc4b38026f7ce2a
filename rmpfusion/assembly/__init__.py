"""From validated specs to torch modules: the tree schema, its checks, and the builder."""

from .. import maps, rmps, weights  # noqa: F401  (imported to register the built-in components' entries)
from .errors import ConfigError, Issue
from .spec import TreeSpec, validate_tree_spec
from .tree import build_tree
from .weighting import expand_aux, tree_with_weights

__all__ = [
    "ConfigError",
    "Issue",
    "TreeSpec",
    "build_tree",
    "expand_aux",
    "tree_with_weights",
    "validate_tree_spec",
]
