"""RMP-algebra* and the RMP-tree*: the math every experiment composes."""

from .algebra import Edge, NodeRMP, pullback_star, pushforward, resolve  # noqa: F401
from .gds import GDS, LeafRMP  # noqa: F401
from .taskmap import TaskMap  # noqa: F401
from .tree import RMPTree, TreeOutput  # noqa: F401
from .weight import WeightFunction  # noqa: F401
