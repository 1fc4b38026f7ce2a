"""Learning RMPfusion from demonstrations: datasets, learners (structured and unstructured), behavior cloning.

Importing this package registers the learners in ``rmpfusion.registry.LEARNERS``; the experiment pipeline
(``rmpfusion.pipeline.run``) is imported on demand because it pulls in plotting.
"""
from . import learners  # noqa: F401  (registration side effects)
from .demonstrations import Dataset, DatasetError, collect, load_dataset, save_dataset  # noqa: F401
from .learners import RMPLearner, UnstructuredLearner, build_learner, width_for_parameters  # noqa: F401
from .train import TrainResult, train  # noqa: F401

