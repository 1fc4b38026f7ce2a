"""Learning RMPfusion: learners (structured and unstructured) and the training methods that train them (behavior
cloning, DAgger, policy optimisation through the simulator, a score-function policy gradient) around one resumable
loop. The demonstrations themselves (``Dataset``, ``collect``, saving and loading) are the environments' product:
``rmpfusion.envs.demonstrations``.

Importing this package registers the learners, objectives, optimisers and training methods (``LEARNERS``,
``OBJECTIVES``, ``OPTIMIZERS``, ``TRAIN_METHODS`` in ``rmpfusion.registry``); the experiment pipeline
(``rmpfusion.pipeline``) is imported on demand because it pulls in plotting.
"""

from . import learners, methods  # noqa: F401  (imported to register the built-in learners and training methods)
from .learner import Learner
from .learners import build_learner, build_order
from .objectives import Objective, dataset_loss
from .rmp_learner import RMPLearner
from .train import TrainResult, train
from .unstructured import UnstructuredLearner, width_for_parameters

__all__ = [
    "Learner",
    "Objective",
    "RMPLearner",
    "TrainResult",
    "UnstructuredLearner",
    "build_learner",
    "build_order",
    "dataset_loss",
    "train",
    "width_for_parameters",
]
