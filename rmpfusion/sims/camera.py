"""The camera every backend renders through, and the projection of world points into its images.

One convention (z up, an orbit around a target: distance, yaw and pitch in degrees, a vertical field of view)
with its view and projection matrices computed here in numpy, so that paths are drawn onto a render the same way
whichever simulator made it (``project``)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

#: near and far clipping planes (m) of every render
NEAR, FAR = 0.05, 10.0


@dataclass(frozen=True)
class Camera:
    """Orbit camera: it looks at ``target`` from ``distance`` metres, turned ``yaw`` degrees about z and tilted
    ``pitch`` degrees (negative: looking down), with a vertical field of view of ``fov`` degrees."""

    distance: float
    yaw: float
    pitch: float
    target: tuple[float, float, float]
    fov: float = 60.0

    def forward(self) -> np.ndarray:
        """The unit viewing direction (from the eye to the target)."""
        y, p = math.radians(self.yaw), math.radians(self.pitch)
        return np.array([-math.sin(y) * math.cos(p), math.cos(y) * math.cos(p), math.sin(p)])

    def eye(self) -> np.ndarray:
        return np.asarray(self.target, dtype=float) - self.distance * self.forward()

    def view_matrix(self) -> np.ndarray:
        """4×4 world-to-camera matrix (OpenGL: the camera looks along −z, y up)."""
        f = self.forward()
        side = np.cross(f, [0.0, 0.0, 1.0])
        side /= np.linalg.norm(side)
        up = np.cross(side, f)
        R = np.stack([side, up, -f])
        V = np.eye(4)
        V[:3, :3] = R
        V[:3, 3] = -R @ self.eye()
        return V

    def projection_matrix(self, width: int, height: int) -> np.ndarray:
        """4×4 OpenGL perspective matrix of the field of view at the image's aspect ratio."""
        f = 1.0 / math.tan(math.radians(self.fov) / 2)
        P = np.zeros((4, 4))
        P[0, 0], P[1, 1] = f / (width / height), f
        P[2, 2], P[2, 3] = (FAR + NEAR) / (NEAR - FAR), 2 * FAR * NEAR / (NEAR - FAR)
        P[3, 2] = -1.0
        return P

    def project(self, points, width: int, height: int) -> np.ndarray:
        """(N, 2) pixel coordinates (column, row) of world points (N, 3) in a ``width``×``height`` image."""
        pts = np.asarray(points, dtype=float).reshape(-1, 3)
        clip = (self.projection_matrix(width, height) @ self.view_matrix() @ np.c_[pts, np.ones(len(pts))].T).T
        ndc = clip[:, :3] / clip[:, 3:4]
        return np.stack([(ndc[:, 0] + 1) / 2 * width, (1 - ndc[:, 1]) / 2 * height], 1)

    def points(self, depth: np.ndarray) -> np.ndarray:
        """(H, W, 3) world points seen at each pixel's centre of a depth image (H, W) taken through this camera
        (depth along the optical axis, m); NaN where the depth is not finite (nothing hit). The inverse of
        ``project`` at that depth."""
        seen = np.isfinite(depth)
        depth = np.where(seen, depth, 0.0)
        height, width = depth.shape
        cols, rows = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
        x_ndc, y_ndc = cols / width * 2 - 1, 1 - rows / height * 2
        P = self.projection_matrix(width, height)
        camera = np.stack([x_ndc * depth / P[0, 0], y_ndc * depth / P[1, 1], -depth, np.ones_like(depth)], -1)
        world = camera.reshape(-1, 4) @ np.linalg.inv(self.view_matrix()).T
        out = world[:, :3].reshape(height, width, 3)
        out[~seen] = np.nan
        return out


def linear_depth(buffer: np.ndarray) -> np.ndarray:
    """Metric depth (m) from an OpenGL depth buffer in [0, 1] of the ``NEAR``/``FAR`` projection; ``inf`` at the
    far plane (nothing hit)."""
    z = NEAR * FAR / (FAR - (FAR - NEAR) * np.asarray(buffer, dtype=float))
    return np.where(np.asarray(buffer) >= 1.0, np.inf, z)
