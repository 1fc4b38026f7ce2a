"""Batched 2D point-particle environment of the paper's 2d1level / 2d2level experiments (§4.1, App. D.1).

The particle is a double integrator q̈ = π(q, q̇, aux) in the plane. An *environment* is one draw of the
auxiliary state (goal, obstacle centres and radii); many initial states share each environment, and the
whole flat batch is integrated at once. Layout: goals on the right, starts on the left, obstacles around
the segment joining them, so a policy has to deal with the obstacle to reach the goal.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any, Literal

import torch
from pydantic import Field, ValidationError, ValidationInfo, field_validator, model_validator
from torch import Tensor

from ..registry import ENVS, Params
from .common import (
    DTYPES,
    ComputesOnDevice,
    SeededSampling,
    check_initial_states,
    evaluate_policy,
    obstacle_aux,
    obstacle_aux_dims,
    qdd_of,
    redraw_until_ok,
    rk4,
    semi_implicit_euler,
    stack_obstacles,
    time_grid,
)
from .demonstrations import Dataset, collect
from .protocol import ObstacleDepths
from .rollout import Rollout

#: what the plane's obstacle depths measure, said beside every entry reported
PLANE_MEASURE = "the distance from the position to each disc's edge (below 0: inside it)"

#: The settings that say where environments and starts are drawn: the ones ``test_sampling`` may change.
SAMPLER_SETTINGS = (
    "goal_region",
    "start_region",
    "start_speed",
    "obstacle_along",
    "obstacle_across",
    "obstacle_radius",
    "clearance",
    "obstacle_gap",
)

Range = tuple[float, float]
Box = tuple[tuple[float, float], tuple[float, float]]  # ((x_low, x_high), (y_low, y_high))


def _check_range(name: str, r: Range, strict: bool = False) -> None:
    """A (low, high) sampling range: low ≤ high (low < high with ``strict``), NaN refused."""
    if not (r[0] < r[1] if strict else r[0] <= r[1]):
        raise ValueError(
            f"{name} must be (low, high) with low {'<' if strict else '≤'} high (values are drawn "
            f"uniformly between them); given {tuple(r)}"
        )


@ENVS.register("particle2d")
class Particle2D(ComputesOnDevice, SeededSampling):
    """Goal reaching around 1 (2d1level) or 2 (2d2level) circular obstacles in a [-5, 5]² workspace.

    A ``rollout`` records collisions (strictly inside an obstacle) and success (within ``goal_tolerance`` at the
    final time); it never ends a sample early, so its ``Rollout.error`` stays empty.
    """

    dim = 2

    class Params(Params):
        n_obstacles: int = Field(1, ge=0, description="1 for 2d1level, 2 for 2d2level")
        workspace: Range = Field((-5.0, 5.0), description="square workspace bounds; every sample lies inside")
        goal_region: Box = Field(((2.0, 3.5), (-2.0, 2.0)), description="goal ~ uniform in this box")
        start_region: Box = Field(((-3.5, -2.0), (-2.0, 2.0)), description="initial positions ~ uniform in this box")
        start_speed: Range = Field((0.0, 1.0), description="initial speed ~ uniform, direction ~ uniform")
        obstacle_along: Range = Field(
            (0.3, 0.7),
            description="obstacle centre at this fraction of the way from the start-region centre to the goal",
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
        test_sampling: dict[str, Any] = Field(
            default_factory=dict,
            description="the test split's own sampler settings, over the ones above (any of goal_region, start_region, "
            "start_speed, obstacle_along, obstacle_across, obstacle_radius, clearance, obstacle_gap): a "
            "test distribution unlike training's; the training and validation splits draw from the above",
        )

        @field_validator("workspace")
        @classmethod
        def _workspace(cls, v: Range) -> Range:
            _check_range("workspace", v, strict=True)
            return v

        @field_validator("obstacle_across")
        @classmethod
        def _range(cls, v: Range, info: ValidationInfo) -> Range:
            assert info.field_name is not None  # a field validator is always called for its field
            _check_range(info.field_name, v)
            return v

        @field_validator("start_speed")
        @classmethod
        def _speed(cls, v: Range) -> Range:
            _check_range("start_speed", v)
            if not v[0] >= 0:
                raise ValueError(
                    f"start_speed must have low ≥ 0 (it is a speed; the direction is drawn separately); "
                    f"given {tuple(v)}"
                )
            return v

        @field_validator("obstacle_along")
        @classmethod
        def _fraction(cls, v: Range) -> Range:
            _check_range("obstacle_along", v)
            if not (0 <= v[0] and v[1] <= 1):
                raise ValueError(
                    f"obstacle_along must lie in [0, 1] (a fraction of the way from the starts to the "
                    f"goal: outside it the obstacle is not between them); given {tuple(v)}"
                )
            return v

        @field_validator("obstacle_radius")
        @classmethod
        def _radius(cls, v: Range) -> Range:
            _check_range("obstacle_radius", v)
            if not v[0] > 0:
                raise ValueError(
                    f"obstacle_radius must have low > 0 (an obstacle of radius ≤ 0 is no obstacle); given {tuple(v)}"
                )
            return v

        @field_validator("goal_region", "start_region")
        @classmethod
        def _box(cls, v: Box, info: ValidationInfo) -> Box:
            ws = info.data.get("workspace")  # absent when the workspace itself was refused
            for axis, r in zip("xy", v):
                _check_range(f"{info.field_name}.{axis}", r)
                if ws is not None and (r[0] < ws[0] or r[1] > ws[1]):
                    raise ValueError(
                        f"{info.field_name}.{axis} must lie inside the workspace {tuple(ws)} (every "
                        f"sample lies in the workspace); given {tuple(r)}"
                    )
            return v

        @model_validator(mode="after")
        def _test_sampling(self):
            unknown = sorted(set(self.test_sampling) - set(SAMPLER_SETTINGS))
            if unknown:
                raise ValueError(
                    f"test_sampling may set only the sampler's settings ({', '.join(SAMPLER_SETTINGS)}); "
                    f"given {unknown}"
                )
            if self.test_sampling:
                try:
                    self.for_test()
                except ValidationError as e:
                    raise ValueError(f"test_sampling: {e.errors()[0]['loc'][0]}: {e.errors()[0]['msg']}") from None
            return self

        def for_test(self) -> Particle2D.Params:
            """These settings with ``test_sampling`` laid over them: what the test split is drawn from."""
            settings = self.model_dump(include=set(type(self).model_fields))
            return type(self).model_validate({**settings, **self.test_sampling, "test_sampling": {}})

        def integration_step(self) -> tuple[float, str]:
            """(seconds, the key that sets it) of the fixed step rollouts integrate on: a run config's recording
            interval and horizon are checked against it before anything runs (``time_grid`` at rollout time)."""
            return self.dt, "env.dt"

    def __init__(self, params: Params | None = None, **overrides: Any):
        if params is None:
            params = self.Params(**overrides)
        elif overrides:
            params = params.model_copy(update=overrides)
            params = self.Params.model_validate(params.model_dump())
        self.params = params
        self.dtype = DTYPES[params.dtype]

    # ------------------------------------------------------------------ auxiliary state
    @property
    def dt(self) -> float:
        """The integration step (s), ``params.dt``."""
        return self.params.dt

    @property
    def n_obstacles(self) -> int:
        return self.params.n_obstacles

    def aux_dims(self) -> dict[str, int]:
        """Names and sizes of the per-sample aux state; pass to ``build_tree(..., aux_dims=...)``."""
        return obstacle_aux_dims(self.dim, self.n_obstacles)

    def recorded_aux(self, goals: Tensor) -> dict[str, Tensor]:
        """Recorded motions in the plane: the goal is where a demonstration ends (recordings carry no obstacles:
        ``data.source: recorded`` is for the obstacle-free plane, ``env=plane``)."""
        return {"goal": goals.to(self.dtype)}

    def recorded_starts(self, candidates: Tensor) -> Tensor:
        """Any point of the obstacle-free plane may start at rest."""
        return torch.ones(len(candidates), dtype=torch.bool)

    def recorded_depths(self, q: Tensor, aux: Mapping[str, Tensor]) -> ObstacleDepths:
        """How positions ``q`` (M, 2) of recordings lie against the discs their aux rows place: the plane's
        recordings carry no obstacles unless their files give them (``data.aux_columns`` naming obstacle{k}_center
        and obstacle{k}_radius), so only the discs the rows hold are measured, by the exact distance from the
        position to each disc's edge (the particle is a point: its collision is this distance below 0)."""
        discs = [
            k for k in range(1, self.n_obstacles + 1) if f"obstacle{k}_center" in aux and f"obstacle{k}_radius" in aux
        ]
        names = tuple(f"obstacle{k} (disc)" for k in discs)
        q = q.to(self.dtype)
        if not discs:
            none = torch.zeros(len(q), dtype=torch.long)
            inf = torch.full((len(q),), float("inf"), dtype=self.dtype)
            return ObstacleDepths(inf, none, none, ("the position",), names, PLANE_MEASURE)
        c = torch.stack([aux[f"obstacle{k}_center"].to(q) for k in discs], 1)
        r = torch.stack([aux[f"obstacle{k}_radius"].to(q).reshape(-1) for k in discs], 1)
        best, which = ((q[:, None, :] - c).norm(dim=-1) - r).min(dim=-1)
        return ObstacleDepths(best, torch.zeros_like(which), which, ("the position",), names, PLANE_MEASURE)

    def obstacles(self, aux: Mapping[str, Tensor]) -> tuple[Tensor, Tensor]:
        """Centres (B, K, 2) and radii (B, K) stacked from the aux dict."""
        return stack_obstacles(aux, self.n_obstacles)

    def clearance(self, q: Tensor, aux: Mapping[str, Tensor]) -> Tensor:
        """(..., B) signed distance of positions q (..., B, 2) to the nearest obstacle surface (+inf without
        obstacles); differentiable in q (policy optimisation through rollouts penalises it)."""
        c, r = self.obstacles(aux)
        if c.shape[1] == 0:
            return q.new_full(q.shape[:-1], float("inf"))
        return ((q[..., None, :] - c).norm(dim=-1) - r).min(dim=-1).values

    def for_split(self, split: str) -> Particle2D:
        """The particle whose sampler draws ``split``: for ``test``, ``test_sampling`` laid over the sampler's
        settings (a harder test distribution than training's); itself for the other splits."""
        if split != "test" or not self.params.test_sampling:
            return self
        return Particle2D(self.params.for_test())

    def gradient_refusal(self) -> str | None:
        """None: the particle is integrated in torch, so its rollouts always keep the graph when asked to."""
        return None

    def with_step(self, dt: float) -> Particle2D:
        """The same particle and sampling, integrated on the step ``dt``."""
        settings = self.params.model_dump(include=set(self.Params.model_fields))  # not a config block's `type`
        return Particle2D(self.Params.model_validate({**settings, "dt": dt}))

    def goal_distance(self, q: Tensor, aux: Mapping[str, Tensor]) -> Tensor:
        """(..., B) distance of positions q (..., B, 2) to the goal; differentiable in q."""
        return (q - aux["goal"]).norm(dim=-1)

    def in_collision(self, q: Tensor, aux: Mapping[str, Tensor]) -> Tensor:
        """(B,) bool: strictly inside some obstacle."""
        return self.clearance(q, aux) < 0

    def success(self, q: Tensor, aux: Mapping[str, Tensor]) -> Tensor:
        """(B,) bool: within goal_tolerance of the goal."""
        return self.goal_distance(q, aux) <= self.params.goal_tolerance

    def task_metrics(self, rollout: Rollout) -> dict[str, Tensor]:
        """Per-trajectory (B,) metrics of the reaching task, from a rollout's records: ``time`` to come within
        ``goal_tolerance`` (the first such record; the horizon if never), ``path_length`` (the polyline through
        the records), ``final_distance`` to the goal, ``min_clearance`` (over every integration step, < 0 inside
        an obstacle), ``collided`` and ``success`` (at the goal at the end, never inside an obstacle)."""
        d = rollout.goal_distance
        assert d is not None  # this environment's rollouts record the goal distance
        near = d <= self.params.goal_tolerance
        first = torch.where(
            near.any(0), near.double().argmax(0), torch.full_like(near[0], len(rollout.times) - 1, dtype=torch.long)
        )
        return {
            "time": rollout.times[first].to(d.dtype),
            "path_length": (rollout.q[1:] - rollout.q[:-1]).norm(dim=-1).sum(0),
            "final_distance": d[-1],
            "min_clearance": rollout.min_clearance,
            "collided": rollout.collided.to(d.dtype),
            "success": rollout.success.to(d.dtype),
        }

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

    def sample_envs(
        self, n_envs: int, generator: torch.Generator | None = None, split: str = "train"
    ) -> dict[str, Tensor]:
        """``n_envs`` environments as an aux dict of (n_envs, k) tensors; reproducible given the generator.

        The training and validation splits are drawn from the same distribution; the test split too unless
        ``test_sampling`` changes its sampler (``for_split``). Rejection sampling: every environment is redrawn until its goal clears every obstacle
        by ``clearance``, obstacles stay inside the workspace and apart by ``obstacle_gap``.
        """
        if split == "test" and self.params.test_sampling:
            return self.for_split("test").sample_envs(n_envs, generator)
        max_tries = self.params.max_tries
        goal, centre, radius = redraw_until_ok(
            lambda: self._draw_envs(n_envs, generator),
            lambda v, _: self._env_ok(*v),
            {},
            max_tries,
            lambda left: (
                f"particle2d: could not sample {left} environments in {max_tries} rounds (env.max_tries) "
                f"with the goal env.clearance = {self.params.clearance} from every obstacle, the obstacles "
                f"env.obstacle_gap = {self.params.obstacle_gap} apart and inside env.workspace; widen "
                "env.goal_region or env.obstacle_along/obstacle_across, or lower env.obstacle_radius, "
                "env.clearance or env.obstacle_gap"
            ),
        )
        return obstacle_aux(goal, centre, radius)

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
            draw,
            lambda v, a: self.clearance(v[0], a) >= p.clearance,
            aux,
            p.max_tries,
            lambda left: (
                f"particle2d: could not place {left} start states env.clearance = {p.clearance} clear of "
                f"the obstacles in {p.max_tries} rounds (env.max_tries); widen env.start_region, or lower "
                "env.clearance or env.obstacle_radius"
            ),
        )
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
        dt = self.dt
        n_steps, every = time_grid(horizon, record_every, dt)
        check_initial_states(q0, qd0, self.dim)
        step = semi_implicit_euler if self.params.integrator == "semi_implicit_euler" else rk4
        home, d = q0.device, self.device
        with torch.set_grad_enabled(enable_grad):
            ro = self._rollout(
                policy,
                step,
                q0.to(d),
                qd0.to(d),
                {k: v.to(d) for k, v in aux.items()},
                dt,
                n_steps,
                every,
                monitor,
                progress,
            )
        return ro if d == home else ro.to(home)

    def _rollout(self, policy, step, q0, qd0, aux, dt, n_steps, every, monitor, progress) -> Rollout:
        q, qd = q0, qd0
        qs, qds, qdds, Vs, Ds, ts, dists = [], [], [], [], [], [], []
        clear = self.clearance(q, aux)
        min_clear = clear
        first_hit = torch.where(clear < 0, 0.0, float("inf")).to(q0)
        reached = self.success(q, aux)

        def accel(x, xd):
            return qdd_of(policy(x, xd, aux))

        for k in range(n_steps + 1):
            a = None
            if k % every == 0:
                a, V, D = evaluate_policy(policy, q, qd, aux)
                qs.append(q)
                qds.append(qd)
                qdds.append(a)
                ts.append(k * dt)
                dists.append(self.goal_distance(q, aux))
                if V is not None:
                    Vs.append(V)
                    if D is not None:
                        Ds.append(D)
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
            goal_distance=torch.stack(dists),
        )

    # ------------------------------------------------------------------ demonstrations
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
        """The expert's demonstrations (paper §4.1 "Data"): ``collect`` of ``n_points`` records ``interval`` s
        apart from ``n_traj`` starts in each of ``n_envs`` environments. The splits are drawn from the same
        distribution unless ``test_sampling`` sets the test split's own (``for_split``); the caller's generator
        tells splits apart."""
        return collect(self.for_split(split), expert, n_envs, n_traj, n_points, interval, generator, progress=progress)
