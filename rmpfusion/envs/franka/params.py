"""The Franka environment's settings: the scene (cylinders, goals, starts), the two rollout modes, the
demonstrations' length, and how figures render; validated when the environment is built from YAML."""
from __future__ import annotations

from typing import Literal

from pydantic import Field, model_validator

from ...registry import Params

Vec3 = tuple[float, float, float]
Range = tuple[float, float]


class ObstacleSpec(Params):
    center: Vec3
    radius: float = Field(gt=0)
    height: float = Field(0.5, gt=0)


class FrankaParams(Params):
    gui: bool = Field(False, description="open pybullet's GUI for the first torque-mode world (else DIRECT)")
    mode: Literal["torque", "kinematic"] = Field(
        "kinematic", description="how rollouts run policies (evaluation); torque = pybullet, computed torque")
    collect_mode: Literal["torque", "kinematic"] = Field(
        "kinematic", description="how the expert's demonstrations are rolled out (kinematic: batched, fast)")
    control_rate: float = Field(240.0, gt=0, description="Hz; the pybullet/integration step is 1/control_rate")
    integrator: Literal["semi_implicit_euler", "rk4"] = Field(
        "semi_implicit_euler", description="kinematic mode; semi-implicit Euler is what pybullet uses")
    gravity: float = -9.81
    obstacles: list[ObstacleSpec] = Field(
        default_factory=lambda: [ObstacleSpec(center=(0.5, 0.0, 0.25), radius=0.06, height=0.5)],
        description="nominal cylinders (standing, axis z); their number is n_obstacles")
    test_obstacles: list[ObstacleSpec] | None = Field(
        None, description="the test split's cylinders (paper: a different placement); null = the same as obstacles")
    obstacle_jitter: Vec3 = Field((0.0, 0.0, 0.0), description="± uniform perturbation of every centre per env")
    goal_per_trajectory: bool = Field(
        True, description="draw a goal per trajectory (paper §4.2); else one goal per environment")
    min_start_goal_distance: float = Field(0.0, ge=0, description="starts whose end effector is closer are redrawn")
    demo_min_duration: float = Field(5.0, ge=0, description="demonstrations last at least this long (s) ...")
    demo_settle_distance: float = Field(0.01, gt=0, description="... and end once the end effector is this close "
                                                                 "to the goal (m) ...")
    demo_settle_speed: float = Field(0.05, gt=0, description="... with joint speed ‖q̇‖ below this (rad/s); "
                                                              "at most data.points records")
    goal_region: tuple[Range, Range, Range] = Field(((0.3, 0.6), (-0.45, -0.2), (0.15, 0.55)),
                                                    description="goal ~ uniform in this box (m)")
    goal_clearance: float = Field(0.15, ge=0, description="min horizontal distance from goal to obstacle surfaces")
    nominal_q: tuple[float, ...] = Field((0.6, -0.3, 0.0, -2.2, 0.0, 2.0, 0.785), description="centre of the starts")
    start_spread: tuple[float, ...] = Field((0.3, 0.3, 0.3, 0.3, 0.3, 0.3, 0.3), description="± uniform per joint")
    start_speed: float = Field(0.0, ge=0, description="initial joint speeds ~ uniform in ±start_speed")
    start_clearance: float = Field(0.05, ge=0, description="min pybullet clearance of the start configuration")
    joint_margin: float = Field(0.05, ge=0, description="starts stay this far inside the URDF limits (rad)")
    goal_tolerance: float = Field(0.05, gt=0)
    clearance_query: float = Field(0.3, gt=0, description="distances beyond this are not resolved")
    max_tries: int = Field(200, ge=1)
    camera: tuple[float, float, float, Vec3] = Field((1.2, -20.0, -50.0, (0.3, 0.0, 0.3)),
                                                     description="render: distance, yaw, pitch (deg), target")
    render_size: tuple[int, int] = Field((320, 240), description="figures: width, height of a rendered frame")
    render_times: tuple[float, ...] = Field((0.0, 1.0, 2.0, 3.0, 5.0, 10.0),
                                            description="figures: times (s) of the frames of the render strip")
    render_trajectory: int | None = Field(
        None, ge=0, description="figures: the test trajectory rendered; null = the one where the expert comes "
                                "closest to the obstacle")
    gif_fps: float = Field(10.0, gt=0, description="figures: frames per second of the execution GIF (real time)")
    dtype: Literal["float64", "float32"] = "float64"

    @model_validator(mode="after")
    def _shapes(self):
        for name in ("nominal_q", "start_spread"):
            if len(getattr(self, name)) != 7:
                raise ValueError(f"{name} needs 7 values (one per joint)")
        for axis, r in zip("xyz", self.goal_region):
            if not r[0] <= r[1]:
                raise ValueError(f"goal_region.{axis}: low {r[0]} is above high {r[1]}")
        if self.test_obstacles is not None and len(self.test_obstacles) != len(self.obstacles):
            raise ValueError(f"test_obstacles has {len(self.test_obstacles)} cylinders but obstacles has "
                             f"{len(self.obstacles)}: the tree has one distance node per obstacle")
        return self
