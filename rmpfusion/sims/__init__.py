"""Simulators as backends: the protocol every engine serves (``protocol.py``), the camera they render through,
the obstacles they build from a scene, the ``sim:`` block that picks one, and the built-in backends (pybullet,
MuJoCo), each importing its engine only when a world opens. Importing registers the built-ins."""

from .camera import Camera
from .config import DEFAULT_SIMULATOR, SimField, SimulatorParams, has_window, open_world
from .mjcf import MJCFDescription, MJCFRobot  # importing it registers the "mjcf" robot kind
from .mujoco_backend import MuJoCoWorld  # importing it registers "mujoco"
from .obstacles import obstacles_of, obstacles_of_sets
from .protocol import BACKGROUND, GOAL_MARKER, GROUND, ROBOT, Images, Obstacle, SimulationError, SimWorld, WorldSettings
from .pybullet_backend import PyBulletWorld  # importing it registers "pybullet"

__all__ = [
    "BACKGROUND",
    "DEFAULT_SIMULATOR",
    "GOAL_MARKER",
    "GROUND",
    "ROBOT",
    "Camera",
    "Images",
    "MJCFDescription",
    "MJCFRobot",
    "MuJoCoWorld",
    "Obstacle",
    "PyBulletWorld",
    "SimField",
    "SimWorld",
    "SimulationError",
    "SimulatorParams",
    "WorldSettings",
    "has_window",
    "obstacles_of",
    "obstacles_of_sets",
    "open_world",
]
