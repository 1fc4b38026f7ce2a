"""Scenes (conf/scene/): obstacles of four shapes, static or moving, a ground plane, and their aux state; obstacle
sets whose members come and go between calls."""

from .aux import aux_at, obstacle_aux_names, scene_aux, scene_aux_dims
from .distance import SHAPE_MAPS, distances, obstacle_map
from .obstacle_set import SET_SHAPES, ObstacleSet
from .sets import SetsSource, every_shape, set_dims, sets_read, with_slots
from .spec import SHAPES, Box, Capsule, Cylinder, Ground, Scene, Sphere, same_layout
from .world import World, WorldError

__all__ = [
    "SET_SHAPES",
    "SHAPES",
    "SHAPE_MAPS",
    "Box",
    "Capsule",
    "Cylinder",
    "Ground",
    "ObstacleSet",
    "Scene",
    "SetsSource",
    "Sphere",
    "World",
    "WorldError",
    "aux_at",
    "distances",
    "every_shape",
    "obstacle_aux_names",
    "obstacle_map",
    "same_layout",
    "scene_aux",
    "scene_aux_dims",
    "set_dims",
    "sets_read",
    "with_slots",
]
