"""The straight reach of a start: the end-effector segment from the start to its goal, and how close it passes to the
obstacles (``scenes/crossing.py``: whether the obstacle is in the way of the reach)."""
from __future__ import annotations

from typing import Mapping

import torch
from torch import Tensor

from ...scenes import Scene
from ...scenes.crossing import segment_clearance


def end_effector_radius(robot) -> float:
    """The radius of the control sphere that carries the end effector: of the robot's control spheres, the one whose
    centre lies nearest the end-effector point at the robot's home configuration (a sphere moved along the straight
    path, it is what "the path crosses the obstacle" measures)."""
    p = robot.params
    home = torch.tensor([list(p.home)], dtype=torch.float64)
    ee = robot.ee_position(home)[0]
    links = sorted({cp.link for cp in p.control_points})
    poses = robot.chain.forward_kinematics(home, links)
    best, radius = float("inf"), 0.0
    for cp in p.control_points:
        R, t = poses[cp.link]
        centre = t[0] + R[0] @ torch.tensor(cp.offset, dtype=torch.float64)
        d = float((centre - ee).norm())
        if d < best:
            best, radius = d, float(cp.radius)
    return radius


def path_clearance(scene: Scene, ee_start: Tensor, aux: Mapping[str, Tensor]) -> Tensor:
    """(B, K) clearance of each straight reach ee_start[b] → aux["goal"][b] from each obstacle's surface (m)."""
    obstacles = {k: v.to(ee_start) for k, v in aux.items() if k != "goal"}
    return segment_clearance(scene, obstacles, ee_start, aux["goal"].to(ee_start))
