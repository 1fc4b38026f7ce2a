"""rmpfusion: Riemannian Motion Policy trees with learnable weight functions (RMPfusion, CoRL 2019).

Importing the package registers every built-in component, environment and learner (each registers when its
own package is imported); plugins load on the first registry lookup. docs/architecture.md draws the layers.
"""

from . import envs, learn  # noqa: F401  (the built-in environments and learners register themselves)
from .assembly import build_tree  # noqa: F401
from .core import RMPTree, TreeOutput  # noqa: F401
from .registry import ENVS, LEAF_RMPS, LEARNERS, TASK_MAPS, WEIGHTS  # noqa: F401

__version__ = "0.1.0"
