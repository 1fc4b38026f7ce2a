"""From validated specs to torch modules: the tree schema, its checks, and the builder."""

from .. import maps, rmps, weights  # noqa: F401  (the built-in components register themselves)
from .errors import ConfigError, Issue  # noqa: F401
from .spec import TreeSpec, validate_tree_spec  # noqa: F401
from .tree import build_tree  # noqa: F401
from .weighting import expand_aux, tree_with_weights  # noqa: F401
