"""rmpfusion: Riemannian Motion Policy trees with learnable weight functions (RMPfusion, CoRL 2019)."""
from .build import build_tree  # noqa: F401
from .core import RMPTree, TreeOutput  # noqa: F401
from .registry import ENVS, LEAF_RMPS, LEARNERS, TASK_MAPS, WEIGHTS  # noqa: F401

__version__ = "0.1.0"
