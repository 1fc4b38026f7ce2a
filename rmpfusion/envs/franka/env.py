"""The Franka environment: its aux state (goal, cylinders), reproducible sampling of environments and starts,
collision geometry, and the entry points that the rollout modes, demonstrations, metrics and rendering serve."""
from __future__ import annotations

from typing import Any, Callable, Literal, Mapping, Sequence

import numpy as np
import torch
from torch import Tensor

from ...maps.kinematics import Chain
from ...maps.urdf import PANDA_ARM_JOINTS, load_panda_urdf_path, parse_urdf
from ...registry import ENVS
from ..common import (DTYPES, SeededSampling, check_initial_states, obstacle_aux, obstacle_aux_dims, on_device,
                      redraw_until_ok, stack_obstacles, time_grid)
from ..demonstrations import Dataset
from ..franka_tree import EE_LINK, EE_OFFSET
from ..protocol import RenderSettings
from ..rollout import Rollout
from . import demonstrations as demos
from . import render as rendering
from .kinematic import rollout_kinematic
from .metrics import RATIO_METRICS, task_metrics
from .params import FrankaParams, ObstacleSpec
from .scene import HelperWorlds, _Scene, scene_args
from .torque import rollout_torque


@ENVS.register("franka")
class Franka(SeededSampling):
    """Franka Panda goal reaching around cylinders; see the package docstring for the two rollout modes."""

    Params = FrankaParams
    dim = 7
    ratio_metrics = RATIO_METRICS

    def __init__(self, params: FrankaParams | None = None, **overrides: Any):
        if params is None:
            params = self.Params(**overrides)
        elif overrides:
            params = self.Params.model_validate({**params.model_dump(), **overrides})
        self.params = params
        self.dtype = DTYPES[params.dtype]
        self.chain = Chain(parse_urdf(load_panda_urdf_path()), PANDA_ARM_JOINTS)
        self.lower, self.upper = (t.to(self.dtype) for t in self.chain.joint_limits())
        self._ee_offset = torch.tensor(EE_OFFSET, dtype=self.dtype)
        self.worlds = HelperWorlds(params.gravity)
        self.device = torch.device("cpu")  # where policies compute (``to``); pybullet and the records stay on the CPU

    def to(self, device: torch.device | str) -> "Franka":
        """Evaluate policies on ``device``: each step's state goes there and the acceleration comes back."""
        self.device = torch.device(device)
        return self

    # ------------------------------------------------------------------ bookkeeping
    @property
    def n_obstacles(self) -> int:
        return len(self.params.obstacles)

    @property
    def dt(self) -> float:
        """The pybullet / integration step, 1/control_rate (s)."""
        return 1.0 / self.params.control_rate

    def aux_dims(self) -> dict[str, int]:
        """Names and sizes of the per-sample aux state; pass to ``build_tree(..., aux_dims=...)``."""
        return obstacle_aux_dims(3, self.n_obstacles)

    def close(self) -> None:
        """Disconnect the helper pybullet worlds (collision checking, rendering)."""
        self.worlds.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def __del__(self):
        try:
            self.close()
        except Exception:  # noqa: BLE001 - interpreter shutdown
            pass

    def scene_args(self, aux: Mapping[str, Tensor], b: int):
        """Sample ``b``'s cylinders and goal as ``_Scene.set_env`` takes them (heights: the nominal cylinders')."""
        return scene_args(aux, b, [o.height for o in self.params.obstacles])

    def checker(self) -> _Scene:
        """The pybullet world that checks collisions (opened on first use)."""
        return self.worlds.checker()

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
            centers, radii, heights, _ = self.scene_args(aux, b)
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
        (goal,) = redraw_until_ok(
            lambda: (self._uniform((n, 3), lo, hi, generator),),
            lambda v, a: self._goal_ok(v[0], a["centers"], a["radii"]), {"centers": centers, "radii": radii},
            p.max_tries,
            lambda left: f"franka: no goal clear of the obstacles for {left} samples in {p.max_tries} rounds; "
                         "move goal_region or lower goal_clearance")
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
        return obstacle_aux(self._sample_goals(centers, radii, generator), centers, radii)

    def sample_initial_states(
        self, envs_aux: Mapping[str, Tensor], n_per_env: int, generator: torch.Generator | None = None
    ) -> tuple[Tensor, Tensor, dict[str, Tensor]]:
        """(q0, q̇0, aux) for n_envs·n_per_env samples, environment-major; starts are redrawn until they
        lie ``joint_margin`` inside the limits and clear every obstacle by ``start_clearance`` in pybullet."""
        p = self.params
        aux = {k: v.repeat_interleave(n_per_env, dim=0) for k, v in envs_aux.items()}
        n = aux["goal"].shape[0]
        if p.goal_per_trajectory:
            aux["goal"] = self._sample_goals(*stack_obstacles(aux, self.n_obstacles), generator)
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
    ) -> Rollout:
        """Run q̈ = policy(q, q̇, aux) for ``horizon`` seconds from (q0, q̇0), batched over samples.

        ``policy`` returns a (B, 7) tensor or a TreeOutput (then V and q̇ᵀBq̇ are recorded from the same
        evaluation). ``record_every`` and ``horizon`` must be multiples of 1/control_rate. ``mode``
        overrides the env's. ``monitor(i, t, q, qd, qdd, V)`` is called at each record, and
        ``progress(i, total)`` too.
        """
        n_steps, every = time_grid(horizon, record_every, self.dt, "1/control_rate")
        check_initial_states(q0, qd0, self.dim)
        mode = mode or self.params.mode
        if progress is not None:  # progress(records done, records in all), reported at every record
            monitor = _reporting(monitor, progress, n_steps // every)
        aux = {k: torch.as_tensor(v, dtype=self.dtype) for k, v in aux.items()}  # lists: never via float32
        q0, qd0 = q0.to(self.dtype), qd0.to(self.dtype)
        run = rollout_torque if mode == "torque" else rollout_kinematic
        with torch.set_grad_enabled(enable_grad):
            return run(self, on_device(policy, self.device), q0, qd0, aux, n_steps, every, monitor)

    # ------------------------------------------------------------------ demonstrations and task metrics
    def demonstration_lengths(self, ro: Rollout) -> Tensor:
        """(B,) records to keep of each demonstration; see ``franka.demonstrations.demonstration_lengths``."""
        return demos.demonstration_lengths(self.params, ro)

    def demonstrations(self, expert: Callable[..., Any], n_envs: int, n_traj: int, n_points: int, interval: float,
                       generator: torch.Generator | None = None, split: str = "train",
                       progress: Callable[[int, int], Any] | None = None) -> Dataset:
        """The expert's demonstrations of a data split (paper §4.2): 5–10 s each, the split's obstacles, a goal per
        trajectory; see ``franka.demonstrations.demonstrations``."""
        return demos.demonstrations(self, expert, n_envs, n_traj, n_points, interval, generator, split, progress)

    def task_metrics(self, ro: Rollout) -> dict[str, Tensor]:
        """Per-trajectory (B,) metrics of paper §4.2; see ``franka.metrics.task_metrics``."""
        return task_metrics(ro, self.dtype)

    # ------------------------------------------------------------------ rendering
    @property
    def render_settings(self) -> RenderSettings:
        p = self.params
        return RenderSettings(size=tuple(p.render_size), times=tuple(p.render_times), gif_fps=p.gif_fps,
                              trajectory=p.render_trajectory)

    def render(self, q: Tensor | Sequence[float], aux: Mapping[str, Tensor], width: int = 320, height: int = 240,
               sample: int = 0) -> np.ndarray:
        """(height, width, 3) uint8 image of the robot at ``q`` in environment ``aux[sample]``, rendered
        headless by pybullet's tiny renderer, for figures and animations."""
        return rendering.render(self, q, aux, width, height, sample)

    def project(self, points, width: int = 320, height: int = 240) -> np.ndarray:
        """(N, 2) pixel coordinates (column, row) of world points (N, 3) in ``render``'s image, to draw paths on it."""
        return rendering.project(self.params.camera, points, width, height)


def _reporting(monitor: Callable[..., Any] | None, progress: Callable[[int, int], Any],
               total: int) -> Callable[..., Any]:
    """``monitor`` that also reports ``progress(records done, records in all)`` at every record."""

    def both(i, *rest):
        if monitor is not None:
            monitor(i, *rest)
        progress(i, total)

    return both
