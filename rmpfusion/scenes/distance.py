"""The distance map of each obstacle of a scene, as a tree-spec map reading the obstacle's aux state.

The manipulator tree puts one of these under every control point, and the environment measures goal clearance
with the same maps, so the tree and the sampling agree on where an obstacle's surface is.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import torch
from torch import Tensor

from ..registry import TASK_MAPS
from .aux import SHAPE_AUX, scene_aux_dims
from .spec import Scene

#: the registered map measuring each shape; a vertical infinite cylinder (``cylinder_distance``) is the other choice
#: for a standing cylinder, conservative above its top
SHAPE_MAPS = {
    "sphere": "sphere_obstacle",
    "box": "box_obstacle",
    "cylinder": "cylinder_obstacle",
    "capsule": "capsule_obstacle",
}
_KEYS = {
    "half_extents": "half_extents",
    "rotation": "rotation",
    "axis": "axis",
    "half_height": "half_height",
    "half_length": "half_length",
}


def obstacle_map(k: int, shape: str, moving: bool, map_type: str | None = None) -> dict[str, Any]:
    """The map spec measuring the distance to obstacle ``k`` of this shape from its aux state."""
    pre = f"obstacle{k}_"
    map_type = map_type or SHAPE_MAPS[shape]
    spec: dict[str, Any] = {"type": map_type, "center": pre + "center"}
    if map_type == "cylinder_distance":  # the infinite vertical cylinder: centre and radius only, static
        if moving:
            raise ValueError(
                f"obstacle {k} moves, but cylinder_distance measures a static cylinder; use {SHAPE_MAPS['cylinder']}"
            )
        return {**spec, "radius": pre + "radius"}
    if shape != "box":
        spec["radius"] = pre + "radius"
    spec.update({key: pre + suffix for suffix, key in _KEYS.items() if suffix in SHAPE_AUX[shape]})
    if moving:
        spec["velocity"] = pre + "velocity"
    return spec


def distances(scene: Scene, aux: Mapping[str, Tensor], points: Tensor) -> Tensor:
    """(n, K) distance from each point (n, 3) to each obstacle of the scene (aux rows: one per point)."""
    dims = scene_aux_dims(scene)
    cols = []
    for k, o in enumerate(scene.obstacles, start=1):
        spec = obstacle_map(k, o.type, False)
        entry = TASK_MAPS.get(spec["type"])
        m = entry.obj(entry.validate({key: v for key, v in spec.items() if key != "type"}), 3, dims).to(points.dtype)
        cols.append(m.psi(points, aux))
    return torch.cat(cols, -1) if cols else points.new_zeros(points.shape[0], 0)
