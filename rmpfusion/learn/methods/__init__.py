"""The built-in training methods, registered in ``TRAIN_METHODS`` by the names ``train.method`` gives them:
behavior cloning (``bc``), DAgger (``dagger``), analytic policy gradients through the simulator (``apg``), a
score-function policy gradient (``pg``), trajectory matching of recorded demonstrations (``match``) and the
first-order field fitted to recorded velocities (``field``)."""

from . import apg, bc, dagger, field, match, pg  # noqa: F401  (importing the modules registers the training methods)

__all__: list[str] = []  # nothing to import from here: the methods are reached through TRAIN_METHODS
