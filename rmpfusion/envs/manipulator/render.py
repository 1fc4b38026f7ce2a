"""Images of a manipulator scene for figures and animations, rendered offscreen by the environment's simulator
through the fixed camera of its settings, and the projection of world points into those images (to draw paths on
them)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import torch
from torch import Tensor

from ...scenes import Scene
from ...sims import Camera, Images
from .params import Vec3
from .worlds import TaskWorld, sample_aux

CameraSetting = tuple[float, float, float, Vec3]  # distance, yaw, pitch (deg), target: ManipulatorParams.camera


def camera_of(setting: CameraSetting) -> Camera:
    """The camera of ``ManipulatorParams.camera``."""
    distance, yaw, pitch, target = setting
    return Camera(distance, yaw, pitch, (target[0], target[1], target[2]))


def images(
    world: TaskWorld,
    scene: Scene,
    q: Tensor | Sequence[float],
    aux: Mapping[str, Tensor],
    camera: Camera,
    width: int = 320,
    height: int = 240,
    sample: int = 0,
) -> Images:
    """Colour, depth and segmentation of the robot at ``q`` (one configuration, or one per sample) in environment
    ``aux[sample]`` of ``scene``, rendered by ``world`` through ``camera``."""
    q = torch.as_tensor(q, dtype=torch.float64).reshape(-1, world.robot.dof)
    qb = q[min(sample, q.shape[0] - 1)]
    aux = {k: torch.as_tensor(v).reshape(-1, torch.as_tensor(v).shape[-1]) for k, v in aux.items()}
    world.set_env(scene, sample_aux(aux, sample))
    world.reset(qb.cpu().numpy())
    return world.sim.render(camera, width, height)


def project(setting: CameraSetting, points, width: int = 320, height: int = 240) -> np.ndarray:
    """(N, 2) pixel coordinates (column, row) of world points (N, 3) in ``images``' pictures."""
    return camera_of(setting).project(points, width, height)
