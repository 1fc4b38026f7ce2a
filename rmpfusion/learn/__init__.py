"""Learning RMPfusion: learners (structured and unstructured) and the training methods that train them (behavior
cloning, DAgger, policy optimisation through the simulator, a score-function policy gradient) around one resumable
loop. The demonstrations themselves (``Dataset``, ``collect``, saving and loading) are the environments' product:
``rmpfusion.envs.demonstrations``.

Importing this package registers the learners, objectives, optimisers and training methods (``LEARNERS``,
``OBJECTIVES``, ``OPTIMIZERS``, ``TRAIN_METHODS`` in ``rmpfusion.registry``); the experiment pipeline
(``rmpfusion.pipeline``) is imported on demand because it pulls in plotting.
"""

from . import learners, methods  # noqa: F401  (registration side effects)
from .learner import Learner  # noqa: F401
from .learners import build_learner, build_order  # noqa: F401
from .objectives import Objective, dataset_loss  # noqa: F401
from .rmp_learner import RMPLearner  # noqa: F401
from .train import TrainResult, train  # noqa: F401
from .unstructured import UnstructuredLearner, width_for_parameters  # noqa: F401
