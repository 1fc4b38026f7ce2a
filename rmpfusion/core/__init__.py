"""RMP-algebra* and the RMP-tree*: the math every experiment composes."""

from .algebra import Edge, NodeRMP, pullback_star, pushforward, resolve
from .gds import GDS, LeafRMP
from .taskmap import TaskMap
from .tree import RMPTree, TreeOutput
from .weight import WeightFunction

__all__ = [
    "GDS",
    "Edge",
    "LeafRMP",
    "NodeRMP",
    "RMPTree",
    "TaskMap",
    "TreeOutput",
    "WeightFunction",
    "pullback_star",
    "pushforward",
    "resolve",
]
