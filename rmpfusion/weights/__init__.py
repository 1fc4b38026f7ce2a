"""Weight-function types registered by name: constant, hand-designed (experts), neural (learners)."""

from . import designed, neural  # noqa: F401  (importing the modules registers their weight functions)
from .designed import RBF, Constant, Logistic
from .neural import MLPWeight

__all__ = ["RBF", "Constant", "Logistic", "MLPWeight"]
