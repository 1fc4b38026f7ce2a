"""The simulator protocol: what rmpfusion asks of a physics engine, and nothing more.

A ``SimWorld`` holds one robot (loaded from its resolved URDF on a fixed base at its mount), the obstacles of a scene
as preallocated slots, a ground plane and a goal marker. The task (sampling starts, rollouts, collisions, metrics,
figures) talks to simulators through this class alone, so pybullet, MuJoCo and a plugin's engine are
interchangeable (``sim: {type: <name>}`` in the environment's config, ``rmpfusion.registry.SIMULATORS``).

Joint vectors are the robot's simulated joints in one order: the actuated joints (the configuration q), then the
held ones (``URDFRobot.held_joints``: mimic followers and fingers). Torques are generalised forces on those joints.
A backend raises ``SimulationError`` for a world that broke; the task ends that sample with the message and goes on.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import ClassVar, Literal

import numpy as np

from ..registry import Params as ParameterModel
from ..robots import URDFRobot
from .camera import Camera

#: segmentation labels of ``Images.segmentation``: obstacle slot k (from 0) reads k + 1
BACKGROUND, ROBOT, GROUND, GOAL_MARKER = -1, 0, -2, -3

ShapeKind = Literal["sphere", "box", "cylinder", "capsule"]


class SimulationError(RuntimeError):
    """A world that failed (the engine refused a call or its state broke): the sample it served ends here."""


@dataclass(frozen=True)
class Obstacle:
    """One obstacle's geometry in the world frame, as every backend builds it.

    ``rotation`` turns the shape's own frame into the world's: a box's axes, or z onto a cylinder's or capsule's
    axis. ``half_length`` is a cylinder's half height or a capsule's segment half length (caps excluded)."""

    kind: ShapeKind
    center: np.ndarray  # (3,)
    rotation: np.ndarray = field(default_factory=lambda: np.eye(3))  # (3, 3)
    radius: float = 0.0
    half_extents: tuple[float, float, float] = (0.0, 0.0, 0.0)
    half_length: float = 0.0


@dataclass(frozen=True)
class Images:
    """One offscreen render: colour (H, W, 3) uint8, depth along the optical axis (H, W) in metres (``inf`` where
    nothing is hit), and segmentation (H, W) int labels (``ROBOT``, ``GROUND``, ``GOAL_MARKER``, ``BACKGROUND``,
    obstacle slot k as k + 1)."""

    rgb: np.ndarray
    depth: np.ndarray
    segmentation: np.ndarray


@dataclass(frozen=True)
class WorldSettings:
    """What every world of an environment shares: gravity (m/s², along z), the step (s), whether a window shows
    it (a backend without a viewer refuses ``gui``), and whether the world is for pictures (obstacles, ground and
    goal marker drawn, a floor under the robot that never collides; a world that only checks collisions skips
    drawing them where its engine allows)."""

    gravity: float = -9.81
    timestep: float = 1.0 / 240.0
    gui: bool = False
    pictures: bool = False


class SimWorld(ABC):
    """One simulated world. Subclasses register with ``rmpfusion.registry.SIMULATORS`` and take
    ``(robot, settings, params)``, ``params`` being their own ``Params`` model (``sim:`` block of the config)."""

    Params: type[ParameterModel]
    #: whether ``settings.gui`` can show the world in a window (checked when an environment's config is validated)
    has_window: ClassVar[bool] = False

    def __init__(self, robot: URDFRobot, settings: WorldSettings, params: ParameterModel):
        self.robot, self.settings, self.params = robot, settings, params

    # ---------------------------------------------------------------- the scene
    @abstractmethod
    def set_obstacles(self, obstacles: Sequence[Obstacle]) -> None:
        """Make the world's obstacles exactly ``obstacles``, slot k for ``obstacles[k]``: slots are added, resized,
        reshaped or removed as needed (a backend may rebuild its model when the shapes change, never when only
        sizes or poses do)."""

    @abstractmethod
    def move_obstacle(self, slot: int, center: np.ndarray) -> None:
        """Put obstacle ``slot``'s centre at ``center``, keeping its orientation (moving obstacles)."""

    @abstractmethod
    def set_ground(self, height: float | None) -> None:
        """A ground plane (collides with the robot) at ``height``, or none."""

    @abstractmethod
    def set_goal_marker(self, position: np.ndarray | None) -> None:
        """A small sphere at the goal, seen by renders only (never collides), or none."""

    # ---------------------------------------------------------------- the robot
    @abstractmethod
    def reset(self, q: np.ndarray, qd: np.ndarray) -> None:
        """Set every simulated joint's position and velocity (actuated, then held), forces cleared."""

    @abstractmethod
    def state(self) -> tuple[np.ndarray, np.ndarray]:
        """(positions, velocities) of every simulated joint, actuated then held."""

    @abstractmethod
    def inverse_dynamics(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
        """Joint torques that give accelerations ``qdd`` at (q, q̇) with no contact: M(q) q̈ + C(q, q̇) q̇ + g(q)."""

    @abstractmethod
    def step(self, torque: np.ndarray) -> None:
        """Apply ``torque`` to the simulated joints for one step of ``settings.timestep`` and advance."""

    # ---------------------------------------------------------------- geometry
    @abstractmethod
    def obstacle_distance(self, query: float) -> float:
        """Smallest signed distance between any robot link and any obstacle (< 0: penetration), or ``query`` when
        nothing is nearer than that."""

    @abstractmethod
    def ground_distance(self, link: str, query: float) -> float:
        """Signed distance between the link named ``link`` and the ground plane, or ``query`` when farther (or
        when there is no ground)."""

    @abstractmethod
    def link_frames(self) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """Link name -> (position (3,), rotation (3, 3)) of every link's frame in the world at the current
        configuration: what kinematics are checked against."""

    @abstractmethod
    def link_boxes(self) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """Link name -> (lower, upper) corners of the world-axis box around its collision shapes, for every link
        that has one, at the current configuration."""

    # ---------------------------------------------------------------- pictures and the end
    @abstractmethod
    def render(self, camera: Camera, width: int, height: int) -> Images:
        """Colour, depth and segmentation seen through ``camera`` (``sims/camera.py``), offscreen."""

    @abstractmethod
    def close(self) -> None:
        """Release the engine's resources; closing twice is harmless."""
