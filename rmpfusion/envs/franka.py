"""Franka Panda reaching around cylinder obstacles in pybullet (paper §4.2, App. D.2).

Two ways to run a policy q̈ = π(q, q̇, aux):
- ``torque``: each rollout has its own pybullet world; the tree's acceleration becomes joint torques by
  computed-torque control (pybullet's inverse dynamics, default velocity motors disabled), so the
  simulated robot is the paper's feedback-linearised system, integrated by pybullet itself;
- ``kinematic``: the same closed loop integrated in torch for the whole batch at once (data collection).
Collision means some robot link is at distance ≤ 0 from an obstacle by pybullet's closest points, in both
modes (kinematic rollouts are replayed in pybullet at every integration step after the fact).
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field
from typing import Any, Callable, Literal, Mapping, Sequence

import numpy as np
import torch
from pydantic import Field, model_validator
from torch import Tensor

from ..maps.kinematics import Chain
from ..maps.urdf import PANDA_ARM_JOINTS, load_panda_urdf_path, parse_urdf
from ..registry import ENVS, Params
from .common import SeededSampling, qdd_of, redraw_until_ok, rk4, semi_implicit_euler
from .faults import IsolatingPolicy
from .franka_tree import EE_LINK, EE_OFFSET

Vec3 = tuple[float, float, float]
Range = tuple[float, float]

_DTYPES = {"float64": torch.float64, "float32": torch.float32}
ARM_JOINTS = list(range(7))  # pybullet joint indices of panda_joint1..7 in pybullet_data's panda.urdf
FINGER_JOINTS = [9, 10]


def _pb():
    import pybullet

    return pybullet


@dataclass
class FrankaRollout:
    """A batch of closed-loop trajectories sampled at the record times (``times``).

    A rollout ended early by an error (pybullet, or a non-finite state) has its ``error`` set and NaN
    records from then on; its flags count only what happened before. ``time_to_goal`` is NaN if the
    end effector never came within the goal tolerance.
    """

    mode: str
    times: Tensor  # (T,)
    q: Tensor  # (T, B, 7)
    qd: Tensor  # (T, B, 7)
    qdd: Tensor  # (T, B, 7): the policy's command
    ee: Tensor  # (T, B, 3) end-effector (fingertip centre) position
    goal_distance: Tensor  # (T, B)
    collided: Tensor  # (B,) bool: some link at distance ≤ 0 from an obstacle at some integration step
    min_clearance: Tensor  # (B,) smallest link–obstacle distance seen (capped at clearance_query)
    reached: Tensor  # (B,) bool: within goal_tolerance at some integration step
    time_to_goal: Tensor  # (B,) first such time (s), NaN if never
    success: Tensor  # (B,) reached, never collided, no error
    error: list[str | None] = field(default_factory=list)
    V: Tensor | None = None  # (T, B)
    dissipation: Tensor | None = None  # (T, B): q̇ᵀBq̇ at the root
    # the execution (paper §4.2): from t = 0 until the goal tolerance is first reached, else the whole horizon
    cspace_length: Tensor | None = None  # (B,) Σ‖Δq‖ over integration steps (rad)
    ee_length: Tensor | None = None  # (B,) Σ‖Δee‖ (m)
    end_goal_distance: Tensor | None = None  # (B,) goal distance when the execution ended (m)
    first_collision_time: Tensor | None = None  # (B,) first integration time with a link at distance ≤ 0 (s), inf if never

    @property
    def batch_size(self) -> int:
        return self.q.shape[1]


class ObstacleSpec(Params):
    center: Vec3
    radius: float = Field(gt=0)
    height: float = Field(0.5, gt=0)


class _Scene:
    """One pybullet world: the Panda on a fixed base at the origin, cylinder obstacles and a goal marker."""

    def __init__(self, gui: bool = False, gravity: float = -9.81):
        p = _pb()
        self.p = p
        self.cid = p.connect(p.GUI if gui else p.DIRECT)
        if self.cid < 0:
            raise RuntimeError("pybullet: could not connect (a GUI may already be open)")
        self.robot = p.loadURDF(load_panda_urdf_path(), useFixedBase=True, flags=p.URDF_USE_INERTIA_FROM_FILE,
                                physicsClientId=self.cid)
        for j in range(-1, p.getNumJoints(self.robot, physicsClientId=self.cid)):
            # pybullet's default link damping is not in its inverse dynamics; remove it so the
            # computed-torque loop realises the commanded acceleration exactly
            p.changeDynamics(self.robot, j, linearDamping=0.0, angularDamping=0.0, jointDamping=0.0,
                             physicsClientId=self.cid)
        p.setGravity(0, 0, gravity, physicsClientId=self.cid)
        self.joints = ARM_JOINTS + FINGER_JOINTS
        p.setJointMotorControlArray(self.robot, self.joints, p.VELOCITY_CONTROL, forces=[0.0] * len(self.joints),
                                    physicsClientId=self.cid)
        self.obstacles: list[int] = []
        self.goal_marker: int | None = None

    def set_env(self, centers: np.ndarray, radii: np.ndarray, heights: Sequence[float], goal: np.ndarray | None,
                visual: bool = False) -> None:
        p, cid = self.p, self.cid
        for b in self.obstacles:
            p.removeBody(b, physicsClientId=cid)
        self.obstacles = []
        for c, r, h in zip(centers, radii, heights):
            col = p.createCollisionShape(p.GEOM_CYLINDER, radius=float(r), height=float(h), physicsClientId=cid)
            vis = p.createVisualShape(p.GEOM_CYLINDER, radius=float(r), length=float(h), rgbaColor=[0.8, 0.2, 0.2, 1],
                                      physicsClientId=cid) if visual else -1
            self.obstacles.append(p.createMultiBody(0.0, col, vis, [float(v) for v in c], physicsClientId=cid))
        if visual and goal is not None:
            if self.goal_marker is None:
                vis = p.createVisualShape(p.GEOM_SPHERE, radius=0.03, rgbaColor=[1.0, 0.6, 0.0, 1], physicsClientId=cid)
                self.goal_marker = p.createMultiBody(0.0, -1, vis, [0, 0, 0], physicsClientId=cid)
            p.resetBasePositionAndOrientation(self.goal_marker, [float(v) for v in goal], [0, 0, 0, 1],
                                              physicsClientId=cid)

    def add_ground(self) -> None:
        """pybullet_data's checkered plane at z = 0 (renders only: the robot's base sits on it)."""
        import pybullet_data

        self.p.loadURDF(os.path.join(pybullet_data.getDataPath(), "plane.urdf"), physicsClientId=self.cid)

    def reset(self, q: np.ndarray, qd: np.ndarray | None = None) -> None:
        qd = np.zeros(7) if qd is None else qd
        for i, j in enumerate(ARM_JOINTS):
            self.p.resetJointState(self.robot, j, float(q[i]), float(qd[i]), physicsClientId=self.cid)
        for j in FINGER_JOINTS:
            self.p.resetJointState(self.robot, j, 0.0, 0.0, physicsClientId=self.cid)

    def state(self) -> tuple[np.ndarray, np.ndarray]:
        """(q, q̇) of all 9 movable joints (arm then fingers)."""
        js = self.p.getJointStates(self.robot, self.joints, physicsClientId=self.cid)
        return np.array([s[0] for s in js]), np.array([s[1] for s in js])

    def clearance(self, query: float) -> float:
        """Smallest robot–obstacle distance, or ``query`` when nothing is closer than that."""
        best = query
        for ob in self.obstacles:
            for pt in self.p.getClosestPoints(self.robot, ob, query, physicsClientId=self.cid):
                best = min(best, pt[8])
        return best

    def close(self) -> None:
        try:
            self.p.disconnect(physicsClientId=self.cid)
        except Exception:  # noqa: BLE001 - already gone
            pass


@ENVS.register("franka")
class Franka(SeededSampling):
    """Franka Panda goal reaching around cylinders; see the module docstring for the two modes."""

    class Params(Params):
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

    def __init__(self, params: Params | None = None, **overrides: Any):
        if params is None:
            params = self.Params(**overrides)
        elif overrides:
            params = self.Params.model_validate({**params.model_dump(), **overrides})
        self.params = params
        self.dtype = _DTYPES[params.dtype]
        self.chain = Chain(parse_urdf(load_panda_urdf_path()), PANDA_ARM_JOINTS)
        self.lower, self.upper = (t.to(self.dtype) for t in self.chain.joint_limits())
        self._ee_offset = torch.tensor(EE_OFFSET, dtype=self.dtype)
        self._checker: _Scene | None = None
        self._renderer: _Scene | None = None

    # ------------------------------------------------------------------ bookkeeping
    @property
    def n_obstacles(self) -> int:
        return len(self.params.obstacles)

    @property
    def dt(self) -> float:
        return 1.0 / self.params.control_rate

    def aux_dims(self) -> dict[str, int]:
        """Names and sizes of the per-sample aux state; pass to ``build_tree(..., aux_dims=...)``."""
        dims = {"goal": 3}
        for k in range(1, self.n_obstacles + 1):
            dims[f"obstacle{k}_center"] = 3
            dims[f"obstacle{k}_radius"] = 1
        return dims

    def close(self) -> None:
        """Disconnect the helper pybullet worlds (collision checking, rendering)."""
        for s in (self._checker, self._renderer):
            if s is not None:
                s.close()
        self._checker = self._renderer = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def __del__(self):
        try:
            self.close()
        except Exception:  # noqa: BLE001 - interpreter shutdown
            pass

    def _scene_args(self, aux: Mapping[str, Tensor], b: int):
        K = self.n_obstacles
        centers = np.array([aux[f"obstacle{k}_center"][b].tolist() for k in range(1, K + 1)]).reshape(K, 3)
        radii = np.array([float(aux[f"obstacle{k}_radius"][b].reshape(-1)[0]) for k in range(1, K + 1)])
        heights = [o.height for o in self.params.obstacles]
        goal = np.array(aux["goal"][b].tolist()) if "goal" in aux else None
        return centers, radii, heights, goal

    def checker(self) -> _Scene:
        if self._checker is None:
            self._checker = _Scene(gui=False, gravity=self.params.gravity)
        return self._checker

    # ------------------------------------------------------------------ geometry
    def ee_position(self, q: Tensor) -> Tensor:
        """(B, 3) fingertip centre, the point the tree's attractor drives to the goal."""
        R, p = self.chain.forward_kinematics(q, [EE_LINK])[EE_LINK]
        return p + (R @ self._ee_offset.to(q).unsqueeze(-1)).squeeze(-1)

    def clearance(self, q: Tensor, aux: Mapping[str, Tensor]) -> Tensor:
        """(B,) pybullet distance from the robot to the nearest obstacle (≤ 0: collision; capped at clearance_query)."""
        sc = self.checker()
        out = []
        for b in range(q.shape[0]):
            centers, radii, heights, _ = self._scene_args(aux, b)
            sc.set_env(centers, radii, heights, None)
            sc.reset(q[b].detach().cpu().numpy())
            out.append(sc.clearance(self.params.clearance_query))
        return torch.tensor(out, dtype=self.dtype)

    def in_collision(self, q: Tensor, aux: Mapping[str, Tensor]) -> Tensor:
        """(B,) bool: some link within zero distance of an obstacle."""
        return self.clearance(q, aux) <= 0.0

    # ------------------------------------------------------------------ sampling
    def _uniform(self, shape, lo, hi, g) -> Tensor:
        lo = torch.as_tensor(lo, dtype=self.dtype)
        hi = torch.as_tensor(hi, dtype=self.dtype)
        return lo + (hi - lo) * torch.rand(shape, generator=g, dtype=self.dtype)

    def _goal_ok(self, goal: Tensor, centers: Tensor, radii: Tensor) -> Tensor:
        if centers.shape[1] == 0:
            return torch.ones(goal.shape[0], dtype=torch.bool)
        horiz = (goal[:, None, :2] - centers[..., :2]).norm(dim=-1) - radii
        return (horiz >= self.params.goal_clearance).all(1)

    def obstacle_specs(self, split: str = "train") -> list[ObstacleSpec]:
        """The nominal cylinders of a data split: ``test_obstacles`` for ``test`` when set, else ``obstacles`` (the
        training placement, which the validation split shares)."""
        if split not in ("train", "val", "test"):
            raise ValueError(f"split must be 'train', 'val' or 'test', got {split!r}")
        p = self.params
        return list(p.test_obstacles) if split == "test" and p.test_obstacles is not None else list(p.obstacles)

    def _sample_goals(self, centers: Tensor, radii: Tensor, generator) -> Tensor:
        """One goal per row of (n, K, 3) centres / (n, K) radii, redrawn until clear of that row's obstacles."""
        p, n = self.params, centers.shape[0]
        lo = [r[0] for r in p.goal_region]
        hi = [r[1] for r in p.goal_region]
        goal = self._uniform((n, 3), lo, hi, generator)
        bad = ~self._goal_ok(goal, centers, radii)
        tries = 1
        while bool(bad.any()):
            if tries >= p.max_tries:
                raise RuntimeError(f"franka: no goal clear of the obstacles for {int(bad.sum())} samples in "
                                   f"{tries} rounds; move goal_region or lower goal_clearance")
            g2 = self._uniform((n, 3), lo, hi, generator)
            take = bad & self._goal_ok(g2, centers, radii)
            goal = torch.where(take[:, None], g2, goal)
            bad &= ~take
            tries += 1
        return goal

    def sample_envs(self, n_envs: int, generator: torch.Generator | None = None,
                    split: str = "train") -> dict[str, Tensor]:
        """``n_envs`` environments as an aux dict of (n_envs, k) tensors, reproducible given the generator.

        Obstacles are the split's nominal ones (``obstacle_specs``) moved by ``obstacle_jitter``; goals are
        redrawn until they clear every obstacle horizontally by ``goal_clearance`` (with
        ``goal_per_trajectory``, ``sample_initial_states`` draws each trajectory's own goal in the same way).
        """
        p, K = self.params, self.n_obstacles
        specs = self.obstacle_specs(split)
        nominal = torch.tensor([o.center for o in specs], dtype=self.dtype).reshape(K, 3)
        radii = torch.tensor([o.radius for o in specs], dtype=self.dtype).expand(n_envs, K)
        jit = torch.tensor(p.obstacle_jitter, dtype=self.dtype)
        centers = nominal + self._uniform((n_envs, K, 3), -jit, jit, generator)
        goal = self._sample_goals(centers, radii, generator)
        aux = {"goal": goal}
        for k in range(K):
            aux[f"obstacle{k + 1}_center"] = centers[:, k].contiguous()
            aux[f"obstacle{k + 1}_radius"] = radii[:, k : k + 1].contiguous()
        return aux

    def sample_initial_states(
        self, envs_aux: Mapping[str, Tensor], n_per_env: int, generator: torch.Generator | None = None
    ) -> tuple[Tensor, Tensor, dict[str, Tensor]]:
        """(q0, q̇0, aux) for n_envs·n_per_env samples, environment-major; starts are redrawn until they
        lie ``joint_margin`` inside the limits and clear every obstacle by ``start_clearance`` in pybullet."""
        p = self.params
        aux = {k: v.repeat_interleave(n_per_env, dim=0) for k, v in envs_aux.items()}
        n = aux["goal"].shape[0]
        if p.goal_per_trajectory:
            K = self.n_obstacles
            centers = torch.stack([aux[f"obstacle{k}_center"] for k in range(1, K + 1)], 1).reshape(n, K, 3)
            radii = torch.cat([aux[f"obstacle{k}_radius"] for k in range(1, K + 1)], 1).reshape(n, K)
            aux["goal"] = self._sample_goals(centers, radii, generator)
        nom = torch.tensor(p.nominal_q, dtype=self.dtype)
        spread = torch.tensor(p.start_spread, dtype=self.dtype)
        lo, hi = self.lower + p.joint_margin, self.upper - p.joint_margin

        def draw():
            q = (nom + self._uniform((n, 7), -spread, spread, generator)).clamp(lo, hi)
            qd = self._uniform((n, 7), -p.start_speed, p.start_speed, generator)
            return q, qd

        def ok(v, a):
            far = (self.ee_position(v[0]) - a["goal"]).norm(dim=-1) >= p.min_start_goal_distance
            good = far.clone()
            if bool(far.any()):  # pybullet only for the candidates that pass the cheap test
                idx = far.nonzero().flatten()
                good[idx] = self.clearance(v[0][idx], {k: x[idx] for k, x in a.items()}) >= p.start_clearance
            return good

        q0, qd0 = redraw_until_ok(
            draw, ok, aux, p.max_tries,
            lambda left: f"franka: could not place {left} start configurations clear of the obstacles and "
                         f"min_start_goal_distance from the goal; move nominal_q or change start_spread")
        return q0, qd0, aux

    # ------------------------------------------------------------------ rollouts
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
    ) -> FrankaRollout:
        """Run q̈ = policy(q, q̇, aux) for ``horizon`` seconds from (q0, q̇0), batched over samples.

        ``policy`` returns a (B, 7) tensor or a TreeOutput (then V and q̇ᵀBq̇ are recorded from the same
        evaluation). ``record_every`` and ``horizon`` must be multiples of 1/control_rate. ``mode``
        overrides the env's. ``monitor(i, t, q, qd, qdd, V)`` is called at each record, and
        ``progress(i, total)`` too.
        """
        dt = self.dt
        n_steps = int(round(horizon / dt))
        every = int(round(record_every / dt))
        if every < 1 or abs(every * dt - record_every) > 1e-9 * max(1.0, record_every):
            raise ValueError(f"record_every={record_every} must be a positive multiple of 1/control_rate={dt}")
        if abs(n_steps * dt - horizon) > 1e-9 * max(1.0, horizon):
            raise ValueError(f"horizon={horizon} must be a multiple of 1/control_rate={dt}")
        if q0.dim() != 2 or q0.shape[-1] != 7 or qd0.shape != q0.shape:
            raise ValueError(f"q0 and qd0 must both be (B, 7); got {tuple(q0.shape)} and {tuple(qd0.shape)}")
        mode = mode or self.params.mode
        if progress is not None:  # progress(records done, records in all), reported at every record
            user_monitor, total = monitor, n_steps // every

            def monitor(i, *rest):
                if user_monitor is not None:
                    user_monitor(i, *rest)
                progress(i, total)

        aux = {k: torch.as_tensor(v, dtype=self.dtype) for k, v in aux.items()}  # lists: never via float32
        q0, qd0 = q0.to(self.dtype), qd0.to(self.dtype)
        with torch.set_grad_enabled(enable_grad):
            if mode == "torque":
                return self._rollout_torque(policy, q0, qd0, aux, n_steps, every, monitor)
            return self._rollout_kinematic(policy, q0, qd0, aux, n_steps, every, monitor)

    def _evaluate(self, policy, q, qd, aux):
        out = policy(q, qd, aux)
        if isinstance(out, Tensor):
            return out, None, None
        V = getattr(out, "V", None)
        Bm = getattr(out, "B", None)
        D = torch.einsum("bi,bij,bj->b", qd, Bm, qd) if Bm is not None else None
        return out.qdd, V, D

    def _rollout_kinematic(self, policy, q0, qd0, aux, n_steps, every, monitor) -> FrankaRollout:
        dt, B = self.dt, q0.shape[0]
        policy = IsolatingPolicy(policy)  # a sample whose evaluation raises gets NaN, the others go on
        q, qd = q0.clone(), qd0.clone()
        alive = torch.ones(B, dtype=torch.bool)
        errors: list[str | None] = [None] * B
        rec = _Recorder()
        path = [q.detach().clone()]  # every integration step, replayed in pybullet for collisions
        goal_hit = _GoalTracker(B, self.dtype)
        goal_hit.update(0.0, self.ee_position(q), aux["goal"], self.params.goal_tolerance, alive, q)

        def accel(x, xd):
            return qdd_of(policy(x, xd, aux))

        for k in range(n_steps + 1):
            a = None
            if k % every == 0 or self.params.integrator == "semi_implicit_euler":
                a, V, D = self._evaluate(policy, q, qd, aux)
                if k % every == 0:
                    rec.add(k * dt, q, qd, a, V, D, alive, monitor)
            if k == n_steps:
                break
            if self.params.integrator == "semi_implicit_euler":
                q_new, qd_new = semi_implicit_euler(accel, q, qd, dt, a)
            else:
                q_new, qd_new = rk4(accel, q, qd, dt, a)
            finite = q_new.isfinite().all(-1) & qd_new.isfinite().all(-1)
            for b in (alive & ~finite).nonzero().flatten().tolist():
                errors[b] = policy.explain(b, f"non-finite state at t={(k + 1) * dt:.4f}s")
            alive &= finite
            # a dead sample keeps its last finite state so the batched evaluation stays well posed
            q = torch.where(alive[:, None], q_new, q)
            qd = torch.where(alive[:, None], qd_new, torch.zeros_like(qd))
            path.append(q.detach().clone())
            goal_hit.update((k + 1) * dt, self.ee_position(q), aux["goal"], self.params.goal_tolerance, alive, q)
        # collisions: replay every integration step of every sample in pybullet
        Q = torch.stack(path)  # (n_steps+1, B, 7)
        death = rec.death_index(alive, errors, n_steps, every)
        min_clear = torch.full((B,), float(self.params.clearance_query), dtype=self.dtype)
        first_hit = torch.full((B,), float("inf"), dtype=self.dtype)
        sc = self.checker()
        for b in range(B):
            try:
                centers, radii, heights, _ = self._scene_args(aux, b)
                sc.set_env(centers, radii, heights, None)
                last = n_steps if errors[b] is None else death[b]
                for k in range(last + 1):
                    sc.reset(Q[k, b].cpu().numpy())
                    min_clear[b] = min(float(min_clear[b]), sc.clearance(self.params.clearance_query))
                    if min_clear[b] <= 0.0 and first_hit[b].isinf():
                        first_hit[b] = k * dt
            except _pb().error as e:
                errors[b] = f"pybullet error during collision check: {e}"
                self._checker = None  # a broken world is not reused
        return self._finish("kinematic", rec, aux, min_clear, first_hit, goal_hit, errors)

    def _rollout_torque(self, policy, q0, qd0, aux, n_steps, every, monitor) -> FrankaRollout:
        p, dt, B = _pb(), self.dt, q0.shape[0]
        policy = IsolatingPolicy(policy)  # a sample whose evaluation raises gets NaN, the others go on
        errors: list[str | None] = [None] * B
        alive = torch.ones(B, dtype=torch.bool)
        scenes: list[_Scene | None] = []
        min_clear = torch.full((B,), float(self.params.clearance_query), dtype=self.dtype)
        first_hit = torch.full((B,), float("inf"), dtype=self.dtype)
        q, qd = q0.clone(), qd0.clone()
        try:
            for b in range(B):
                try:
                    sc = _Scene(gui=self.params.gui and b == 0, gravity=self.params.gravity)
                    sc.set_env(*self._scene_args(aux, b), visual=self.params.gui and b == 0)
                    p.setTimeStep(dt, physicsClientId=sc.cid)
                    sc.reset(q0[b].cpu().numpy(), qd0[b].cpu().numpy())
                    scenes.append(sc)
                    min_clear[b] = sc.clearance(self.params.clearance_query)
                    if min_clear[b] <= 0.0:
                        first_hit[b] = 0.0
                except p.error as e:
                    scenes.append(None)
                    errors[b] = f"pybullet error at setup: {e}"
                    alive[b] = False
            rec = _Recorder()
            goal_hit = _GoalTracker(B, self.dtype)
            fingers = [np.zeros(2)] * B
            finger_v = [np.zeros(2)] * B

            def read_states():
                for b, sc in enumerate(scenes):
                    if not alive[b]:
                        continue
                    try:
                        qa, qda = sc.state()
                    except p.error as e:
                        self._kill(b, f"pybullet error reading state: {e}", alive, errors, scenes)
                        continue
                    q[b] = torch.as_tensor(qa[:7], dtype=self.dtype)
                    qd[b] = torch.as_tensor(qda[:7], dtype=self.dtype)
                    fingers[b], finger_v[b] = qa[7:], qda[7:]

            read_states()
            goal_hit.update(0.0, self.ee_position(q), aux["goal"], self.params.goal_tolerance, alive, q)
            for k in range(n_steps + 1):
                a, V, D = self._evaluate(policy, q, qd, aux)
                if k % every == 0:
                    rec.add(k * dt, q, qd, a, V, D, alive, monitor)
                if k == n_steps:
                    break
                a_np = a.detach().cpu().numpy()
                for b, sc in enumerate(scenes):
                    if not alive[b]:
                        continue
                    if not np.isfinite(a_np[b]).all():
                        self._kill(b, policy.explain(b, f"non-finite acceleration at t={k * dt:.4f}s"), alive, errors,
                                   scenes)
                        continue
                    try:
                        # fingers are held closed by a stiff PD acceleration inside the same inverse dynamics
                        acc_f = -400.0 * fingers[b] - 40.0 * finger_v[b]
                        qs = q[b].tolist() + fingers[b].tolist()
                        vs = qd[b].tolist() + finger_v[b].tolist()
                        tau = p.calculateInverseDynamics(sc.robot, qs, vs, a_np[b].tolist() + acc_f.tolist(),
                                                         physicsClientId=sc.cid)
                        p.setJointMotorControlArray(sc.robot, sc.joints, p.TORQUE_CONTROL, forces=list(tau),
                                                    physicsClientId=sc.cid)
                        p.stepSimulation(physicsClientId=sc.cid)
                        min_clear[b] = min(float(min_clear[b]), sc.clearance(self.params.clearance_query))
                        if min_clear[b] <= 0.0 and first_hit[b].isinf():
                            first_hit[b] = (k + 1) * dt
                    except p.error as e:
                        self._kill(b, f"pybullet error at t={k * dt:.4f}s: {e}", alive, errors, scenes)
                read_states()
                goal_hit.update((k + 1) * dt, self.ee_position(q), aux["goal"], self.params.goal_tolerance, alive, q)
        finally:
            for sc in scenes:
                if sc is not None:
                    sc.close()
        return self._finish("torque", rec, aux, min_clear, first_hit, goal_hit, errors)

    @staticmethod
    def _kill(b, reason, alive, errors, scenes):
        alive[b] = False
        errors[b] = reason
        if scenes[b] is not None:
            scenes[b].close()
            scenes[b] = None

    def _finish(self, mode, rec: "_Recorder", aux, min_clear, first_hit, goal_hit: "_GoalTracker",
                errors) -> FrankaRollout:
        q = rec.stack(rec.q)
        T, B = q.shape[:2]
        ee = self.ee_position(q.nan_to_num().reshape(T * B, 7)).reshape(T, B, 3)
        ee = torch.where(q.isnan().any(-1, keepdim=True), torch.full_like(ee, float("nan")), ee)
        gd = (ee - aux["goal"].unsqueeze(0)).norm(dim=-1)
        collided = min_clear <= 0.0
        ok = torch.tensor([e is None for e in errors])
        return FrankaRollout(
            mode=mode,
            times=torch.tensor(rec.t, dtype=self.dtype),
            q=q, qd=rec.stack(rec.qd), qdd=rec.stack(rec.qdd), ee=ee, goal_distance=gd,
            collided=collided, min_clearance=min_clear, first_collision_time=first_hit, reached=goal_hit.reached, time_to_goal=goal_hit.time,
            success=goal_hit.reached & ~collided & ok, error=list(errors),
            cspace_length=goal_hit.cspace_length, ee_length=goal_hit.ee_length, end_goal_distance=goal_hit.end_distance,
            V=rec.stack(rec.V) if rec.V else None,
            dissipation=rec.stack(rec.D) if rec.D else None,
        )

    # ------------------------------------------------------------------ hooks of the experiment pipeline
    def demonstration_lengths(self, ro: FrankaRollout) -> Tensor:
        """(B,) records to keep of each demonstration (paper §4.2: trajectories of 5–10 s).

        A demonstration runs until the expert has settled at the goal (within ``demo_settle_distance`` and
        slower than ``demo_settle_speed``) but at least ``demo_min_duration``; at most the whole rollout.
        Records after an error (NaN) are never kept.
        """
        p = self.params
        finite = ro.q.isfinite().all(-1) & ro.qd.isfinite().all(-1)  # (T, B)
        settled = ((ro.goal_distance <= p.demo_settle_distance) & (ro.qd.norm(dim=-1) <= p.demo_settle_speed)
                   & (ro.times[:, None] >= p.demo_min_duration - 1e-9) & finite)
        T = ro.q.shape[0]
        idx = torch.arange(T)[:, None].expand_as(settled)
        first_settled = torch.where(settled, idx, T).min(0).values  # T when never settled
        first_bad = torch.where(~finite, idx, T).min(0).values
        return torch.minimum(first_settled + 1, first_bad).clamp(max=T)

    def collect_demonstrations(self, expert, n_envs: int, n_traj: int, n_points: int, interval: float,
                               generator: torch.Generator | None = None, split: str = "train",
                               progress: Callable[[int, int], Any] | None = None):
        """The expert's demonstrations of a data split (paper §4.2) as a ``Dataset``.

        ``n_envs`` obstacle placements of the split (``obstacle_specs``) × ``n_traj`` (start, goal) pairs; the
        expert runs for at most ``(n_points − 1)·interval`` s in ``collect_mode``, recorded every ``interval`` s
        and cut by ``demonstration_lengths``. Each record is (q, q̇, aux, the expert's q̈ there).
        """
        from ..learn.demonstrations import Dataset

        envs = self.sample_envs(n_envs, generator, split=split)
        q0, qd0, aux = self.sample_initial_states(envs, n_traj, generator)
        with torch.no_grad():
            ro = self.rollout(expert, q0, qd0, aux, horizon=(n_points - 1) * interval, record_every=interval,
                              mode=self.params.collect_mode, progress=progress)
        lengths = self.demonstration_lengths(ro).tolist()
        B = q0.shape[0]
        rows = [(b, k) for b in range(B) for k in range(lengths[b])]  # trajectory-major, time-ordered
        bi = torch.tensor([r[0] for r in rows], dtype=torch.long)
        ki = torch.tensor([r[1] for r in rows], dtype=torch.long)
        return Dataset(
            q=ro.q[ki, bi].contiguous(), qd=ro.qd[ki, bi].contiguous(), qdd=ro.qdd[ki, bi].detach().contiguous(),
            aux={k: v[bi].contiguous() for k, v in aux.items()}, env_id=bi // n_traj, traj_id=bi,
            t=ro.times[ki].contiguous(), collided=ro.collided.clone(), success=ro.success.clone(),
        )

    #: Metrics compared with the expert's as per-trajectory ratios learner/expert (paper Fig. 5b). The paper's
    #: "goal distance at the end of an execution" is not among them: an execution ends at ``goal_tolerance``, so
    #: for every policy that reaches the goal it is ~0.05 m and its ratio is 1 by construction. The distance at the
    #: time-out (the rollout always continues to it) and the closest approach say how well each policy got there.
    ratio_metrics = ("time", "cspace_length", "ee_length", "timeout_goal_distance", "min_goal_distance")

    def task_metrics(self, ro: FrankaRollout) -> dict[str, Tensor]:
        """Per-trajectory (B,) metrics of paper §4.2 on a rollout whose horizon is the time-out.

        An execution ends when the end effector first comes within ``goal_tolerance`` of the goal, else at the
        time-out. ``time``: its duration; ``cspace_length`` / ``ee_length``: distance travelled in configuration
        space (rad) and by the end effector (m) during it; ``goal_distance``: end-effector–goal distance when it
        ended (the paper's). ``timeout_goal_distance``: the distance at the time-out; ``min_goal_distance``: the
        closest the end effector came at any record. Also ``reached``, ``collided`` (any link within zero distance
        of an obstacle during the whole rollout) and ``min_clearance``. A rollout ended by an error gets NaN
        execution metrics.
        """
        timeout = float(ro.times[-1])
        failed = torch.tensor([e is not None for e in ro.error])
        time = torch.where(ro.reached, ro.time_to_goal, torch.full_like(ro.time_to_goal, timeout))
        closest = torch.where(ro.goal_distance.isfinite(), ro.goal_distance, float("inf")).min(0).values
        out = {"time": time, "cspace_length": ro.cspace_length, "ee_length": ro.ee_length,
               "goal_distance": ro.end_goal_distance, "timeout_goal_distance": ro.goal_distance[-1],
               "min_goal_distance": closest}
        out = {k: torch.where(failed, float("nan"), v) for k, v in out.items()}
        out.update({"reached": ro.reached.to(self.dtype), "collided": ro.collided.to(self.dtype),
                    "min_clearance": ro.min_clearance, "error": failed.to(self.dtype)})
        return out

    def figures(self, fig_dir, expert, stages, aux: Mapping[str, Tensor], title: str = "franka") -> list[str]:
        """The Franka figures (paper Fig. 5b, 6): ratio bars, V_r(t) per stage, a render strip and a GIF of one
        test execution, end-effector paths seen from above. ``expert`` / ``stages`` are ``StageResult``s on the
        same test initial states, ``aux`` their aux state. Returns the files written."""
        from ..plots import franka as fp

        return fp.franka_figures(self, fig_dir, expert, stages, aux, title=title)

    # ------------------------------------------------------------------ rendering
    def render(self, q: Tensor | Sequence[float], aux: Mapping[str, Tensor], width: int = 320, height: int = 240,
               sample: int = 0) -> np.ndarray:
        """(height, width, 3) uint8 image of the robot at ``q`` in environment ``aux[sample]``, rendered
        headless by pybullet's tiny renderer, for figures and animations."""
        p = _pb()
        q = torch.as_tensor(q, dtype=self.dtype).reshape(-1, 7)
        qb = q[min(sample, q.shape[0] - 1)]
        if self._renderer is None:
            self._renderer = _Scene(gui=False, gravity=self.params.gravity)
            self._renderer.add_ground()
        sc = self._renderer
        aux = {k: torch.as_tensor(v).reshape(-1, torch.as_tensor(v).shape[-1]) for k, v in aux.items()}
        sc.set_env(*self._scene_args(aux, sample), visual=True)
        sc.reset(qb.cpu().numpy())
        view, proj = self._camera(width, height)
        img = p.getCameraImage(width, height, view, proj, renderer=p.ER_TINY_RENDERER, physicsClientId=sc.cid)
        rgba = np.asarray(img[2], dtype=np.uint8).reshape(height, width, 4)
        return np.ascontiguousarray(rgba[..., :3])

    def _camera(self, width: int, height: int) -> tuple[list[float], list[float]]:
        p = _pb()
        dist, yaw, pitch, target = self.params.camera
        view = p.computeViewMatrixFromYawPitchRoll(list(target), dist, yaw, pitch, 0.0, 2)
        proj = p.computeProjectionMatrixFOV(60.0, width / height, 0.05, 10.0)
        return list(view), list(proj)

    def project(self, points, width: int = 320, height: int = 240) -> np.ndarray:
        """(N, 2) pixel coordinates (column, row) of world points (N, 3) in ``render``'s image, to draw paths on it."""
        view, proj = self._camera(width, height)
        V = np.asarray(view, dtype=float).reshape(4, 4).T  # pybullet matrices are column-major (OpenGL)
        P = np.asarray(proj, dtype=float).reshape(4, 4).T
        pts = np.asarray(points, dtype=float).reshape(-1, 3)
        clip = (P @ V @ np.concatenate([pts, np.ones((len(pts), 1))], 1).T).T
        ndc = clip[:, :3] / clip[:, 3:4]
        return np.stack([(ndc[:, 0] + 1) / 2 * width, (1 - ndc[:, 1]) / 2 * height], 1)


class _Recorder:
    """Records at the record times; samples that died get NaN rows."""

    def __init__(self):
        self.t, self.q, self.qd, self.qdd, self.V, self.D = [], [], [], [], [], []
        self.alive: list[Tensor] = []

    def add(self, t, q, qd, a, V, D, alive, monitor=None):
        """Record one time; ``monitor(i, t, q, qd, qdd, V)`` sees the live values of record i."""
        if monitor is not None:
            monitor(len(self.t), t, q, qd, a, V)
        m = alive[:, None]
        nan = float("nan")
        self.t.append(t)
        self.q.append(torch.where(m, q, nan).detach().clone())
        self.qd.append(torch.where(m, qd, nan).detach().clone())
        self.qdd.append(torch.where(m, a, nan).detach().clone())
        if V is not None:
            self.V.append(torch.where(alive, V, nan).detach().clone())
        if D is not None:
            self.D.append(torch.where(alive, D, nan).detach().clone())
        self.alive.append(alive.clone())

    @staticmethod
    def stack(xs):
        return torch.stack(xs)

    def death_index(self, alive, errors, n_steps, every) -> list[int]:
        """Last integration step each sample was alive at (approximate to a record for dead ones)."""
        out = []
        for b in range(alive.shape[0]):
            if errors[b] is None:
                out.append(n_steps)
                continue
            last = max((i for i, a in enumerate(self.alive) if bool(a[b])), default=0)
            out.append(min(n_steps, (last + 1) * every))
        return out


class _GoalTracker:
    """Per integration step: the first time within the goal tolerance, and the *execution* up to then (paper
    §4.2: an execution ends on reaching the goal or at the time-out): configuration-space and end-effector
    path lengths and the goal distance where it ended."""

    def __init__(self, B, dtype):
        self.reached = torch.zeros(B, dtype=torch.bool)
        self.time = torch.full((B,), float("nan"), dtype=dtype)
        self.cspace_length = torch.zeros(B, dtype=dtype)
        self.ee_length = torch.zeros(B, dtype=dtype)
        self.end_distance = torch.full((B,), float("nan"), dtype=dtype)
        self._prev: tuple[Tensor, Tensor] | None = None

    def update(self, t, ee, goal, tol, alive, q=None):
        ee = ee.detach()
        dist = (ee - goal).norm(dim=-1)
        going = alive & ~self.reached  # executions still running at this step
        if q is not None:
            q = q.detach()
            if self._prev is not None:
                pq, pe = self._prev
                self.cspace_length += torch.where(going, (q - pq).norm(dim=-1), 0.0)
                self.ee_length += torch.where(going, (ee - pe).norm(dim=-1), 0.0)
            self._prev = (q.clone(), ee.clone())
        self.end_distance = torch.where(going, dist, self.end_distance)
        hit = (dist <= tol) & going
        self.time = torch.where(hit, torch.full_like(self.time, t), self.time)
        self.reached |= hit
