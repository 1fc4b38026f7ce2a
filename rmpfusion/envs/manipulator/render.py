"""Images of a manipulator scene for figures and animations: pybullet's headless tiny renderer through a fixed
camera, and the projection of world points into those images (to draw paths on them)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING

import numpy as np
import torch
from torch import Tensor

from .params import Vec3
from .scene import _pb, sample_aux

if TYPE_CHECKING:
    from .env import Manipulator

Camera = tuple[float, float, float, Vec3]  # distance, yaw, pitch (deg), target: ManipulatorParams.camera


def render(
    env: Manipulator,
    q: Tensor | Sequence[float],
    aux: Mapping[str, Tensor],
    width: int = 320,
    height: int = 240,
    sample: int = 0,
) -> np.ndarray:
    """(height, width, 3) uint8 image of the robot at ``q`` in environment ``aux[sample]``."""
    p = _pb()
    q = torch.as_tensor(q, dtype=env.dtype).reshape(-1, env.dim)
    qb = q[min(sample, q.shape[0] - 1)]
    sc = env.worlds.renderer()
    aux = {k: torch.as_tensor(v).reshape(-1, torch.as_tensor(v).shape[-1]) for k, v in aux.items()}
    sc.set_env(env.scene, sample_aux(aux, sample), visual=True)
    sc.reset(qb.cpu().numpy())
    view, proj = camera_matrices(env.params.camera, width, height)
    img = p.getCameraImage(width, height, view, proj, renderer=p.ER_TINY_RENDERER, physicsClientId=sc.cid)
    rgba = np.asarray(img[2], dtype=np.uint8).reshape(height, width, 4)
    return np.ascontiguousarray(rgba[..., :3])


def camera_matrices(camera: Camera, width: int, height: int) -> tuple[list[float], list[float]]:
    """pybullet's (view, projection) matrices of the camera, column-major (OpenGL)."""
    p = _pb()
    dist, yaw, pitch, target = camera
    view = p.computeViewMatrixFromYawPitchRoll(list(target), dist, yaw, pitch, 0.0, 2)
    proj = p.computeProjectionMatrixFOV(60.0, width / height, 0.05, 10.0)
    return list(view), list(proj)


def project(camera: Camera, points, width: int = 320, height: int = 240) -> np.ndarray:
    """(N, 2) pixel coordinates (column, row) of world points (N, 3) in ``render``'s image."""
    view, proj = camera_matrices(camera, width, height)
    V = np.asarray(view, dtype=float).reshape(4, 4).T  # pybullet matrices are column-major (OpenGL)
    P = np.asarray(proj, dtype=float).reshape(4, 4).T
    pts = np.asarray(points, dtype=float).reshape(-1, 3)
    clip = (P @ V @ np.concatenate([pts, np.ones((len(pts), 1))], 1).T).T
    ndc = clip[:, :3] / clip[:, 3:4]
    return np.stack([(ndc[:, 0] + 1) / 2 * width, (1 - ndc[:, 1]) / 2 * height], 1)
