"""A depth camera through the simulator protocol: back-projection inverts the camera's projection, the clouds of
pybullet and MuJoCo lie on the obstacles' surfaces with the robot's, the ground's and the goal marker's points
removed, noise is seeded, and the manipulator environment's ``point_cloud`` sees its scene."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from conftest import needs_mujoco_rendering
from manipulators import robot

from rmpfusion.envs.manipulator.sensing import DepthCameraParams, cloud_of
from rmpfusion.robots import RobotDescription, build_robot
from rmpfusion.sims import ROBOT, Camera, Obstacle, SimulatorParams, WorldSettings, open_world

pytest.importorskip("pybullet")
pytest.importorskip("mujoco")

CAMERA = Camera(1.5, 60.0, -25.0, (0.45, 0.0, 0.3))
SPHERE, CYLINDER = (np.array([0.6, 0.25, 0.35]), 0.08), (np.array([0.55, -0.15, 0.3]), 0.06, 0.3)


def _surface_distance(points: np.ndarray) -> np.ndarray:
    """Each point's distance to the nearer of the two obstacles' surfaces (signed: < 0 inside)."""
    (cs, rs), (cc, rc, hc) = SPHERE, CYLINDER
    sphere = np.linalg.norm(points - cs, axis=1) - rs
    rel = points - cc
    radial, axial = np.linalg.norm(rel[:, :2], axis=1) - rc, np.abs(rel[:, 2]) - hc
    cylinder = np.hypot(np.maximum(radial, 0), np.maximum(axial, 0)) + np.minimum(np.maximum(radial, axial), 0)
    return np.where(np.abs(sphere) < np.abs(cylinder), sphere, cylinder)


def test_back_projection_inverts_the_projection():
    """Every pixel of a random depth image back-projects to a point that projects onto that pixel's centre, at that
    depth along the optical axis (1e-9); pixels without a return are NaN."""
    g = np.random.default_rng(0)
    width, height = 64, 48
    depth = 0.5 + 2.0 * g.random((height, width))
    depth[3, 5] = np.inf
    points = CAMERA.points(depth)
    seen = np.isfinite(depth)
    assert np.isnan(points[~seen]).all() and np.isfinite(points[seen]).all()
    pixels = CAMERA.project(points[seen], width, height)
    rows, cols = np.nonzero(seen)
    np.testing.assert_allclose(pixels, np.c_[cols + 0.5, rows + 0.5], atol=1e-9)
    along = -(np.c_[points[seen], np.ones(seen.sum())] @ CAMERA.view_matrix().T)[:, 2]
    np.testing.assert_allclose(along, depth[seen], atol=1e-9)


@pytest.mark.parametrize("sim", ["pybullet", "mujoco"])
def test_the_cloud_lies_on_the_obstacles_and_not_on_the_robot(sim):
    """The Panda in view beside a sphere and a cylinder on the ground: every cloud point within 1.5 cm of an obstacle's
    surface (pybullet's tessellated spheres sit up to 1.4 cm inside), both obstacles seen, and the robot's pixels in
    the image but none of them in the cloud."""
    if sim == "mujoco":
        needs_mujoco_rendering()
    r = build_robot(RobotDescription.model_validate(robot("panda")))
    world = open_world(r, WorldSettings(pictures=True), SimulatorParams(type=sim))
    try:
        world.set_obstacles(
            [
                Obstacle("sphere", SPHERE[0], radius=SPHERE[1]),
                Obstacle("cylinder", CYLINDER[0], np.eye(3), radius=CYLINDER[1], half_length=CYLINDER[2]),
            ]
        )
        world.set_ground(0.0)
        world.set_goal_marker(np.array([0.5, 0.0, 0.5]))
        world.reset(np.array([*r.params.home, 0.0, 0.0]), np.zeros(9))
        images = world.render(CAMERA, 160, 120)
        assert (images.segmentation == ROBOT).sum() > 200
        cloud = cloud_of(images, CAMERA)
        d = _surface_distance(cloud)
        assert np.abs(d).max() < 0.015, np.abs(d).max()
        on_sphere = np.linalg.norm(cloud - SPHERE[0], axis=1) < SPHERE[1] + 0.02
        assert on_sphere.sum() > 50 and (~on_sphere).sum() > 50
    finally:
        world.close()


def test_depth_noise_is_seeded_and_scales_the_error():
    needs_mujoco_rendering()
    r = build_robot(RobotDescription.model_validate(robot("panda")))
    world = open_world(r, WorldSettings(pictures=True), SimulatorParams(type="mujoco"))
    try:
        world.set_obstacles([Obstacle("sphere", SPHERE[0], radius=SPHERE[1])])
        world.reset(np.array([*r.params.home, 0.0, 0.0]), np.zeros(9))
        images = world.render(CAMERA, 160, 120)
        a = cloud_of(images, CAMERA, noise=0.01, rng=np.random.default_rng(3))
        b = cloud_of(images, CAMERA, noise=0.01, rng=np.random.default_rng(3))
        clean = cloud_of(images, CAMERA)
        np.testing.assert_array_equal(a, b)
        spread = np.linalg.norm(a - clean, axis=1)
        assert 0.005 < float(np.median(spread)) < 0.02  # |N(0, 1 cm)| along the ray, a little more off-axis
    finally:
        world.close()


def test_the_environment_point_cloud_sees_its_scene():
    """experiment=franka's env: the camera of ``env.depth_camera`` sees the test split's cylinder (its aux: centre,
    radius, half height), every point on its surface."""
    from manipulators import franka_env

    env = franka_env(depth_camera=DepthCameraParams(width=120, height=90).model_dump())
    try:
        g = torch.Generator().manual_seed(0)
        q0, _, aux = env.sample_initial_states(env.sample_envs(1, g), 1, g)
        cloud = env.point_cloud(q0[0], aux).numpy()
        c = aux["obstacle1_center"][0].numpy()
        radius, half = float(aux["obstacle1_radius"][0, 0]), float(aux["obstacle1_half_height"][0, 0])
        rel = cloud - c
        radial, axial = np.linalg.norm(rel[:, :2], axis=1) - radius, np.abs(rel[:, 2]) - half
        d = np.hypot(np.maximum(radial, 0), np.maximum(axial, 0)) + np.minimum(np.maximum(radial, axial), 0)
        assert len(cloud) > 30 and np.abs(d).max() < 0.015
    finally:
        env.close()
