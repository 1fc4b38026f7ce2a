"""Scenes (conf/scene/): obstacles of four shapes, static or moving, a ground plane, and their aux state; obstacle
sets whose members come and go between calls."""

from .aux import aux_at, obstacle_aux_names, scene_aux, scene_aux_dims  # noqa: F401
from .distance import SHAPE_MAPS, distances, obstacle_map  # noqa: F401
from .sets import SET_SHAPES, ObstacleSet, every_shape, set_dims, with_slots  # noqa: F401
from .spec import SHAPES, Box, Capsule, Cylinder, Ground, Scene, Sphere, same_layout  # noqa: F401
from .world import World, WorldError  # noqa: F401
