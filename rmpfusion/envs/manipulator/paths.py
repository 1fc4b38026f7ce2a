"""The straight reach of a start: the end-effector segment from the start to its goal, and how close it passes to the
obstacles (``scenes/crossing.py``: whether the obstacle is in the way of the reach)."""

from __future__ import annotations

from collections.abc import Mapping

import torch
from torch import Tensor

from ...scenes import Scene
from ...scenes.crossing import segment_clearance


def end_effector_radius(robot) -> float:
    """The radius of the control sphere that carries the end effector: of the robot's control spheres, the one whose
    centre lies nearest the end-effector point at the robot's home configuration (a sphere moved along the straight
    path, it is what "the path crosses the obstacle" measures)."""
    if not robot.params.control_points:
        return 0.0
    home = torch.tensor([list(robot.params.home)], dtype=torch.float64)
    distance = (robot.sphere_centres(home)[0] - robot.ee_position(home)[0]).norm(dim=-1)
    return float(robot.params.control_points[int(distance.argmin())].radius)


def path_clearance(scene: Scene, ee_start: Tensor, aux: Mapping[str, Tensor]) -> Tensor:
    """(B, K) clearance of each straight reach ee_start[b] → aux["goal"][b] from each obstacle's surface (m)."""
    obstacles = {k: v.to(ee_start) for k, v in aux.items() if k != "goal"}
    return segment_clearance(scene, obstacles, ee_start, aux["goal"].to(ee_start))
