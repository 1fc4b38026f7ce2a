"""Environments; importing this package registers them in ``rmpfusion.registry.ENVS``."""

from . import manipulator_tree  # noqa: F401  (imported to register the tree generator arm_reach)
from .demonstrations import Dataset, DatasetError, collect, dataset_meta, load_dataset, save_dataset
from .manipulator import Manipulator
from .particle2d import Particle2D
from .protocol import (
    DifferentiableRollouts,
    DifferentiableTask,
    Env,
    HasRatioMetrics,
    HasTaskMetrics,
    PlanarWorkspace,
    Renders,
    RenderSettings,
    TimeVaryingAux,
)
from .rollout import Rollout

__all__ = [
    "Dataset",
    "DatasetError",
    "DifferentiableRollouts",
    "DifferentiableTask",
    "Env",
    "HasRatioMetrics",
    "HasTaskMetrics",
    "Manipulator",
    "Particle2D",
    "PlanarWorkspace",
    "RenderSettings",
    "Renders",
    "Rollout",
    "TimeVaryingAux",
    "collect",
    "dataset_meta",
    "load_dataset",
    "save_dataset",
]
