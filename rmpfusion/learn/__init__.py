"""Learning RMPfusion from demonstrations: learners (structured and unstructured), behavior cloning. The
demonstrations themselves (``Dataset``, ``collect``, saving and loading) are the environments' product:
``rmpfusion.envs.demonstrations``.

Importing this package registers the learners, objectives and optimisers (``LEARNERS``, ``OBJECTIVES``,
``OPTIMIZERS`` in ``rmpfusion.registry``); the experiment pipeline (``rmpfusion.pipeline``) is imported on
demand because it pulls in plotting.
"""
from . import learners  # noqa: F401  (registration side effects)
from .learner import Learner  # noqa: F401
from .learners import build_learner, build_order  # noqa: F401
from .objectives import Objective, dataset_loss  # noqa: F401
from .rmp_learner import RMPLearner  # noqa: F401
from .unstructured import UnstructuredLearner, width_for_parameters  # noqa: F401
from .train import TrainResult, train  # noqa: F401

