"""Environments; importing this package registers them in ``rmpfusion.registry.ENVS``."""

from . import manipulator_tree  # noqa: F401  (registers the tree generator fig1b)
from .demonstrations import Dataset, DatasetError, collect, dataset_meta, load_dataset, save_dataset  # noqa: F401
from .manipulator import Manipulator  # noqa: F401
from .particle2d import Particle2D  # noqa: F401
from .protocol import (
    DifferentiableRollouts,
    Env,
    HasRatioMetrics,
    HasTaskMetrics,
    PlanarWorkspace,  # noqa: F401
    Renders,
    RenderSettings,
    TimeVaryingAux,
)
from .rollout import Rollout  # noqa: F401
