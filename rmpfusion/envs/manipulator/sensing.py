"""A depth camera in the manipulator's world: what it sees as a point cloud, through whichever simulator the
environment runs (``rmpfusion.sims``: every backend renders depth and segmentation through one camera model).

The cloud is the depth image back-projected to world points (``Camera.points``), with optional Gaussian noise on
the depth, and without the points the robot needs no barrier for: its own (the self-filter a real arm runs on the
segmentation its URDF gives), the ground's (a table-plane filter: the scene's ground plane has a leaf of its own) and
the goal marker's. Nothing else is known to the cloud: an obstacle is whatever surface the camera sees.
``scenes/clouds.py`` turns a cloud into the members of a sphere obstacle set.
"""

from __future__ import annotations

import numpy as np
from pydantic import Field

from ...registry import Params
from ...sims import BACKGROUND, GOAL_MARKER, GROUND, ROBOT, Camera, Images

Vec3 = tuple[float, float, float]


class DepthCameraParams(Params):
    """A depth camera fixed in the world."""

    pose: tuple[float, float, float, Vec3] = Field(
        (1.5, 60.0, -25.0, (0.45, 0.0, 0.3)),
        description="distance (m), yaw, pitch (deg) and the point it looks at (m), as env.camera",
    )
    fov: float = Field(60.0, gt=0, lt=180, description="vertical field of view (deg)")
    width: int = Field(160, ge=1, le=4096, description="pixels")
    height: int = Field(120, ge=1, le=4096, description="pixels")
    rate: float = Field(30.0, gt=0, description="frames per second")
    noise: float = Field(0.0, ge=0, description="standard deviation of Gaussian noise on each depth (m)")
    latency: float = Field(0.0, ge=0, description="a frame reaches the controller this long after it is taken (s)")
    seed: int = Field(0, ge=0, description="of the depth noise")

    def camera(self) -> Camera:
        distance, yaw, pitch, target = self.pose
        return Camera(distance, yaw, pitch, (target[0], target[1], target[2]), fov=self.fov)


#: segmentation labels whose points are not obstacles
NOT_OBSTACLES = (ROBOT, GROUND, GOAL_MARKER, BACKGROUND)


def cloud_of(images: Images, camera: Camera, noise: float = 0.0, rng: np.random.Generator | None = None) -> np.ndarray:
    """(P, 3) world points of the obstacles in ``images`` (taken through ``camera``): every pixel with a finite depth
    that is not the robot, the ground or the goal marker, its depth perturbed by N(0, noise²)."""
    depth = images.depth
    if noise > 0:
        depth = depth + (rng if rng is not None else np.random.default_rng()).normal(0.0, noise, depth.shape)
    keep = np.isfinite(depth) & ~np.isin(images.segmentation, NOT_OBSTACLES)
    return camera.points(np.where(keep, depth, np.inf))[keep]
