"""Batched 2D point-particle environment of the paper's 2d1level / 2d2level experiments (§4.1, App. D.1).

The particle is a double integrator q̈ = π(q, q̇, aux) in the plane. An *environment* is one draw of the
auxiliary state (goal, obstacle centres and radii); many initial states share each environment, and the
whole flat batch is integrated at once. Layout: goals on the right, starts on the left, obstacles around
the segment joining them, so a policy has to deal with the obstacle to reach the goal.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Literal, Mapping

import torch
from pydantic import Field, model_validator
from torch import Tensor

from ..registry import ENVS, Params
from .common import SeededSampling, qdd_of, redraw_until_ok, rk4, semi_implicit_euler

Range = tuple[float, float]
Box = tuple[tuple[float, float], tuple[float, float]]  # ((x_low, x_high), (y_low, y_high))

_DTYPES = {"float64": torch.float64, "float32": torch.float32}


@dataclass
class Rollout:
    """A batch of closed-loop trajectories sampled at the record times.

    ``V`` and ``dissipation`` (q̇ᵀ B q̇ at the root, so dV/dt should equal −dissipation) exist only when
    the policy returns a TreeOutput (an RMPTree); for a plain callable they are None.
    """

    times: Tensor  # (T,)
    q: Tensor  # (T, B, 2)
    qd: Tensor  # (T, B, 2)
    qdd: Tensor  # (T, B, 2)
    collided: Tensor  # (B,) bool: inside an obstacle at any integration step
    reached: Tensor  # (B,) bool: within goal_tolerance at any integration step
    success: Tensor  # (B,) bool: within goal_tolerance at the final time and never collided
    min_clearance: Tensor  # (B,) closest approach to any obstacle surface (negative = penetration)
    first_collision_time: Tensor | None = None  # (B,) first integration time inside an obstacle (s), inf if never
    V: Tensor | None = None  # (T, B)
    dissipation: Tensor | None = None  # (T, B)

    @property
    def batch_size(self) -> int:
        return self.q.shape[1]


def _check_range(name: str, r: Range) -> None:
    if not r[0] <= r[1]:
        raise ValueError(f"{name}: low {r[0]} is above high {r[1]}")


@ENVS.register("particle2d")
class Particle2D(SeededSampling):
    """Goal reaching around 1 (2d1level) or 2 (2d2level) circular obstacles in a [-5, 5]² workspace."""

    class Params(Params):
        n_obstacles: int = Field(1, ge=0, description="1 for 2d1level, 2 for 2d2level")
        workspace: Range = Field((-5.0, 5.0), description="square workspace bounds; every sample lies inside")
        goal_region: Box = Field(((2.0, 3.5), (-2.0, 2.0)), description="goal ~ uniform in this box")
        start_region: Box = Field(((-3.5, -2.0), (-2.0, 2.0)), description="initial positions ~ uniform in this box")
        start_speed: Range = Field((0.0, 1.0), description="initial speed ~ uniform, direction ~ uniform")
        obstacle_along: Range = Field(
            (0.3, 0.7), description="obstacle centre at this fraction of the way from the start-region centre to the goal"
        )
        obstacle_across: Range = Field((-1.0, 1.0), description="and this far perpendicular to that segment")
        obstacle_radius: Range = Field((0.5, 1.5))
        clearance: float = Field(0.3, ge=0, description="minimum distance from any obstacle surface to a start or goal")
        obstacle_gap: float = Field(
            0.5, ge=0, description="minimum distance between obstacle surfaces, so obstacles never merge into a trap"
        )
        max_tries: int = Field(1000, ge=1, description="rejection-sampling rounds before giving up")
        dt: float = Field(0.01, gt=0, description="integration step (s)")
        integrator: Literal["semi_implicit_euler", "rk4"] = "rk4"
        goal_tolerance: float = Field(0.1, gt=0)
        dtype: Literal["float64", "float32"] = "float64"

        @model_validator(mode="after")
        def _ranges(self):
            for name in ("workspace", "start_speed", "obstacle_along", "obstacle_across", "obstacle_radius"):
                _check_range(name, getattr(self, name))
            for name in ("goal_region", "start_region"):
                for axis, r in zip("xy", getattr(self, name)):
                    _check_range(f"{name}.{axis}", r)
                    if r[0] < self.workspace[0] or r[1] > self.workspace[1]:
                        raise ValueError(f"{name}.{axis} {r} leaves the workspace {self.workspace}")
            if self.obstacle_radius[0] <= 0:
                raise ValueError("obstacle_radius must be positive")
            return self

    def __init__(self, params: Params | None = None, **overrides: Any):
        if params is None:
            params = self.Params(**overrides)
        elif overrides:
            params = params.model_copy(update=overrides)
            params = self.Params.model_validate(params.model_dump())
        self.params = params
        self.dtype = _DTYPES[params.dtype]

    # ------------------------------------------------------------------ auxiliary state
    @property
    def n_obstacles(self) -> int:
        return self.params.n_obstacles

    def aux_dims(self) -> dict[str, int]:
        """Names and sizes of the per-sample aux state; pass to ``build_tree(..., aux_dims=...)``."""
        dims = {"goal": 2}
        for k in range(1, self.n_obstacles + 1):
            dims[f"obstacle{k}_center"] = 2
            dims[f"obstacle{k}_radius"] = 1
        return dims

    def obstacles(self, aux: Mapping[str, Tensor]) -> tuple[Tensor, Tensor]:
        """Centres (B, K, 2) and radii (B, K) stacked from the aux dict."""
        K = self.n_obstacles
        if K == 0:
            g = aux["goal"]
            return g.new_zeros(g.shape[0], 0, 2), g.new_zeros(g.shape[0], 0)
        c = torch.stack([aux[f"obstacle{k}_center"] for k in range(1, K + 1)], 1)
        r = torch.stack([aux[f"obstacle{k}_radius"].reshape(-1) for k in range(1, K + 1)], 1)
        return c, r

    def clearance(self, q: Tensor, aux: Mapping[str, Tensor]) -> Tensor:
        """(B,) signed distance to the nearest obstacle surface (+inf without obstacles)."""
        c, r = self.obstacles(aux)
        if c.shape[1] == 0:
            return q.new_full((q.shape[0],), float("inf"))
        return ((q[:, None, :] - c).norm(dim=-1) - r).min(dim=1).values

    def in_collision(self, q: Tensor, aux: Mapping[str, Tensor]) -> Tensor:
        """(B,) bool: strictly inside some obstacle."""
        return self.clearance(q, aux) < 0

    def success(self, q: Tensor, aux: Mapping[str, Tensor]) -> Tensor:
        """(B,) bool: within goal_tolerance of the goal."""
        return (q - aux["goal"]).norm(dim=-1) <= self.params.goal_tolerance

    # ------------------------------------------------------------------ sampling
    def _uniform(self, shape: tuple[int, ...], r: Range, g: torch.Generator | None) -> Tensor:
        u = torch.rand(shape, generator=g, dtype=self.dtype)
        return r[0] + (r[1] - r[0]) * u

    def _box(self, n: int, box: Box, g: torch.Generator | None) -> Tensor:
        return torch.stack([self._uniform((n,), box[0], g), self._uniform((n,), box[1], g)], -1)

    def _start_centre(self) -> Tensor:
        (x0, x1), (y0, y1) = self.params.start_region
        return torch.tensor([(x0 + x1) / 2, (y0 + y1) / 2], dtype=self.dtype)

    def _draw_envs(self, n: int, g: torch.Generator | None) -> tuple[Tensor, Tensor, Tensor]:
        p = self.params
        goal = self._box(n, p.goal_region, g)
        seg = goal - self._start_centre()  # from the start region towards the goal
        normal = torch.stack([-seg[:, 1], seg[:, 0]], -1) / seg.norm(dim=-1, keepdim=True).clamp(min=1e-12)
        K = p.n_obstacles
        along = self._uniform((n, K), p.obstacle_along, g)
        across = self._uniform((n, K), p.obstacle_across, g)
        radius = self._uniform((n, K), p.obstacle_radius, g)
        centre = self._start_centre() + along[..., None] * seg[:, None, :] + across[..., None] * normal[:, None, :]
        return goal, centre, radius

    def _env_ok(self, goal: Tensor, centre: Tensor, radius: Tensor) -> Tensor:
        p = self.params
        ok = ((goal[:, None, :] - centre).norm(dim=-1) - radius >= p.clearance).all(1)
        lo, hi = p.workspace
        ok &= ((centre - radius[..., None] >= lo) & (centre + radius[..., None] <= hi)).all(-1).all(-1)
        K = centre.shape[1]
        for i in range(K):
            for j in range(i + 1, K):
                gap = (centre[:, i] - centre[:, j]).norm(dim=-1) - radius[:, i] - radius[:, j]
                ok &= gap >= p.obstacle_gap
        return ok

    def sample_envs(self, n_envs: int, generator: torch.Generator | None = None) -> dict[str, Tensor]:
        """``n_envs`` environments as an aux dict of (n_envs, k) tensors; reproducible given the generator.

        Rejection sampling: every environment is redrawn until its goal clears every obstacle by
        ``clearance``, obstacles stay inside the workspace and apart by ``obstacle_gap``.
        """
        goal, centre, radius = self._draw_envs(n_envs, generator)
        bad = ~self._env_ok(goal, centre, radius)
        tries = 1
        while bool(bad.any()):
            if tries >= self.params.max_tries:
                raise RuntimeError(
                    f"particle2d: could not sample {int(bad.sum())} environments in {tries} rounds; "
                    "widen the sampling ranges or lower clearance/obstacle_gap"
                )
            g2, c2, r2 = self._draw_envs(n_envs, generator)  # fixed-size draws keep the stream deterministic
            take = bad & self._env_ok(g2, c2, r2)
            goal = torch.where(take[:, None], g2, goal)
            centre = torch.where(take[:, None, None], c2, centre)
            radius = torch.where(take[:, None], r2, radius)
            bad &= ~take
            tries += 1
        aux = {"goal": goal}
        for k in range(self.n_obstacles):
            aux[f"obstacle{k + 1}_center"] = centre[:, k].contiguous()
            aux[f"obstacle{k + 1}_radius"] = radius[:, k : k + 1].contiguous()
        return aux

    def sample_initial_states(
        self, envs_aux: Mapping[str, Tensor], n_per_env: int, generator: torch.Generator | None = None
    ) -> tuple[Tensor, Tensor, dict[str, Tensor]]:
        """(q0, qd0, aux) for a flat batch of n_envs·n_per_env, environment-major (sample b is in env b // n_per_env).

        Start positions are redrawn until they clear every obstacle by ``clearance``.
        """
        p = self.params
        n_envs = envs_aux["goal"].shape[0]
        aux = {k: v.repeat_interleave(n_per_env, dim=0) for k, v in envs_aux.items()}
        n = n_envs * n_per_env

        def draw():
            q = self._box(n, p.start_region, generator)
            speed = self._uniform((n,), p.start_speed, generator)
            angle = self._uniform((n,), (-torch.pi, torch.pi), generator)
            return q, speed[:, None] * torch.stack([angle.cos(), angle.sin()], -1)

        q0, qd0 = redraw_until_ok(
            draw, lambda v, a: self.clearance(v[0], a) >= p.clearance, aux, p.max_tries,
            lambda left: f"particle2d: could not place {left} start states clear of the obstacles")
        return q0, qd0, aux

    # ------------------------------------------------------------------ dynamics
    def rollout(
        self,
        policy: Callable[..., Any],
        q0: Tensor,
        qd0: Tensor,
        aux: Mapping[str, Tensor],
        horizon: float,
        record_every: float,
        monitor: Callable[..., Any] | None = None,
        progress: Callable[[int, int], Any] | None = None,
        enable_grad: bool = False,
    ) -> Rollout:
        """Integrate q̈ = policy(q, q̇, aux) for the whole batch with the fixed-step integrator.

        ``policy`` may return a tensor (B, 2) or a TreeOutput (an RMPTree does); in the latter case V and
        q̇ᵀBq̇ are recorded from the same evaluation that gives the recorded q̈, so they cost nothing extra.
        ``record_every`` must be a multiple of ``dt``; records are at t = 0, record_every, ... ≤ horizon.
        ``monitor(i, t, q, qd, qdd, V)`` is called at each record; ``progress(step, total)`` after each
        record with integration steps done. Runs under ``torch.no_grad()`` unless ``enable_grad``.
        """
        dt = self.params.dt
        n_steps = int(round(horizon / dt))
        every = int(round(record_every / dt))
        if every < 1 or abs(every * dt - record_every) > 1e-9 * max(1.0, record_every):
            raise ValueError(f"record_every={record_every} must be a positive multiple of dt={dt}")
        if abs(n_steps * dt - horizon) > 1e-9 * max(1.0, horizon):
            raise ValueError(f"horizon={horizon} must be a multiple of dt={dt}")
        if q0.dim() != 2 or q0.shape[-1] != 2 or qd0.shape != q0.shape:
            raise ValueError(f"q0 and qd0 must both be (B, 2); got {tuple(q0.shape)} and {tuple(qd0.shape)}")
        step = semi_implicit_euler if self.params.integrator == "semi_implicit_euler" else rk4
        with torch.set_grad_enabled(enable_grad):
            return self._rollout(policy, step, q0, qd0, dict(aux), dt, n_steps, every, monitor, progress)

    def _rollout(self, policy, step, q0, qd0, aux, dt, n_steps, every, monitor, progress) -> Rollout:
        q, qd = q0, qd0
        qs, qds, qdds, Vs, Ds, ts = [], [], [], [], [], []
        clear = self.clearance(q, aux)
        min_clear = clear
        first_hit = torch.where(clear < 0, 0.0, float("inf")).to(q0.dtype)
        reached = self.success(q, aux)

        def accel(x, xd):
            return qdd_of(policy(x, xd, aux))

        for k in range(n_steps + 1):
            a = None
            if k % every == 0:
                out = policy(q, qd, aux)
                a = qdd_of(out)
                V = None if isinstance(out, Tensor) else getattr(out, "V", None)
                qs.append(q), qds.append(qd), qdds.append(a), ts.append(k * dt)
                if V is not None:
                    Vs.append(V)
                    Bm = getattr(out, "B", None)
                    if Bm is not None:
                        Ds.append(torch.einsum("bi,bij,bj->b", qd, Bm, qd))
                if monitor is not None:
                    monitor(len(ts) - 1, k * dt, q, qd, a, V)
            if progress is not None and (k % every == 0 or k == n_steps):
                progress(k, n_steps)
            if k == n_steps:
                break
            q, qd = step(accel, q, qd, dt, a)
            clear = self.clearance(q, aux)
            min_clear = torch.minimum(min_clear, clear)
            first_hit = torch.where((clear < 0) & first_hit.isinf(), (k + 1) * dt, first_hit)
            reached = reached | self.success(q, aux)
        collided = min_clear < 0
        return Rollout(
            times=torch.tensor(ts, dtype=q0.dtype),
            q=torch.stack(qs),
            qd=torch.stack(qds),
            qdd=torch.stack(qdds),
            collided=collided,
            reached=reached,
            success=self.success(q, aux) & ~collided,
            min_clearance=min_clear,
            first_collision_time=first_hit,
            V=torch.stack(Vs) if Vs else None,
            dissipation=torch.stack(Ds) if Ds else None,
        )
