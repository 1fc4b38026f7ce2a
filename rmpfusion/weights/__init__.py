"""Weight-function types registered by name: constant, hand-designed (experts), neural (learners), and a learned
radial profile (learners that must keep the goal the only equilibrium)."""

from . import designed, neural, radial  # noqa: F401  (importing the modules registers their weight functions)
from .designed import RBF, Constant, Logistic
from .neural import MLPWeight
from .radial import Radial

__all__ = ["RBF", "Constant", "Logistic", "MLPWeight", "Radial"]
