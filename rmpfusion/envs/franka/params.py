"""The Franka environment's settings: the scene (cylinders, goals, starts), the two rollout modes, the
demonstrations' length, and how figures render; validated when the environment is built from YAML."""
from __future__ import annotations

import functools
from typing import Literal

from pydantic import Field, ValidationInfo, field_validator

from ...maps.urdf import PANDA_ARM_JOINTS, load_panda_urdf_path, parse_urdf
from ...registry import Params

Vec3 = tuple[float, float, float]
Range = tuple[float, float]


class ObstacleSpec(Params):
    center: Vec3
    radius: float = Field(gt=0)
    height: float = Field(0.5, gt=0)


@functools.lru_cache(maxsize=1)
def panda_limits() -> tuple[tuple[float, float], ...]:
    """(lower, upper) of panda_joint1..7 in the URDF the environment simulates (rad)."""
    model = parse_urdf(load_panda_urdf_path())
    return tuple((model.joint(n).lower, model.joint(n).upper) for n in PANDA_ARM_JOINTS)


def _per_joint(name: str, v: tuple[float, ...]) -> None:
    if len(v) != 7:
        raise ValueError(f"{name} needs 7 values (one per joint); given {len(v)}: {list(v)}")


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

    def integration_step(self) -> tuple[float, str]:
        """(seconds, the key that sets it) of the step rollouts integrate and pybullet steps on: a run config's
        recording interval and horizon are checked against it before anything runs (``time_grid`` at rollout time)."""
        return 1.0 / self.control_rate, "1/env.control_rate"

    @field_validator("test_obstacles")
    @classmethod
    def _as_many_as_obstacles(cls, v: list[ObstacleSpec] | None, info: ValidationInfo):
        nominal = info.data.get("obstacles")
        if v is not None and nominal is not None and len(v) != len(nominal):
            raise ValueError(f"test_obstacles has {len(v)} cylinders but obstacles has {len(nominal)}: the tree has "
                             f"one distance node per obstacle")
        return v

    @field_validator("obstacle_jitter", "start_spread")
    @classmethod
    def _half_widths(cls, v: tuple[float, ...], info: ValidationInfo):
        if info.field_name == "start_spread":
            _per_joint("start_spread", v)
        if not all(x >= 0 for x in v):
            raise ValueError(f"{info.field_name} must be ≥ 0 in every entry (each is the half-width of a uniform "
                             f"± perturbation); given {list(v)}")
        return v

    @field_validator("goal_region")
    @classmethod
    def _box(cls, v: tuple[Range, Range, Range]):
        for axis, r in zip("xyz", v):
            if not r[0] <= r[1]:
                raise ValueError(f"goal_region.{axis} must be (low, high) with low ≤ high (goals are drawn uniformly "
                                 f"between them); given {tuple(r)}")
        return v

    @field_validator("nominal_q")
    @classmethod
    def _inside_the_limits(cls, v: tuple[float, ...]):
        _per_joint("nominal_q", v)
        for k, (q, (lo, hi)) in enumerate(zip(v, panda_limits())):
            if not lo <= q <= hi:
                raise ValueError(f"nominal_q[{k}] must lie within {PANDA_ARM_JOINTS[k]}'s limits [{lo}, {hi}] (starts "
                                 f"are drawn around it and clamped to the limits); given {q}")
        return v

    @field_validator("joint_margin")
    @classmethod
    def _room_inside_the_limits(cls, v: float, info: ValidationInfo):
        nominal = info.data.get("nominal_q")  # absent when it was refused itself
        for k, (lo, hi) in enumerate(panda_limits()):
            if not lo + v < hi - v:
                raise ValueError(f"joint_margin must be < half of every joint's range (starts are drawn in "
                                 f"[lower + margin, upper − margin]); {PANDA_ARM_JOINTS[k]} spans [{lo}, {hi}], "
                                 f"half of it is {(hi - lo) / 2:.4g}; given {v}")
            if nominal is not None and not lo + v <= nominal[k] <= hi - v:
                raise ValueError(f"joint_margin puts nominal_q[{k}] = {nominal[k]} outside the start range of "
                                 f"{PANDA_ARM_JOINTS[k]} [{lo} + margin, {hi} − margin] (every start would be "
                                 f"clamped to its edge); move nominal_q inward or lower joint_margin; given {v}")
        return v

    @field_validator("camera")
    @classmethod
    def _in_front(cls, v):
        if not v[0] > 0:
            raise ValueError(f"camera distance (the first entry) must be > 0 (the camera looks at the target from "
                             f"that far); given {v[0]}")
        return v

    @field_validator("render_size")
    @classmethod
    def _pixels(cls, v: tuple[int, int]):
        if not (v[0] >= 1 and v[1] >= 1):
            raise ValueError(f"render_size must be ≥ 1 pixel in width and height; given {tuple(v)}")
        return v

    @field_validator("render_times")
    @classmethod
    def _times(cls, v: tuple[float, ...]):
        if not all(t >= 0 for t in v):
            raise ValueError(f"render_times must all be ≥ 0 (times into a rollout, in s); given {list(v)}")
        return v
