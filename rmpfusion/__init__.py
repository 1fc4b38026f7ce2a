"""rmpfusion: Riemannian Motion Policy trees with learnable weight functions (RMPfusion, CoRL 2019).

Importing the package registers every built-in component, environment and learner (each registers when its
own package is imported); plugins load on the first registry lookup. docs/architecture.md draws the layers.
"""

# imported to register the built-in environments, learners, simulators and config resolvers
from . import envs, learn, resolvers, sims  # noqa: F401
from .assembly import build_tree
from .core import RMPTree, TreeOutput
from .registry import ENVS, LEAF_RMPS, LEARNERS, TASK_MAPS, WEIGHTS

__version__ = "0.1.0"

__all__ = ["ENVS", "LEAF_RMPS", "LEARNERS", "TASK_MAPS", "WEIGHTS", "RMPTree", "TreeOutput", "build_tree"]
