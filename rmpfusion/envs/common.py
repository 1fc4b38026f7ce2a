"""What every environment shares: closed-loop integrators, the record grid, policy evaluation with its
monitoring quantities, sampling by seed, rejection sampling."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any, Protocol

import torch
from torch import Tensor

from ..core.gds import quad

#: The ``dtype`` setting of an environment's Params as a torch dtype.
DTYPES = {"float64": torch.float64, "float32": torch.float32}


def qdd_of(out: Any) -> Tensor:
    """The acceleration of a policy's answer: a tensor, or a TreeOutput."""
    return out if isinstance(out, Tensor) else out.qdd


def obstacle_aux_dims(space: int, n_obstacles: int) -> dict[str, int]:
    """The aux layout of a goal among obstacles: ``goal`` (space,), then ``obstacle{k}_center`` (space,) and
    ``obstacle{k}_radius`` (1,) for k = 1..K. Tree specs name these keys, so every environment spells them alike."""
    dims = {"goal": space}
    for k in range(1, n_obstacles + 1):
        dims[f"obstacle{k}_center"] = space
        dims[f"obstacle{k}_radius"] = 1
    return dims


def obstacle_aux(goal: Tensor, centers: Tensor, radii: Tensor) -> dict[str, Tensor]:
    """The aux dict of goals (n, space), centres (n, K, space) and radii (n, K), laid out as ``obstacle_aux_dims``."""
    aux = {"goal": goal}
    for k in range(centers.shape[1]):
        aux[f"obstacle{k + 1}_center"] = centers[:, k].contiguous()
        aux[f"obstacle{k + 1}_radius"] = radii[:, k : k + 1].contiguous()
    return aux


def stack_obstacles(aux: Mapping[str, Tensor], n_obstacles: int) -> tuple[Tensor, Tensor]:
    """Centres (n, K, space) and radii (n, K) stacked from an aux dict laid out as ``obstacle_aux_dims``."""
    if n_obstacles == 0:
        g = aux["goal"]
        return g.new_zeros(g.shape[0], 0, g.shape[-1]), g.new_zeros(g.shape[0], 0)
    c = torch.stack([aux[f"obstacle{k}_center"] for k in range(1, n_obstacles + 1)], 1)
    r = torch.stack([aux[f"obstacle{k}_radius"].reshape(-1) for k in range(1, n_obstacles + 1)], 1)
    return c, r


class ComputesOnDevice:
    """The ``to`` of an environment that computes policies on a device (``envs.protocol.ComputesOn``): what runs
    there is the environment's to say (the particle integrates there; the manipulator sends each step's state);
    sampling, records and simulators stay on the CPU, and rollouts come back on it."""

    device: torch.device = torch.device("cpu")

    def to(self, device: torch.device | str):
        """Compute policies on ``device`` from now on; returns the environment."""
        self.device = torch.device(device)
        return self


class OnDevice:
    """A policy that computes on ``device`` for a caller holding its states elsewhere (pybullet's CPU, a dataset):
    the state goes over, the answer (a tensor or a tree's output) comes back to the state's device, once a call."""

    def __init__(self, policy: Callable[..., Any], device: torch.device | str):
        self.policy, self.device = policy, torch.device(device)

    def __call__(self, q: Tensor, qd: Tensor, aux: Mapping[str, Tensor]):
        home = q.device
        out = self.policy(q.to(self.device), qd.to(self.device), {k: v.to(self.device) for k, v in aux.items()})
        return out.to(home)


def on_device(policy: Callable[..., Any], device: torch.device | str | None) -> Callable[..., Any]:
    """``policy`` as it is on the CPU (or where no device is set), else wrapped to compute on ``device``."""
    if device is None or torch.device(device).type == "cpu":
        return policy
    return OnDevice(policy, device)


def evaluate_policy(
    policy: Callable[..., Any], q: Tensor, qd: Tensor, aux: Mapping[str, Tensor]
) -> tuple[Tensor, Tensor | None, Tensor | None]:
    """(q̈, V, q̇ᵀBq̇) of one policy evaluation: a tree's V and dissipation come from the same evaluation that gives
    the recorded q̈, so monitoring them costs nothing; a plain callable's tensor has neither (None, None)."""
    out = policy(q, qd, aux)
    if isinstance(out, Tensor):
        return out, None, None
    return out.qdd, out.V, quad(qd, out.B)


def time_grid(horizon: float, record_every: float, dt: float, step: str = "dt") -> tuple[int, int]:
    """(integration steps, steps between records) of a rollout on the fixed step ``dt`` (named ``step`` in errors).

    Records and the horizon must fall on the step grid: rounding them silently would record other times than
    asked and compare rollouts of different lengths.
    """
    n_steps = round(horizon / dt)
    every = round(record_every / dt)
    if every < 1 or abs(every * dt - record_every) > 1e-9 * max(1.0, record_every):
        raise ValueError(f"record_every={record_every} must be a positive multiple of {step}={dt}")
    if abs(n_steps * dt - horizon) > 1e-9 * max(1.0, horizon):
        raise ValueError(f"horizon={horizon} must be a multiple of {step}={dt}")
    return n_steps, every


def check_initial_states(q0: Tensor, qd0: Tensor, dim: int) -> None:
    """Refuse initial states that are not a (B, dim) batch, before any integration step is spent on them."""
    if q0.dim() != 2 or q0.shape[-1] != dim or qd0.shape != q0.shape:
        raise ValueError(f"q0 and qd0 must both be (B, {dim}); got {tuple(q0.shape)} and {tuple(qd0.shape)}")


def semi_implicit_euler(accel, q, qd, dt, a=None):
    """Symplectic Euler: velocity first, then position with the new velocity (first order, no energy drift)."""
    if a is None:
        a = accel(q, qd)
    qd = qd + dt * a
    return q + dt * qd, qd


def rk4(accel, q, qd, dt, a=None):
    """Classical RK4 on the first-order system (q, q̇); ``a`` reuses an acceleration already evaluated at (q, q̇)."""
    k1v = accel(q, qd) if a is None else a
    k1x = qd
    k2x = qd + 0.5 * dt * k1v
    k2v = accel(q + 0.5 * dt * k1x, k2x)
    k3x = qd + 0.5 * dt * k2v
    k3v = accel(q + 0.5 * dt * k2x, k3x)
    k4x = qd + dt * k3v
    k4v = accel(q + dt * k3x, k4x)
    return (q + dt / 6 * (k1x + 2 * k2x + 2 * k3x + k4x), qd + dt / 6 * (k1v + 2 * k2v + 2 * k3v + k4v))


class SamplingError(RuntimeError):
    """The environment's sampling region cannot give the states its config asks for (starts clear of the
    obstacles, goals apart from starts): a setting to change, so the command line prints the message alone."""


def redraw_until_ok(
    draw: Callable[[], tuple[Tensor, ...]],
    ok: Callable[[tuple[Tensor, ...], Mapping[str, Tensor]], Tensor],
    aux: Mapping[str, Tensor],
    max_tries: int,
    failure: Callable[[int], str],
) -> tuple[Tensor, ...]:
    """Rejection sampling of a batch: redraw every rejected sample until ``ok`` accepts it.

    Every round draws the whole batch, so the random stream (and with it every sample) does not depend on how
    many were rejected before. ``ok`` is only asked about the samples still rejected (with their aux rows), so
    expensive checks (pybullet clearance) run on few samples; ``failure(n_left)`` is the error after
    ``max_tries`` rounds (a ``SamplingError``).
    """
    vals = draw()
    bad = ~ok(vals, aux)
    tries = 1
    while bool(bad.any()):
        if tries >= max_tries:
            raise SamplingError(failure(int(bad.sum())))
        new = draw()
        idx = bad.nonzero().flatten()
        good = ok(tuple(v[idx] for v in new), {k: v[idx] for k, v in aux.items()})
        take = torch.zeros_like(bad)
        take[idx[good]] = True
        vals = tuple(torch.where(take.view(-1, *[1] * (v.dim() - 1)), nv, v) for v, nv in zip(vals, new))
        bad &= ~take
        tries += 1
    return vals


class _SamplesStates(Protocol):
    """What ``SeededSampling`` needs of the environment it is mixed into (``Env``'s two sampling steps)."""

    def sample_envs(
        self, n_envs: int, generator: torch.Generator | None = None, split: str = "train"
    ) -> dict[str, Tensor]: ...

    def sample_initial_states(
        self, envs_aux: Mapping[str, Tensor], n_per_env: int, generator: torch.Generator | None = None
    ) -> tuple[Tensor, Tensor, dict[str, Tensor]]: ...


class SeededSampling:
    """Mixin: environments and initial states in one call, from a seed or a generator."""

    def sample(
        self: _SamplesStates,
        n_envs: int,
        n_per_env: int,
        seed: int | None = None,
        generator: torch.Generator | None = None,
    ) -> tuple[Tensor, Tensor, dict[str, Tensor]]:
        if generator is None and seed is not None:
            generator = torch.Generator().manual_seed(seed)
        return self.sample_initial_states(self.sample_envs(n_envs, generator), n_per_env, generator)
