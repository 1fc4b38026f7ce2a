"""The manipulator environment: any robot of conf/robot/ reaching goals in a scene of conf/scene/. Its aux state
(goal, obstacles), reproducible sampling of environments and starts, collision geometry, moving obstacles, and the
entry points that the rollout modes, demonstrations, metrics and rendering serve."""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Mapping, Sequence
from typing import Any, Literal

import numpy as np
import torch
from torch import Tensor

from ...registry import ENVS
from ...robots import RobotDescription, build_robot
from ...scenes import Scene, aux_at, distances, same_layout, scene_aux, scene_aux_dims
from ...sims import Images
from ..common import (
    DTYPES,
    ComputesOnDevice,
    SeededSampling,
    check_initial_states,
    on_device,
    redraw_until_ok,
    time_grid,
)
from ..demonstrations import Dataset
from ..protocol import ObstacleDepths, RenderSettings
from ..rollout import Rollout
from . import demonstrations as demos
from . import render as rendering
from .collisions import obstacle_depths
from .kinematic import rollout_kinematic
from .layout import Clearances, Derived, derive
from .metrics import RATIO_METRICS, task_metrics
from .params import ManipulatorParams
from .paths import end_effector_radius, path_clearance
from .sensing import cloud_of
from .torque import rollout_torque
from .worlds import HelperWorlds, TaskWorld, fixed_links_extent, sample_aux


@ENVS.register("manipulator")
class Manipulator(ComputesOnDevice, SeededSampling):
    """A robot reaching goals among obstacles; see the package docstring for the two rollout modes."""

    Params = ManipulatorParams
    ratio_metrics = RATIO_METRICS

    def __init__(self, params: ManipulatorParams | None = None, **overrides: Any):
        if params is None:
            params = self.Params(**overrides)
        elif overrides:
            params = self.Params.model_validate({**params.model_dump(), **overrides})
        self.dtype = DTYPES[params.dtype]
        self.robot = build_robot(params.robot)
        self.worlds = HelperWorlds(self.robot, params.gravity, params.sim)
        self.layout = (
            None
            if params.reach_layout is None
            else derive(
                self.robot,
                params.start_centre(),
                params.spread(),
                params.reach_layout,
                Clearances(
                    start=params.start_clearance,
                    goal=params.goal_clearance,
                    end_effector=end_effector_radius(self.robot),
                    fixed_extent=fixed_links_extent(self.worlds.checker().sim, self.robot),
                ),
                centre_given=params.nominal_q is not None,
            )
        )
        self.params = params if self.layout is None else _laid_out(params, self.layout)
        self.dim = self.robot.dof
        self.lower, self.upper = self.robot.lower.to(self.dtype), self.robot.upper.to(self.dtype)

    # ------------------------------------------------------------------ bookkeeping
    @property
    def scene(self) -> Scene:
        """The training scene: the shapes and motions every split shares."""
        return self.params.scene

    @property
    def n_obstacles(self) -> int:
        return len(self.scene.obstacles)

    @property
    def moving(self) -> bool:
        """Whether some obstacle moves (then aux changes with time, ``aux_at``)."""
        return self.scene.moving

    @property
    def dt(self) -> float:
        """The simulator / integration step, 1/control_rate (s)."""
        return 1.0 / self.params.control_rate

    def aux_dims(self) -> dict[str, int]:
        """Names and sizes of the per-sample aux state; pass to ``build_tree(..., aux_dims=...)``."""
        posture = {"posture": self.dim} if self.params.posture_goal else {}
        return {"goal": 3, **scene_aux_dims(self.scene), **posture}

    def aux_at(self, aux: Mapping[str, Tensor], t: Tensor | float) -> dict[str, Tensor]:
        """The aux state ``aux`` (at t = 0) at times ``t``: moving obstacles advanced along their paths."""
        return aux_at(self.scene, aux, torch.as_tensor(t, dtype=self.dtype)) if self.moving else dict(aux)

    def close(self) -> None:
        """Close the helper simulated worlds (collision checking, rendering)."""
        self.worlds.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def __del__(self):
        with contextlib.suppress(Exception):  # interpreter shutdown
            self.close()

    def checker(self) -> TaskWorld:
        """The simulated world that checks collisions (opened on first use)."""
        return self.worlds.checker()

    # ------------------------------------------------------------------ geometry
    def ee_position(self, q: Tensor) -> Tensor:
        """(B, 3) end-effector point, the point the tree's attractor drives to the goal."""
        return self.robot.ee_position(q)

    def clearance(self, q: Tensor, aux: Mapping[str, Tensor]) -> Tensor:
        """(B,) simulator distance from the robot to the nearest obstacle (≤ 0: collision; capped at clearance_query)."""
        sc = self.checker()
        out = []
        for b in range(q.shape[0]):
            sc.set_env(self.scene, sample_aux(aux, b))
            sc.reset(q[b].detach().cpu().numpy())
            out.append(sc.clearance(self.params.clearance_query))
        return torch.tensor(out, dtype=self.dtype)

    def start_margin(self, q: Tensor, aux: Mapping[str, Tensor]) -> Tensor:
        """(B,) how far each configuration is from a fit start (≥ 0: it is one): ``start_clearance`` from every
        obstacle and from the ground, counting only links some joint can raise or lower, each asked for no more
        height than it can reach (``TaskWorld.start_margin``)."""
        sc, p = self.checker(), self.params
        out = []
        for b in range(q.shape[0]):
            sc.set_env(self.scene, sample_aux(aux, b))
            sc.reset(q[b].detach().cpu().numpy())
            out.append(sc.start_margin(p.start_clearance, p.clearance_query))
        return torch.tensor(out, dtype=self.dtype)

    @property
    def ee_radius(self) -> float:
        """The end effector's control-sphere radius (m), what a straight reach must clear the obstacles by."""
        return end_effector_radius(self.robot)

    def path_clearance(self, q0: Tensor, aux: Mapping[str, Tensor]) -> Tensor:
        """(B, K) clearance of the straight end-effector reach from each start ``q0`` to its goal from each obstacle's
        surface (m); the reach crosses obstacle k when it is below ``ee_radius`` (``scenes/crossing.py``)."""
        return path_clearance(self.scene, self.ee_position(q0.to(self.dtype)), aux)

    def describe_task(self) -> str | None:
        """What ``reach_layout`` derived for this robot (None when the task is read from the config)."""
        return None if self.layout is None else self.layout.describe()

    def in_collision(self, q: Tensor, aux: Mapping[str, Tensor]) -> Tensor:
        """(B,) bool: some link within zero distance of an obstacle."""
        return self.clearance(q, aux) <= 0.0

    # ------------------------------------------------------------------ sampling
    def _uniform(self, shape, lo, hi, g) -> Tensor:
        lo = torch.as_tensor(lo, dtype=self.dtype)
        hi = torch.as_tensor(hi, dtype=self.dtype)
        return lo + (hi - lo) * torch.rand(shape, generator=g, dtype=self.dtype)

    def _goal_ok(self, goal: Tensor, aux: Mapping[str, Tensor]) -> Tensor:
        return (distances(self.scene, aux, goal) >= self.params.goal_clearance).all(1)

    def scene_of(self, split: str = "train") -> Scene:
        """The scene of a data split: ``test_scene`` for ``test`` when set, else ``scene`` (the training
        placement, which the validation split shares)."""
        if split not in ("train", "val", "test"):
            raise ValueError(f"split must be 'train', 'val' or 'test', got {split!r}")
        p = self.params
        return p.test_scene if split == "test" and p.test_scene is not None else p.scene

    def _sample_goals(self, aux: Mapping[str, Tensor], generator) -> Tensor:
        """One goal per row of the obstacle aux state, redrawn until clear of that row's obstacles."""
        p = self.params
        n = aux[next(iter(aux))].shape[0] if aux else 0
        lo = [r[0] for r in p.goal_region]
        hi = [r[1] for r in p.goal_region]
        (goal,) = redraw_until_ok(
            lambda: (self._uniform((n, 3), lo, hi, generator),),
            lambda v, a: self._goal_ok(v[0], a),
            aux,
            p.max_tries,
            lambda left: (
                f"manipulator: no goal clear of the obstacles for {left} samples in {p.max_tries} rounds; "
                "move goal_region or lower goal_clearance"
            ),
        )
        return goal

    def sample_envs(
        self, n_envs: int, generator: torch.Generator | None = None, split: str = "train"
    ) -> dict[str, Tensor]:
        """``n_envs`` environments as an aux dict of (n_envs, k) tensors, reproducible given the generator.

        Obstacles are the split's scene's (``scene_of``) with every centre moved by ``obstacle_jitter``; goals are
        redrawn until they clear every obstacle by ``goal_clearance`` (with ``goal_per_trajectory``,
        ``sample_initial_states`` draws each trajectory's own goal in the same way).
        """
        scene, K = self.scene_of(split), self.n_obstacles
        nominal = torch.tensor([o.center for o in scene.obstacles], dtype=self.dtype).reshape(K, 3)
        jit = torch.tensor(self.params.obstacle_jitter, dtype=self.dtype)
        centers = nominal + self._uniform((n_envs, K, 3), -jit, jit, generator)
        obstacles = scene_aux(scene, centers, self.dtype)
        if not obstacles:
            obstacles = {"_n": torch.zeros(n_envs, 1, dtype=self.dtype)}
        goal = self._sample_goals(obstacles, generator)
        obstacles.pop("_n", None)
        return {"goal": goal, **obstacles, **self._posture(self._home().expand(n_envs, -1))}

    def _home(self) -> Tensor:
        return torch.tensor(self.params.robot.home, dtype=self.dtype)

    def _posture(self, q: Tensor) -> dict[str, Tensor]:
        """The aux posture (``posture_goal``): ``q`` (n, dof), or nothing."""
        return {"posture": q.to(self.dtype)} if self.params.posture_goal else {}

    # ------------------------------------------------------------------ recorded demonstrations
    @property
    def robot_description(self) -> RobotDescription:
        """The robot file: joint-space recordings are checked against its joints and limits."""
        return self.params.robot

    def recorded_aux(self, goals: Tensor) -> dict[str, Tensor]:
        """The aux state of demonstrations that end at the configurations ``goals`` (n, dof): the end effector's
        position there is the goal, the training scene's obstacles where the scene puts them (no jitter: a recording
        was made in one world), and the configuration itself the posture."""
        goals = goals.to(self.dtype)
        centers = torch.tensor([o.center for o in self.scene.obstacles], dtype=self.dtype).reshape(1, -1, 3)
        obstacles = scene_aux(self.scene, centers.expand(len(goals), -1, -1), self.dtype)
        return {"goal": self.ee_position(goals), **obstacles, **self._posture(goals)}

    def recorded_starts(self, candidates: Tensor) -> Tensor:
        """Which start configurations ``candidates`` (n, dof) are usable at rest: ``joint_margin`` inside the limits
        and clear of the scene's obstacles and the ground by ``start_clearance`` (as sampled starts are)."""
        q = candidates.to(self.dtype)
        m = self.params.joint_margin
        ok = ((q >= self.lower + m) & (q <= self.upper - m)).all(-1)
        inside = ok.nonzero().flatten()
        if len(inside):
            margin = self.start_margin(q[inside], self.recorded_aux(q[inside]))
            ok[inside] = margin >= 0
        return ok

    def recorded_depths(self, q: Tensor, aux: Mapping[str, Tensor]) -> ObstacleDepths:
        """How configurations ``q`` (M, dof) of recordings lie against the obstacles and the ground of their worlds
        (aux rows ``aux``): the robot's spheres nearest them, confirmed by the simulator where they are inside
        (``collisions.obstacle_depths``)."""
        return obstacle_depths(self, q, aux)

    def sample_initial_states(
        self, envs_aux: Mapping[str, Tensor], n_per_env: int, generator: torch.Generator | None = None
    ) -> tuple[Tensor, Tensor, dict[str, Tensor]]:
        """(q0, q̇0, aux) for n_envs·n_per_env samples, environment-major; starts are redrawn until they
        lie ``joint_margin`` inside the limits and clear every obstacle by ``start_clearance`` in the simulator."""
        p = self.params
        aux = {k: v.repeat_interleave(n_per_env, dim=0) for k, v in envs_aux.items()}
        n = aux["goal"].shape[0]
        if p.goal_per_trajectory:
            obstacles = {k: v for k, v in aux.items() if k != "goal"} or {"_n": aux["goal"]}
            aux["goal"] = self._sample_goals(obstacles, generator)
        nom = torch.tensor(p.start_centre(), dtype=self.dtype)
        spread = torch.tensor(p.spread(), dtype=self.dtype)
        lo, hi = self.lower + p.joint_margin, self.upper - p.joint_margin

        def draw():
            q = (nom + self._uniform((n, self.dim), -spread, spread, generator)).clamp(lo, hi)
            qd = self._uniform((n, self.dim), -p.start_speed, p.start_speed, generator)
            return q, qd

        def ok(v, a):
            far = (self.ee_position(v[0]) - a["goal"]).norm(dim=-1) >= p.min_start_goal_distance
            good = far.clone()
            if bool(far.any()):  # the simulator only for the candidates that pass the cheap test
                idx = far.nonzero().flatten()
                good[idx] = self.start_margin(v[0][idx], {k: x[idx] for k, x in a.items()}) >= 0.0
            return good

        q0, qd0 = redraw_until_ok(
            draw,
            ok,
            aux,
            p.max_tries,
            lambda left: (
                f"manipulator: could not place {left} start configurations clear of the obstacles and the "
                f"ground by env.start_clearance ({p.start_clearance} m) and env.min_start_goal_distance "
                f"({p.min_start_goal_distance} m) from the goal in {p.max_tries} rounds; move the starts' "
                f"centre ({_centre_key(p)}), or change env.start_spread or env.start_clearance"
            ),
        )
        return q0, qd0, aux

    # ------------------------------------------------------------------ rollouts
    def gradient_refusal(self) -> str | None:
        return _gradient_refusal(self.params.mode)

    def with_step(self, dt: float) -> Manipulator:
        """The same robot, scene and settings integrated on the step ``dt`` (control_rate = 1/dt)."""
        if abs(dt - self.dt) <= 1e-12 * max(1.0, self.dt):
            return self
        settings = self.params.model_dump(include=set(ManipulatorParams.model_fields))  # not a config block's `type`
        return Manipulator(ManipulatorParams.model_validate({**settings, "control_rate": 1.0 / dt}))

    def rollout(
        self,
        policy: Callable[..., Any],
        q0: Tensor,
        qd0: Tensor,
        aux: Mapping[str, Tensor],
        horizon: float,
        record_every: float = 0.1,
        mode: Literal["torque", "kinematic"] | None = None,
        monitor: Callable[..., Any] | None = None,
        enable_grad: bool = False,
        progress: Callable[[int, int], Any] | None = None,
    ) -> Rollout:
        """Run q̈ = policy(q, q̇, aux(t)) for ``horizon`` seconds from (q0, q̇0), batched over samples; ``aux`` is
        the aux state at t = 0 (moving obstacles move from there, ``aux_at``).

        ``policy`` returns a (B, dof) tensor or a TreeOutput (then V and q̇ᵀBq̇ are recorded from the same
        evaluation). ``record_every`` and ``horizon`` must be multiples of 1/control_rate. ``mode`` overrides the
        env's. ``monitor(i, t, q, qd, qdd, V)`` is called at each record, and ``progress(done, total)`` too; in kinematic
        mode the collision check after the records is reported once per sample, on ``progress.stage("collision
        check")`` where the callback has stages (``pipeline/progress.py::Bar``), else as more units of ``progress``.
        """
        n_steps, every = time_grid(horizon, record_every, self.dt, "1/control_rate")
        check_initial_states(q0, qd0, self.dim)
        mode = mode or self.params.mode
        aux = {k: torch.as_tensor(v, dtype=self.dtype) for k, v in aux.items()}  # lists: never via float32
        q0, qd0 = q0.to(self.dtype), qd0.to(self.dtype)
        records = n_steps // every
        if enable_grad and (why := _gradient_refusal(mode)) is not None:
            raise ValueError(f"rollout(enable_grad=True) cannot keep the autograd graph: {why}")
        policy = on_device(policy, self.device)
        with torch.set_grad_enabled(enable_grad):
            if mode == "torque":
                if progress is not None:  # progress(records done, records in all), reported at every record
                    monitor = _reporting(monitor, progress, records)
                return rollout_torque(self, policy, q0, qd0, aux, n_steps, every, monitor)
            # kinematic: after the records, every sample's path is checked for collisions, one unit per sample
            monitor, checked = _staged(monitor, progress, records, q0.shape[0])
            return rollout_kinematic(self, policy, q0, qd0, aux, n_steps, every, monitor, checked)

    # ------------------------------------------------------------------ demonstrations and task metrics
    def demonstration_lengths(self, ro: Rollout) -> Tensor:
        """(B,) records to keep of each demonstration; see ``manipulator.demonstrations.demonstration_lengths``."""
        return demos.demonstration_lengths(self.params, ro)

    def demonstrations(
        self,
        expert: Callable[..., Any],
        n_envs: int,
        n_traj: int,
        n_points: int,
        interval: float,
        generator: torch.Generator | None = None,
        split: str = "train",
        progress: Callable[[int, int], Any] | None = None,
    ) -> Dataset:
        """The expert's demonstrations of a data split (paper §4.2): 5–10 s each, the split's scene, a goal per
        trajectory; see ``manipulator.demonstrations.demonstrations``."""
        return demos.demonstrations(self, expert, n_envs, n_traj, n_points, interval, generator, split, progress)

    def task_metrics(self, ro: Rollout) -> dict[str, Tensor]:
        """Per-trajectory (B,) metrics of paper §4.2; see ``manipulator.metrics.task_metrics``."""
        return task_metrics(ro, self.dtype)

    # ------------------------------------------------------------------ rendering
    @property
    def render_settings(self) -> RenderSettings:
        p = self.params
        return RenderSettings(
            size=p.render_size, times=tuple(p.render_times), gif_fps=p.gif_fps, trajectory=p.render_trajectory
        )

    def render(
        self,
        q: Tensor | Sequence[float],
        aux: Mapping[str, Tensor],
        width: int = 320,
        height: int = 240,
        sample: int = 0,
    ) -> np.ndarray:
        """(height, width, 3) uint8 image of the robot at ``q`` in environment ``aux[sample]``, rendered
        offscreen by the simulator, for figures and animations (``images`` for depth and segmentation too)."""
        return self.images(q, aux, width, height, sample).rgb

    def images(
        self,
        q: Tensor | Sequence[float],
        aux: Mapping[str, Tensor],
        width: int = 320,
        height: int = 240,
        sample: int = 0,
    ) -> Images:
        """Colour, depth (m) and segmentation of the robot at ``q`` in environment ``aux[sample]``, through the
        camera of ``env.camera`` (``rmpfusion.sims.Images``)."""
        camera = rendering.camera_of(self.params.camera)
        return rendering.images(self.worlds.renderer(), self.scene, q, aux, camera, width, height, sample)

    def point_cloud(
        self,
        q: Tensor | Sequence[float],
        aux: Mapping[str, Tensor],
        sample: int = 0,
        rng: np.random.Generator | None = None,
    ) -> Tensor:
        """(P, 3) world points of the obstacles that ``env.depth_camera`` sees with the robot at ``q`` in environment
        ``aux[sample]``: its depth image back-projected, the robot's, the ground's and the goal marker's points
        removed by the simulator's segmentation (``manipulator/sensing.py``)."""
        c = self.params.depth_camera
        images = rendering.images(self.worlds.renderer(), self.scene, q, aux, c.camera(), c.width, c.height, sample)
        return torch.as_tensor(cloud_of(images, c.camera(), c.noise, rng), dtype=self.dtype)

    def project(self, points, width: int = 320, height: int = 240) -> np.ndarray:
        """(N, 2) pixel coordinates (column, row) of world points (N, 3) in ``render``'s image, to draw paths on it."""
        return rendering.project(self.params.camera, points, width, height)


def _gradient_refusal(mode: str) -> str | None:
    """None in kinematic mode (the closed loop is integrated in torch; the collision replay after it reads the path
    but enters no gradient); torque mode steps pybullet, outside torch."""
    if mode == "kinematic":
        return None
    return "env.mode=torque steps pybullet outside torch; set env.mode=kinematic"


def _centre_key(p: ManipulatorParams) -> str:
    """How the user sets the starts' centre: the robot file's ``home`` unless ``env.nominal_q`` overrides it."""
    return "env.nominal_q" if p.nominal_q is not None else f"home in the robot file of {p.robot.name}, env.robot.home"


def _laid_out(p: ManipulatorParams, d: Derived) -> ManipulatorParams:
    """``p`` with the task a reach layout derived: its goal region, the two scenes, the per-environment jitter."""
    try:
        same_layout(p.scene, d.scene, "the reach layout's scene")
    except ValueError as e:
        raise ValueError(
            f"env.reach_layout places one standing cylinder above a ground plane; env.scene must have "
            f"that layout (conf/scene/reach_post.yaml), as the tree is built from it: {e}"
        ) from None
    centre = {} if d.start_centre is None else {"nominal_q": d.start_centre}
    return p.model_copy(
        update={
            "goal_region": d.goal_region,
            "scene": d.scene,
            "test_scene": d.test_scene,
            "obstacle_jitter": d.obstacle_jitter,
            "min_start_goal_distance": d.min_start_goal_distance,
            **centre,
        }
    )


def _reporting(
    monitor: Callable[..., Any] | None, progress: Callable[[int, int], Any], total: int
) -> Callable[..., Any]:
    """``monitor`` that also reports ``progress(records done, records in all)`` at every record."""

    def both(i, *rest):
        if monitor is not None:
            monitor(i, *rest)
        progress(i, total)

    return both


def _staged(
    monitor: Callable[..., Any] | None, progress: Callable[[int, int], Any] | None, records: int, samples: int
) -> tuple[Callable[..., Any] | None, Callable[[int], Any] | None]:
    """(monitor, checked(b)) of a kinematic rollout reporting ``progress``: the records, then the collision check
    sample by sample on a stage of its own where ``progress`` has stages (a stage whose count is the samples, not
    the last percent of the records'), else counted on after the records."""
    if progress is None:
        return monitor, None
    stage = getattr(progress, "stage", None)
    if stage is None:
        total = records + samples
        return _reporting(monitor, progress, total), lambda b: progress(records + b + 1, total)
    check = stage("collision check")

    def checked(b: int) -> None:
        check(b + 1, samples)

    def records_then_check(i, *rest):
        if monitor is not None:
            monitor(i, *rest)
        progress(i, records)
        if i == records:  # the check starts now (its torch bound first, then the samples one by one)
            check(0, samples)

    return records_then_check, checked
