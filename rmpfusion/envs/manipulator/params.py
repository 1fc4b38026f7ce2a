"""The manipulator environment's settings: the robot and the scenes (conf/robot/, conf/scene/), goals and starts,
the two rollout modes, the demonstrations' length, and how figures render; validated when the environment is built
from YAML."""

from __future__ import annotations

from typing import Literal

from pydantic import Field, ValidationInfo, field_validator, model_validator

from ...registry import Params
from ...robots import RobotField
from ...scenes import Scene, same_layout
from ...sims import SimField, SimulatorParams, has_window
from .layout import ReachLayout
from .sensing import DepthCameraParams

Vec3 = tuple[float, float, float]
Range = tuple[float, float]


def _per_joint(name: str, v: tuple[float, ...] | float, info: ValidationInfo) -> tuple[float, ...]:
    """One value per actuated joint (a single number is every joint's)."""
    robot = info.data.get("robot")
    n = len(robot.joints) if robot is not None else None
    if isinstance(v, (int, float)):
        return (float(v),) * (n or 1)
    if robot is not None and len(v) != n:
        raise ValueError(
            f"{name} needs one value per actuated joint ({n}: {', '.join(robot.joints)}); given {len(v)}: {list(v)}"
        )
    return tuple(v)


class ManipulatorParams(Params):
    sim: SimField = Field(
        default_factory=SimulatorParams,
        description="the simulator rollouts, collision checks and renders run in (conf/sim/: pybullet, mujoco, a "
        "plugin's)",
    )
    gui: bool = Field(False, description="show the first torque-mode world in the simulator's window")
    mode: Literal["torque", "kinematic"] = Field(
        "kinematic", description="how rollouts run policies (evaluation); torque = the simulator, computed torque"
    )
    collect_mode: Literal["torque", "kinematic"] = Field(
        "kinematic", description="how the expert's demonstrations are rolled out (kinematic: batched, fast)"
    )
    control_rate: float = Field(240.0, gt=0, description="Hz; the simulator/integration step is 1/control_rate")
    integrator: Literal["semi_implicit_euler", "rk4"] = Field(
        "semi_implicit_euler", description="kinematic mode; semi-implicit Euler is what pybullet and MuJoCo use"
    )
    gravity: float = -9.81
    robot: RobotField = Field(description="the robot description (conf/robot/<name>.yaml)")
    scene: Scene = Field(default_factory=Scene, description="the training and validation splits' scene (conf/scene/)")
    test_scene: Scene | None = Field(
        None, description="the test split's scene (paper: a different placement); null = the same as scene"
    )
    obstacle_jitter: Vec3 = Field((0.0, 0.0, 0.0), description="± uniform perturbation of every centre per env")
    goal_per_trajectory: bool = Field(
        True, description="draw a goal per trajectory (paper §4.2); else one goal per environment"
    )
    min_start_goal_distance: float = Field(0.0, ge=0, description="starts whose end effector is closer are redrawn")
    demo_min_duration: float = Field(5.0, ge=0, description="demonstrations last at least this long (s) ...")
    demo_settle_distance: float = Field(
        0.01, gt=0, description="... and end once the end effector is this close to the goal (m) ..."
    )
    demo_settle_speed: float = Field(
        0.05, gt=0, description="... with joint speed ‖q̇‖ below this (rad/s); at most data.points records"
    )
    goal_region: tuple[Range, Range, Range] = Field(
        ((0.3, 0.6), (-0.45, -0.2), (0.15, 0.55)), description="goal ~ uniform in this box (m)"
    )
    reach_layout: ReachLayout | None = Field(
        None,
        description="lay the task out from the robot's kinematics (experiment=reach): goal_region, the scenes' "
        "placement, obstacle_jitter and min_start_goal_distance are derived, not read",
    )
    goal_clearance: float = Field(0.15, ge=0, description="min horizontal distance from goal to obstacle surfaces")
    posture_goal: bool = Field(
        False,
        description="aux posture (one angle per joint) for a tree's posture attractor (tree.posture): the robot's "
        "home in sampled environments, a recorded demonstration's final configuration in recorded ones",
    )
    nominal_q: tuple[float, ...] | None = Field(None, description="centre of the starts (rad); null: the robot's home")
    start_spread: tuple[float, ...] | float = Field(
        0.3, description="± uniform per joint (rad): one value for every joint, or one per joint"
    )
    start_speed: float = Field(0.0, ge=0, description="initial joint speeds ~ uniform in ±start_speed")
    start_clearance: float = Field(0.05, ge=0, description="min simulator clearance of the start configuration")
    joint_margin: float = Field(0.05, ge=0, description="starts stay this far inside the URDF limits (rad)")
    goal_tolerance: float = Field(0.05, gt=0)
    clearance_query: float = Field(0.3, gt=0, description="distances beyond this are not resolved")
    max_tries: int = Field(200, ge=1)
    camera: tuple[float, float, float, Vec3] = Field(
        (1.2, -20.0, -50.0, (0.3, 0.0, 0.3)), description="render: distance, yaw, pitch (deg), target"
    )
    render_size: tuple[int, int] = Field((320, 240), description="figures: width, height of a rendered frame")
    render_times: tuple[float, ...] = Field(
        (0.0, 1.0, 2.0, 3.0, 5.0, 10.0), description="figures: times (s) of the frames of the render strip"
    )
    render_trajectory: int | None = Field(
        None,
        ge=0,
        description="figures: the test trajectory rendered; null = the one where the expert comes "
        "closest to the obstacle",
    )
    gif_fps: float = Field(10.0, gt=0, description="figures: frames per second of the execution GIF (real time)")
    depth_camera: DepthCameraParams = Field(
        default_factory=DepthCameraParams, description="the depth camera of point_cloud (pose, resolution, rate, noise)"
    )
    dtype: Literal["float64", "float32"] = "float64"

    def integration_step(self) -> tuple[float, str]:
        """(seconds, the key that sets it) of the step rollouts integrate and the simulator steps on: a run config's
        recording interval and horizon are checked against it before anything runs (``time_grid`` at rollout time)."""
        return 1.0 / self.control_rate, "1/env.control_rate"

    @model_validator(mode="after")
    def _a_window_needs_a_simulator_with_one(self):
        if self.gui and not has_window(self.sim):
            raise ValueError(
                f"gui: sim '{self.sim.type}' has no window to show a world in; set env.gui=false or sim=pybullet"
            )
        return self

    @model_validator(mode="after")
    def _test_scene_fits_the_tree(self):
        if self.test_scene is not None:
            same_layout(self.scene, self.test_scene, "test_scene")
        return self

    @field_validator("obstacle_jitter", "start_spread")
    @classmethod
    def _half_widths(cls, v: tuple[float, ...] | float, info: ValidationInfo):
        if info.field_name == "start_spread":
            v = _per_joint("start_spread", v, info)
        assert not isinstance(v, float)  # obstacle_jitter is a Vec3, and start_spread one value per joint by now
        if not all(x >= 0 for x in v):
            raise ValueError(
                f"{info.field_name} must be ≥ 0 in every entry (each is the half-width of a uniform "
                f"± perturbation); given {list(v)}"
            )
        return v

    @field_validator("goal_region")
    @classmethod
    def _box(cls, v: tuple[Range, Range, Range]):
        for axis, r in zip("xyz", v):
            if not r[0] <= r[1]:
                raise ValueError(
                    f"goal_region.{axis} must be (low, high) with low ≤ high (goals are drawn uniformly "
                    f"between them); given {tuple(r)}"
                )
        return v

    @field_validator("nominal_q")
    @classmethod
    def _inside_the_limits(cls, v: tuple[float, ...] | None, info: ValidationInfo):
        robot = info.data.get("robot")
        if v is None or robot is None:
            return v
        v = _per_joint("nominal_q", v, info)
        for name, q, (lo, hi, _) in zip(robot.joints, v, robot.joint_limits()):
            if not lo <= q <= hi:
                raise ValueError(
                    f"nominal_q: {name} = {q} lies outside its limits [{lo}, {hi}] (starts are drawn around "
                    f"it and clamped to the limits)"
                )
        return v

    @field_validator("joint_margin")
    @classmethod
    def _room_inside_the_limits(cls, v: float, info: ValidationInfo):
        robot = info.data.get("robot")  # absent when it was refused itself
        if robot is None:
            return v
        nominal = info.data.get("nominal_q") or robot.home
        for k, (name, (lo, hi, _)) in enumerate(zip(robot.joints, robot.joint_limits())):
            if not lo + v < hi - v:
                raise ValueError(
                    f"joint_margin must be < half of every joint's range (starts are drawn in "
                    f"[lower + margin, upper − margin]); {name} spans [{lo:.5g}, {hi:.5g}], "
                    f"half of it is {(hi - lo) / 2:.4g}; given {v}"
                )
            if not lo + v <= nominal[k] <= hi - v:
                raise ValueError(
                    f"joint_margin puts the start centre {name} = {nominal[k]} outside its start range "
                    f"[{lo:.5g} + margin, {hi:.5g} − margin] (every start would be clamped to its edge); "
                    f"move {'nominal_q' if info.data.get('nominal_q') else 'home (the robot file)'} "
                    f"inward or lower joint_margin; given {v}"
                )
        return v

    def start_centre(self) -> tuple[float, ...]:
        """Where starts are drawn around: ``nominal_q``, else the robot's home."""
        return tuple(self.nominal_q) if self.nominal_q is not None else tuple(self.robot.home)

    def spread(self) -> tuple[float, ...]:
        """``start_spread`` per joint."""
        v = self.start_spread
        return (float(v),) * len(self.robot.joints) if isinstance(v, (int, float)) else tuple(v)

    @field_validator("camera")
    @classmethod
    def _in_front(cls, v):
        if not v[0] > 0:
            raise ValueError(
                f"camera distance (the first entry) must be > 0 (the camera looks at the target from "
                f"that far); given {v[0]}"
            )
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
