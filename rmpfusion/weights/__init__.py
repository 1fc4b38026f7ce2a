"""Weight-function types registered by name: constant, hand-designed (experts), neural (learners)."""

from . import designed, neural  # noqa: F401  (registration side effects)
from .designed import RBF, Constant, Logistic  # noqa: F401
from .neural import MLPWeight  # noqa: F401
