#!/usr/bin/env python
"""rmpfusion's performance table (`make bench`): every figure is a median over repeated runs, measured side
by side with its reference in the same process, so the ratios hold whatever else the machine is doing. Rows with
a target say whether it is met.

    python -m tools.bench                   # the whole table (~15 min on 2 cores, most of it torch.compile)
    python -m tools.bench --only reference  # one section: reference, latency, compile, scaling, sets, clouds, batched, train, rollout, cuda, robots, collisions, memory
    python -m tools.bench --no-compile      # eager only (--no-export: no AOTInductor packages)
    python -m tools.bench --check           # also compare the ratios with this machine kind's baseline: exit 1 if one
                                            # rose beyond noise (make bench: --check --store-baseline)

Every row with a ratio (a subject's time over its reference's, both timed in the same rounds) is what the baseline
of tools/bench_baseline.json keeps per kind of machine (CPU model, cores, torch version): see
tools/bench_baseline.py. CI runs ``--only reference --no-export --check``.

Run it from the repository root as a module (``-m``): it reads the test-vector tree and the numpy RMPflow oracle
from tests/ and the world demo's controller from tools/ (both packages of the checkout).

Sections:
  reference  B = 1, the control-loop case: the test-vector tree (RMPflow's two reference leaves) beside an
           independent numpy transcription of RMPflow's reference code (its policy: f and M resolved), eager,
           compiled as a controller's and exported with AOTInductor, all timed in the same rounds as the numpy.
  latency  B = 1: the 2d2level learner tree; the Franka expert tree (46 nodes), eager, compiled, and exported with
           AOTInductor (rmpfusion-export --aoti).
  compile  the Franka tree's time to compile, in a fresh process with an empty inductor cache (a user's first).
  scaling  the Franka tree with 1, 10 and 100 obstacles (14 control points each), B = 1 and B = 1024: how the
           cost grows with the work.
  batched  2d2level tree with neural weights (including ∇w), B = 4096: states/s.
  train    2d2level learner-rmp training step (minibatch 200: forward, backward through the h_i terms, RMSprop
           step), the config-built tree against a hand-fused reference of the same math written below (all four
           weight MLPs stacked into batched matrix products, every map and leaf inlined). Both are checked to
           agree to 1e-9 before they are timed.
  rollout  an evaluation rollout step of experiment=recorded_arm's tree for 100 starts at rest (the kinematic
           simulator's step: the tree with its monitoring quantities, the integrator, goal tracking, records), eager
           and compiled side by side (target: the compiled step ≤ 0.05 of the eager one).
  cuda     with a CUDA device only: 2d2level at B = 65,536 and the training step, on the GPU.
  robots   rmpfusion-fit-spheres on a 7-joint arm with meshes (the xArm7 of example-robot-data, else the iiwa of
           pybullet_data), as a user runs it: one fresh process, its wall time (target ≤ 60 s on two cores).
  collisions  the collision check of a kinematic evaluation: the Franka expert's rollouts from 100 starts over
           5,871 steps of 4 ms (the recorded-arm evaluation's size; --collision-steps N for fewer), checked by the
           per-configuration pybullet replay and by the batched check (sphere bounds in torch, pybullet where they
           cannot decide), side by side; both are checked to agree (flags, first collision times, clearances within
           the check's 1 mm) before the times are printed (target: the batched check ≤ 10 s).
  memory   the peak resident memory of a 2d2level training run (a child process) while it trains, over what was
           resident before its first step (the kernel's high-water mark, reset at that point); and the same of one
           eager call of the Franka tree with a run-time sphere set of N_max = 1 and 100 members at B = 1024.
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import os
import platform
import statistics
import subprocess
import sys
import time
import warnings
from collections.abc import Callable
from pathlib import Path

import torch
import torch.nn.functional as F

import rmpfusion
from tools import bench_baseline as baseline
from tools.bench_baseline import Ratio, side_by_side

ROOT = Path(__file__).resolve().parents[1]


# ---------------------------------------------------------------------------------------------- timing
def median_time(fn: Callable[[], object], min_time: float = 0.4, repeats: int = 7, warmup: int = 3) -> float:
    """Median seconds per call over ``repeats`` rounds, each round long enough (≥ min_time/repeats) that
    timer resolution does not matter."""
    for _ in range(warmup):
        fn()
    t0 = time.perf_counter()
    fn()
    one = max(time.perf_counter() - t0, 1e-7)
    number = max(1, int(min_time / repeats / one))
    rounds = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _ in range(number):
            fn()
        rounds.append((time.perf_counter() - t0) / number)
    return statistics.median(rounds)


def _fmt_time(s: float) -> str:
    return f"{s * 1e6:.0f} µs" if s < 1e-3 else (f"{s * 1e3:.2f} ms" if s < 1 else f"{s:.2f} s")


ROWS: list[dict] = []


def row(
    section: str,
    what: str,
    value: str,
    reference: str = "",
    ratio: str | Ratio = "",
    target: str = "",
    ok: bool | None = None,
    key: str | None = None,
):
    """One line of the table. A ``Ratio`` (the subject's time over its reference's) with a ``key`` is what the
    baseline keeps and ``--check`` compares (``tools/bench_baseline.py``)."""
    r = {
        "section": section,
        "what": what,
        "value": value,
        "reference": reference,
        "ratio": ratio.text() if isinstance(ratio, Ratio) else ratio,
        "target": target,
        "met": None if ok is None else bool(ok),
    }
    if isinstance(ratio, Ratio) and key is not None:
        r.update(key=f"{section}/{key}", ratio_value=ratio.value, spread=ratio.spread)
    ROWS.append(r)
    mark = "" if ok is None else ("  ok" if ok else "  MISSED")
    print(f"  {what:<58} {value:>16} {reference:>22} {r['ratio']:>8} {target:>14}{mark}", flush=True)


# ---------------------------------------------------------------------------------------------- configs
def compose(experiment: str, overrides: list[str] | None = None):
    from rmpfusion.pipeline.compose import compose_run

    return compose_run([f"experiment={experiment}", "logger=disabled", *(overrides or [])])


def learner_2d2level(seed: int = 0):
    from rmpfusion.pipeline.construct import build_learners, make_env

    cfg = compose("2d2level")
    env = make_env(cfg)
    torch.manual_seed(seed)
    return build_learners(cfg, env.aux_dims())["rmp"].double(), env


def franka_subject(n_obstacles: int = 1):
    """The Franka experiment's expert tree among ``n_obstacles`` standing cylinders (14 control points each, the
    experiment's cylinder's size, spread in a row in front of the robot, beyond the goals so every goal stays clear
    of them), and the environment of that scene."""
    from omegaconf import OmegaConf

    from rmpfusion.assembly.generated import expand_tree
    from rmpfusion.assembly.weighting import tree_with_weights
    from rmpfusion.pipeline.compose import compose_config
    from rmpfusion.registry import ENVS

    raw = OmegaConf.to_container(compose_config(["experiment=franka"]), resolve=True)  # the tree as declared
    cylinder = raw["env"]["scene"]["obstacles"][0]
    scene = {
        "obstacles": [
            {**cylinder, "center": [0.85, -0.6 + 1.2 * k / (n_obstacles + 1), cylinder["center"][2]]}
            for k in range(1, n_obstacles + 1)
        ]
    }
    spec = tree_with_weights(expand_tree({**raw["tree"], "scene": scene}), raw["expert"])
    tree = rmpfusion.build_tree(spec)
    settings = {**raw["env"], "scene": scene, "test_scene": None}
    entry = ENVS.get(settings.pop("type"))
    return tree, entry.obj(entry.validate(settings))


def franka_expert(n_obstacles: int = 1):
    """The subject of ``franka_subject`` and one sample of its aux state from its environment: a goal and the
    cylinders."""
    tree, env = franka_subject(n_obstacles)
    return tree, env.sample_envs(1, torch.Generator().manual_seed(0))


#: Every Franka state the benchmark times, as the arguments of ``franka_states`` (obstacles, batch, seed):
#: tests/test_bench.py checks each one is inside the joint limits and clear of the obstacles.
LATENCY_STATES = (1, 1, 0)  # the latency rows (eager, compiled) and the time to compile
EXPORT_STATES = (1, 2, 0)  # the AOTInductor row: traced on both, timed on the first
SCALING_STATES = tuple((n, B, B) for n in (1, 10, 100) for B in (1, 1024))
TIMED_FRANKA_STATES = (LATENCY_STATES, EXPORT_STATES, *SCALING_STATES)


def franka_states(n_obstacles: int, batch: int, seed: int):
    """(tree, q, q̇, aux): the subject of ``franka_subject`` and ``batch`` states a controller meets, drawn by the
    experiment's own sampler of start states (inside the joint limits by its ``joint_margin``, clear of every
    obstacle by its ``start_clearance`` in pybullet, at its start speeds); a state deep in a joint-limit barrier
    or inside an obstacle would time the barrier's saturated branch, not the policy."""
    tree, env = franka_subject(n_obstacles)
    g = torch.Generator().manual_seed(seed)
    try:
        q, qd, aux = env.sample_initial_states(env.sample_envs(1, g), batch, g)
    finally:
        env.close()
    return tree, q, qd, aux


# ---------------------------------------------------------------------------------------------- the hand-fused reference
class Fused2d2level(torch.nn.Module):
    """The 2d2level learner-rmp policy written out by hand: q → {goal (offset), obstacles (identity) →
    {obstacle1, obstacle2 (sphere distances)}, conditioning (identity)}, the four weight MLPs stacked
    (one batched product per layer for all edges, forward-mode tangent alongside), leaves inlined, then
    pullback* of paper eq. 6 and an LU solve. Parameters are copied from a built learner."""

    EDGES = ("goal", "obstacles", "obstacle1", "obstacle2")

    def __init__(self, learner):
        super().__init__()
        tree = learner.tree
        mlps = [tree.weights[e].fn for e in self.EDGES]
        if any(
            len(m.layers) != 3
            or m.activation != "tanh"
            or m.positivity != "softplus"
            or not m.use_config
            or m.layers[0].out_features != mlps[0].layers[0].out_features
            or m.floor != mlps[0].floor
            for m in mlps
        ):
            raise ValueError("the fused reference is written for equal 2-hidden-layer tanh/softplus MLPs on [q, aux]")
        # every edge reads [q, all the aux any edge reads]: an edge's first layer gets zero columns for the aux it
        # does not read, so one batched product per layer serves all four (same numbers, a few more FLOPs)
        names = sorted({a for m in mlps for a in m.aux_names})
        dims = {a: m.aux_dims[a] for m in mlps for a in m.aux_names}
        start = dict(zip(names, itertools.accumulate([dims[a] for a in names[:-1]], initial=2)))
        W0 = []
        for m in mlps:
            w = m.layers[0].weight.detach()
            full = w.new_zeros(w.shape[0], 2 + sum(dims.values()))
            full[:, :2] = w[:, :2]
            col = 2
            for a in m.aux_names:
                full[:, start[a] : start[a] + dims[a]] = w[:, col : col + dims[a]]
                col += dims[a]
            W0.append(full)
        self.aux_names, self.floor = names, mlps[0].floor
        for i in range(3):
            Ws = W0 if i == 0 else [m.layers[i].weight.detach() for m in mlps]
            self.register_parameter(f"W{i}", torch.nn.Parameter(torch.stack(Ws).clone()))
            self.register_parameter(
                f"b{i}", torch.nn.Parameter(torch.stack([m.layers[i].bias.detach() for m in mlps]).clone())
            )
        g, o = tree.rmps["goal"], tree.rmps["obstacle1"]
        if any(
            vars(tree.rmps["obstacle2"])[k] != vars(o)[k]
            for k in ("r_w", "sigma", "epsilon", "alpha", "eta", "min_distance")
        ):
            raise ValueError("the fused reference assumes both obstacle leaves share parameters")
        self.g = {k: getattr(g, k) for k in ("gain", "alpha", "eta", "w_u", "w_l", "sigma")}
        self.o = {k: getattr(o, k) for k in ("r_w", "sigma", "epsilon", "alpha", "eta", "min_distance")}
        self.scale = float(tree.rmps["conditioning"].w)

    def weights(self, q, aux):
        B = q.shape[0]
        h = torch.cat([q] + [aux[n].expand(B, -1) for n in self.aux_names], -1)
        z1 = torch.baddbmm(self.b0[:, None], h.expand(4, B, -1), self.W0.transpose(1, 2))
        a1 = torch.tanh(z1)
        U = (1 - a1 * a1)[:, :, None, :] * self.W0[:, :, :2].transpose(1, 2)[:, None]  # (4, B, 2, 32)
        z2 = torch.baddbmm(self.b1[:, None], a1, self.W1.transpose(1, 2))
        U = (U.reshape(4, 2 * B, -1) @ self.W1.transpose(1, 2)).reshape(4, B, 2, -1)
        a2 = torch.tanh(z2)
        U = (1 - a2 * a2)[:, :, None, :] * U
        z3 = torch.baddbmm(self.b2[:, None], a2, self.W2.transpose(1, 2))[..., 0]  # (4, B)
        dz3 = (U * self.W2[:, None, None, 0, :]).sum(-1)  # (4, B, 2)
        return self.floor + F.softplus(z3), torch.sigmoid(z3)[..., None] * dz3

    def forward(self, q, qd, aux):
        w, gw = self.weights(q, aux)
        qq = (qd * qd).sum(-1)
        # goal attractor on y = q − goal (J = I, J̇ẋ = 0)
        p = self.g
        y = q - aux["goal"]
        r = y.norm(dim=-1)
        beta = torch.exp(-r * r / (2 * p["sigma"] ** 2))
        wl = (p["w_u"] - p["w_l"]) * beta + p["w_l"]
        dwl = -((p["w_u"] - p["w_l"]) * beta / p["sigma"] ** 2)[:, None] * y
        ar = p["alpha"] * r
        Phi_g = p["gain"] * (ar + torch.log1p(torch.exp(-2 * ar)) - math.log(2.0)) / p["alpha"]
        dPhi = p["gain"] * (torch.tanh(ar) / r)[:, None] * y
        xi = qd * (qd * dwl).sum(-1, keepdim=True) - 0.5 * qq[:, None] * dwl
        f_g = -dPhi - p["eta"] * wl[:, None] * qd - xi
        L_g = 0.5 * wl * qq - Phi_g
        # the two barriers on sphere distances (J = uᵀ, J̇ẋ = (|q̇|² − ẏ²)/r)
        o = self.o
        f_o = torch.zeros_like(q)
        M_o = q.new_zeros(q.shape[0], 2, 2)
        L_o = q.new_zeros(q.shape[0])
        G_o = q.new_zeros(q.shape[0], 2, 2)
        for k in (1, 2):
            d = q - aux[f"obstacle{k}_center"]
            rk = d.norm(dim=-1)
            u = d / rk[:, None]
            x = rk - aux[f"obstacle{k}_radius"][:, 0]
            xd = (u * qd).sum(-1)
            c = (qq - xd * xd) / rk
            xc = x.clamp(min=o["min_distance"])
            dd = (o["r_w"] - xc).clamp(min=0.0)
            wb = dd * dd / xc
            gwb = (-2 * dd * xc - dd * dd) / (xc * xc)
            wb = torch.where(x < o["min_distance"], wb + gwb * (x - o["min_distance"]), wb)
            e = torch.exp(-xd * xd / (2 * o["sigma"] ** 2))
            neg = xd < 0
            ug = o["epsilon"] + torch.where(neg, 1 - e, torch.zeros_like(xd))
            dug = torch.where(neg, xd / o["sigma"] ** 2 * e, torch.zeros_like(xd))
            g = wb * ug
            m = g + 0.5 * xd * wb * dug
            fk = -o["alpha"] * wb * gwb - o["eta"] * g * xd - 0.5 * xd * xd * ug * gwb
            Lk = 0.5 * g * xd * xd - 0.5 * o["alpha"] * wb * wb
            wk, gwk = w[k + 1], gw[k + 1]
            uu = u[:, :, None] * u[:, None, :]
            f_o = (
                f_o + (wk * (fk - m * c))[:, None] * u + Lk[:, None] * gwk - ((qd * gwk).sum(-1) * g * xd)[:, None] * u
            )
            M_o = M_o + (wk * m)[:, None, None] * uu
            G_o = G_o + (wk * g)[:, None, None] * uu
            L_o = L_o + wk * Lk
        # root: goal, obstacles (both identity Jacobians, weighted), conditioning (scale·I)
        wg, gwg, wo, gwo = w[0], gw[0], w[1], gw[1]
        f = (
            wg[:, None] * f_g
            + L_g[:, None] * gwg
            - ((qd * gwg).sum(-1) * wl)[:, None] * qd
            + wo[:, None] * f_o
            + L_o[:, None] * gwo
            - (qd * gwo).sum(-1)[:, None] * (G_o @ qd[..., None])[..., 0]
        )
        eye = torch.eye(2, dtype=q.dtype)
        M = (wg * wl)[:, None, None] * eye + wo[:, None, None] * M_o + self.scale * eye
        return torch.linalg.solve(M, f)


# ---------------------------------------------------------------------------------------------- sections
def section_train(compile_: bool) -> None:
    print("\ntraining step, 2d2level learner-rmp, minibatch 200 (forward, backward incl. h_i, RMSprop step)")
    learner, env = learner_2d2level()
    q, qd, aux = env.sample(n_envs=4, n_per_env=50, seed=1)
    aux = learner.tree._normalise_aux(aux, q.shape[0])
    ref = Fused2d2level(learner)
    with torch.no_grad():
        err = (ref(q, qd, aux) - learner(q, qd, aux)).abs().max().item()
    if err > 1e-9:
        raise SystemExit(f"the fused reference disagrees with the tree by {err:.2e}: fix the reference before timing")
    target = torch.randn(200, 2, dtype=torch.float64, generator=torch.Generator().manual_seed(0))

    def stepper(model):
        opt = torch.optim.RMSprop(model.parameters(), lr=1e-4, foreach=True)  # as rmpfusion.learn.train does

        def step():
            opt.zero_grad(set_to_none=True)
            loss = ((model(q, qd, aux) - target) ** 2).mean()
            loss.backward()
            opt.step()

        return step

    t_ref = median_time(stepper(ref))
    t_tree = median_time(stepper(learner))
    row(
        "train",
        "tree (eager) step",
        _fmt_time(t_tree),
        f"fused {_fmt_time(t_ref)}",
        f"{t_tree / t_ref:.2f}",
        "≤ 1.5",
        t_tree / t_ref <= 1.5,
    )
    best = t_tree
    if compile_:
        learner.tree.compile(dynamic=False)
        t0 = time.perf_counter()
        stepper(learner)()
        ct = time.perf_counter() - t0
        t_c = median_time(stepper(learner))
        row(
            "train",
            f"tree (torch.compile, {ct:.0f} s to compile) step",
            _fmt_time(t_c),
            f"fused {_fmt_time(t_ref)}",
            f"{t_c / t_ref:.2f}",
            "≤ 1.5",
            t_c / t_ref <= 1.5,
        )
        best = min(best, t_c)
        learner.tree.uncompile()
    row(
        "train",
        "paper's 20,000 iterations (projected, best mode)",
        _fmt_time(20000 * best),
        "",
        "",
        "≤ 5 min",
        20000 * best <= 300,
    )


def section_batched(compile_: bool) -> None:
    print("\nbatched evaluation, 2d2level tree with neural weights (incl. ∇w), B = 4096")
    learner, env = learner_2d2level()
    q, qd, aux = env.sample(n_envs=16, n_per_env=256, seed=2)
    tree = learner.tree
    for threads in sorted({1, os.cpu_count() or 1}):
        torch.set_num_threads(threads)
        for dtype in (torch.float64, torch.float32):
            tree.to(dtype)
            args = (q.to(dtype), qd.to(dtype), {k: v.to(dtype) for k, v in aux.items()})
            with torch.no_grad():
                t = median_time(lambda args=args: tree(*args))
                row(
                    "batched",
                    f"eager, {str(dtype)[6:]}, {threads} thread(s)",
                    f"{4096 / t:,.0f} /s",
                    "",
                    "",
                    "≥ 1,000,000",
                    4096 / t >= 1e6,
                )
                if compile_:
                    tree.compile(dynamic=False)
                    with warnings.catch_warnings(record=True) as said:
                        warnings.simplefilter("always")
                        tree(*args)
                    failed = any(isinstance(w.message, rmpfusion.core.tree.CompileFallbackWarning) for w in said)
                    t = median_time(lambda args=args: tree(*args))
                    row(
                        "batched",
                        f"torch.compile{' (failed: ran eagerly)' if failed else ''}, {str(dtype)[6:]}, "
                        f"{threads} thread(s)",
                        f"{4096 / t:,.0f} /s",
                        "",
                        "",
                        "≥ 1,000,000",
                        4096 / t >= 1e6,
                    )
                    tree.uncompile()
    tree.to(torch.float64)
    torch.set_num_threads(1)


def _rmpflow_numpy():
    """RMPflow's reference code on the test vector as a call to time: its root policy (f, M and the resolve) at
    q = (2.5, 0), q̇ = (−1, 0), the state the tree's rows are timed at."""
    import numpy as np

    from tests import rmpflow_reference as ref

    children = [
        (ref.sphere_map(np.array([0.0, 0.0]), 1.0), ref.collision_avoidance),
        (ref.offset_map(np.array([-3.0, 3.0])), ref.goal_attractor),
    ]
    q, qd = np.array([2.5, 0.0]), np.array([-1.0, 0.0])
    return lambda: ref.rmpflow_root(q, qd, children)


def _compiled_time(tree, args, policy: bool = False) -> tuple[float, float]:
    """(seconds to compile, seconds a call) of the tree compiled for its batch size with a fixed structure (a
    controller's tree), without SIMD loops for a single state."""
    call = (lambda: tree.policy(*args)) if policy else (lambda: tree(*args))
    tree.compile(fixed_structure=True, vectorize=args[0].shape[0] > 1)  # dynamic=None: see _controller
    t0 = time.perf_counter()
    call()
    compile_s = time.perf_counter() - t0
    t = median_time(call)
    tree.uncompile()
    return compile_s, t


def _controller(tree, q: torch.Tensor, qd: torch.Tensor) -> float:
    """``tree`` compiled as a controller's (fixed structure, one state, no SIMD loops) and called once: the seconds
    that first call took (the compile). ``dynamic`` is left None: the first compile is static for the batch it meets
    either way, and dynamic=False patches dynamo's config around every call (0.44x against 0.37x RMPflow's numpy,
    side by side)."""
    tree.compile(fixed_structure=True, vectorize=False)
    t0 = time.perf_counter()
    with torch.inference_mode():
        tree.policy(q, qd)
    return time.perf_counter() - t0


def hand_fused_test_vector(q: torch.Tensor, qd: torch.Tensor) -> torch.Tensor:
    """The test-vector tree's policy written out by hand in torch, eagerly: RMPflow's collision barrier on the
    normalised distance to the unit circle at the origin and its goal attractor at (−3, 3) with their default
    numbers, pulled back and LU-solved, every constant folded and no check made. What torch's per-operation cost
    allows the same math at one state (the tree adds its groups, its maps' Jacobians and the solve's pivot test);
    checked against the tree before it is timed."""
    r = torch.linalg.vector_norm(q, dim=-1, keepdim=True)  # the circle's centre is the origin, its radius 1
    u = q / r
    x, xd = r - 1.0, (u * qd).sum(-1, keepdim=True)
    c = ((qd * qd).sum(-1, keepdim=True) - xd * xd) / r
    inside = x < 0
    xs = torch.where(inside, 1.0, x)
    w = torch.where(inside, 1e10, torch.pow(xs, -4))
    grad_w = torch.where(inside, 0.0, -4.0 * torch.pow(xs, -5))
    braking = xd.clamp(max=0.0) * xd
    g = w * (0.2 + braking)
    m = (g + w * braking).clamp(-1e5, 1e5)
    fx = (-(1e-5 * w + 0.5 * xd * xd * (0.2 + braking)) * grad_w).clamp(-1e10, 1e10)
    f = (fx - m * c) * u
    M = m[..., None] * (u[..., :, None] * u[..., None, :])
    y = q - torch.tensor([-3.0, 3.0], dtype=q.dtype)
    ry = torch.linalg.vector_norm(y, dim=-1, keepdim=True)
    beta = torch.exp(ry * ry * -0.5)
    wg = 9.0 * beta + 1.0
    grad_phi = torch.where(ry > 0.005, wg * torch.tanh(ry) / ry, 0.0) * y
    grad_wg = (-9.0 * beta) * y
    xi = qd * (qd * grad_wg).sum(-1, keepdim=True) - 0.5 * (qd * qd).sum(-1, keepdim=True) * grad_wg
    f = f - grad_phi - 2.0 * wg * qd - xi
    M = M + wg[..., None] * torch.eye(2, dtype=q.dtype)
    LU, pivots, _ = torch.linalg.lu_factor_ex(M)
    return torch.linalg.lu_solve(LU, pivots, f.unsqueeze(-1)).squeeze(-1)


#: whether the AOTInductor rows run (--no-export leaves them out: packaging takes about a minute each)
AHEAD_OF_TIME = {"on": True}
#: the test-vector rows: (key, what, target ratio to RMPflow's numpy or None)
REFERENCE_ROWS = {
    "eager policy": ("eager_policy", "test-vector tree, policy (q̈), eager", 2.0),
    "eager everything": ("eager_all", "test-vector tree, q̈ and V, G, B, Φ, L, eager", None),
    "hand-fused": ("hand_fused", "its policy hand-fused in torch, eager (the floor)", None),
    "compiled policy": ("compiled_policy", "test-vector tree, policy, compiled", 0.5),
}


def section_reference(compile_: bool) -> None:
    """The test-vector tree at one state beside RMPflow's numpy, every variant timed in the same rounds."""
    print("\ntest-vector tree at one state (B = 1, the control loop) beside RMPflow's numpy, timed side by side")
    from tests.trees import TEST_VECTOR_SPEC

    q = torch.tensor([[2.5, 0.0]], dtype=torch.float64)
    qd = torch.tensor([[-1.0, 0.0]], dtype=torch.float64)
    eager, fast = rmpfusion.build_tree(TEST_VECTOR_SPEC), rmpfusion.build_tree(TEST_VECTOR_SPEC)
    with torch.no_grad():
        err = (hand_fused_test_vector(q, qd) - eager.policy(q, qd)).abs().max().item()
    if err > 1e-12:
        raise SystemExit(f"the hand-fused test vector disagrees with the tree by {err:.2e}: fix it before timing")
    fns = {
        "numpy": _rmpflow_numpy(),
        "eager policy": lambda: eager.policy(q, qd),
        "eager everything": lambda: eager(q, qd),
        "hand-fused": lambda: hand_fused_test_vector(q, qd),
    }
    compile_s = None
    if compile_:
        compile_s = _controller(fast, q, qd)
        fns["compiled policy"] = lambda: fast.policy(q, qd)
    with torch.inference_mode():
        times = side_by_side(fns)
    reference = f"RMPflow numpy {_fmt_time(statistics.median(times['numpy']))}"
    for name, (key, what, target) in REFERENCE_ROWS.items():
        if name not in times:
            continue
        r = Ratio.of(times[name], times["numpy"])
        label = f"{what} ({compile_s:.0f} s)" if name == "compiled policy" else what
        met = {} if target is None else {"target": f"≤ {target:g}", "ok": r.value <= target}
        row("reference", label, _fmt_time(statistics.median(times[name])), reference, r, key=key, **met)
    if compile_ and AHEAD_OF_TIME["on"]:
        g = torch.Generator().manual_seed(0)
        q2 = torch.tensor([[2.5, 0.0], [1.0, -1.5]], dtype=torch.float64)
        qd2 = torch.randn(2, 2, generator=g, dtype=torch.float64)
        _exported_latency("test-vector tree", eager, q2, qd2, {}, reference=_rmpflow_numpy(), key="aoti_policy")


def section_latency(compile_: bool) -> None:
    print("\nsingle-state latency (B = 1, the control loop): the 2d2level learner and the Franka expert (46 nodes)")
    learner, env = learner_2d2level()
    args = env.sample(n_envs=1, n_per_env=1, seed=3)
    fr, fq, fqd, faux = franka_states(*LATENCY_STATES)
    fargs = (fq, fqd, faux)
    with torch.inference_mode():
        for name, tree, a, eager_target, compiled_target in (
            ("2d2level learner tree", learner.tree, args, None, None),
            ("Franka expert tree (46 nodes)", fr, fargs, 2e-3, 0.3e-3),
        ):
            t = median_time(lambda tree=tree, a=a: tree(*a))
            target = {"target": f"≤ {_fmt_time(eager_target)}", "ok": t <= eager_target} if eager_target else {}
            row("latency", f"{name}, eager", _fmt_time(t), **target)
            if compile_:
                ct, t = _compiled_time(tree, a)
                target = (
                    {"target": f"≤ {_fmt_time(compiled_target)}", "ok": t <= compiled_target} if compiled_target else {}
                )
                row("latency", f"{name}, compiled ({ct:.0f} s)", _fmt_time(t), **target)
    if compile_ and AHEAD_OF_TIME["on"]:
        fr, fq, fqd, faux = franka_states(*EXPORT_STATES)
        _exported_latency("Franka expert tree", fr, fq, fqd, faux)


def _exported_latency(
    name: str, tree, q2, qd2, aux2: dict, reference: Callable[[], object] | None = None, key: str | None = None
) -> None:
    """The tree exported and compiled ahead of time (what rmpfusion-export --aoti writes), traced on the two
    states (q2, qd2, aux2) and timed at B = 1 on the first, side by side with ``reference`` (a call) when given."""
    import tempfile

    from rmpfusion.core.export import export_tree

    names = sorted(aux2)
    aux2 = {k: v.expand(2, -1) for k, v in aux2.items()}
    aux = {k: v[:1] for k, v in aux2.items()}
    program = export_tree(tree, q2, qd2, aux2, names)
    with tempfile.TemporaryDirectory() as d:
        t0 = time.perf_counter()
        path = torch._inductor.aoti_compile_and_package(program, package_path=os.path.join(d, "tree.pt2"))
        ct = time.perf_counter() - t0
        runner = torch._inductor.aoti_load_package(path)
    x = (q2[:1], qd2[:1], *(aux[n] for n in names))
    with torch.inference_mode():
        err = (runner(*x) - tree(q2[:1], qd2[:1], aux).qdd).abs().max().item()
        fns = {"package": lambda: runner(*x), **({"reference": reference} if reference is not None else {})}
        times = side_by_side(fns)
    compared = {}
    if reference is not None:
        compared = {
            "reference": f"RMPflow numpy {_fmt_time(statistics.median(times['reference']))}",
            "ratio": Ratio.of(times["package"], times["reference"]),
            "key": key,
        }
    section = "reference" if reference is not None else "latency"
    what = f"{name}, AOTInductor package ({ct:.0f} s, |Δq̈| {err:.0e})"
    row(section, what, _fmt_time(statistics.median(times["package"])), **compared)


COMPILE_CHILD = """
import sys, time, torch
torch.set_num_threads(1)
from tools import bench
tree, q, qd, aux = bench.franka_states(*bench.LATENCY_STATES)
tree.compile(fixed_structure=True, vectorize=False)
t0 = time.perf_counter()
with torch.inference_mode():
    tree(q, qd, aux)
print(time.perf_counter() - t0)
"""


def section_compile(compile_: bool) -> None:
    if not compile_:
        return
    print("\ntime to compile, Franka expert tree, B = 1 (a fresh process, an empty inductor cache)")
    import tempfile

    with tempfile.TemporaryDirectory() as cache:
        env = {**os.environ, "TORCHINDUCTOR_CACHE_DIR": cache}
        out = subprocess.run(  # from the repository root, where ``tools`` is a package
            [sys.executable, "-c", COMPILE_CHILD], capture_output=True, text=True, check=True, env=env, cwd=ROOT
        )
    s = float(out.stdout.split()[-1])
    row("compile", "Franka expert tree, first call after compile()", f"{s:.1f} s", "", "", "≤ 30 s", s <= 30)


def _eager_and_compiled(section: str, label: str, tree, args: tuple, compile_: bool) -> dict[str, float]:
    """One tree at one batch: its eager row, and its compiled row unless ``compile_`` is off; {mode: seconds}."""
    out = {}
    with torch.inference_mode():
        out["eager"] = median_time(lambda: tree(*args), min_time=1.0)
        row(section, f"{label}, eager", _fmt_time(out["eager"]), "", "", "")
        if compile_:
            ct, out["compiled"] = _compiled_time(tree, args)
            row(section, f"{label}, compiled ({ct:.0f} s)", _fmt_time(out["compiled"]))
    return out


def section_scaling(compile_: bool) -> None:
    print("\nFranka tree with 1, 10 and 100 obstacles (14 control points each): how the cost grows")
    compiled_b1 = {}
    for n, B, seed in SCALING_STATES:
        tree, q, qd, a = franka_states(n, B, seed)
        t = _eager_and_compiled("scaling", f"{n} obstacle(s), B = {B}", tree, (q, qd, a), compile_)
        if compile_ and B == 1:
            compiled_b1[n] = t["compiled"]
    if compile_:
        r = compiled_b1[100] / compiled_b1[1]
        row("scaling", "100 obstacles / 1, B = 1, compiled", f"{r:.2f}", "", "", "≤ 3", r <= 3)


#: (N_max, batch, seed) of the obstacle-set rows: one sphere set of N_max members, every member present
SET_STATES = tuple((n, B, B) for n in (1, 100) for B in (1, 1024))


def franka_set_states(n_max: int, batch: int, seed: int, nearest: int | None = None):
    """(tree, q, q̇, aux, exact): the Franka expert on the Panda's tree with one sphere set of ``n_max`` members (the
    run-time world's tree: tools/world_demo.py), every member present, 3 cm spheres in a slab beyond the goals (x
    0.9–1.1 m, clear of the arm's starts), and ``batch`` start states of experiment=franka's sampler. The tree makes
    its slot entries itself (``SetsSource``): ``aux`` is the goal and the set's tensors and mask, as a World holds
    them. With ``nearest`` every control point reads its ``nearest`` members, selected inside the tree; ``exact``
    is the fraction of the states where the selection equals the whole set (1.0 without ``nearest``)."""
    from rmpfusion.scenes import ObstacleSet, SetsSource
    from rmpfusion.scenes.nearest import nearest_members, selection_exact
    from tools.world_demo import controller

    sets = [ObstacleSet(shape="sphere", n_max=n_max, nearest=nearest)]
    tree, robot, run = controller(sets)
    n_points = len(run.env.robot.control_points)
    tree.read_aux_through(SetsSource(sets, n_points, robot.sphere_centres))
    _, q, qd, _ = franka_states(1, batch, seed)
    aux = {k: v.expand(batch, *v.shape[1:]) for k, v in _slab_world(sets, seed).set_aux().items()}
    exact = 1.0
    if nearest is not None:
        _, left_out = nearest_members(sets[0], aux, robot.sphere_centres(q))
        radii = torch.tensor([cp.radius for cp in run.env.robot.control_points], dtype=torch.float64)
        exact = selection_exact(left_out, radii, _barrier_support(run)).double().mean().item()
    return tree, q, qd, aux, exact


def _barrier_support(run) -> float:
    """r_w of the run's obstacle barrier: beyond it an obstacle edge contributes nothing."""
    barrier = next(n.rmp for n in run.tree.nodes.values() if n.rmp is not None and n.rmp.type == "collision_avoidance")
    return float(barrier.model_dump()["r_w"])


def _slab_world(sets, seed: int):
    """A world whose one sphere set is full: 3 cm spheres in a slab beyond the goals (x 0.9–1.1 m)."""
    from rmpfusion.scenes import World

    world = World(sets, goal=[0.45, 0.35, 0.35])
    g = torch.Generator().manual_seed(seed)
    lo, hi = torch.tensor([0.9, -0.6, 0.1]), torch.tensor([1.1, 0.6, 0.8])
    for _ in range(sets[0].n_max):
        world.add("sphere", center=(lo + (hi - lo) * torch.rand(3, generator=g)).tolist(), radius=0.03)
    return world


#: each control point's nearest members of the N_max = 100 set in the selection rows (scenes/nearest.py)
SET_NEAREST = 8


def section_sets(compile_: bool) -> None:
    print("\nFranka tree with a run-time obstacle set of N_max = 1 and 100 spheres (every member present): one tree")
    print("and one compile serve any count from 0 to N_max; the tree is given the set's tensors and makes one entry")
    print("per member itself (SetsSource); how the cost grows with N_max")
    times: dict[tuple[int, int], dict[str, float]] = {}
    for n, B, seed in SET_STATES:
        tree, q, qd, a, _ = franka_set_states(n, B, seed)
        times[n, B] = _eager_and_compiled("sets", f"N_max = {n}, B = {B}", tree, (q, qd, a), compile_)
    mode = "compiled" if compile_ else "eager"
    r1 = times[100, 1][mode] / times[1, 1][mode]
    row("sets", f"N_max 100 / 1, B = 1, {mode}", f"{r1:.2f}", "", "", "≤ 3", r1 <= 3)
    rb = times[100, 1024][mode] / times[1, 1024][mode]
    row("sets", f"N_max 100 / 1, B = 1024, {mode}", f"{rb:.2f}")
    print(
        f"the same 100 members, each control point reading its {SET_NEAREST} nearest (nearest: {SET_NEAREST}), selected"
    )
    print("inside the tree from the control spheres' centres; exact where every member left out lies beyond the")
    print("barrier's support (the fraction of the states where it is, in the row)")
    for B in (1, 1024):
        tree, q, qd, a, exact = franka_set_states(100, B, B, nearest=SET_NEAREST)
        t = _eager_and_compiled(
            "sets", f"N_max = 100, {SET_NEAREST} nearest, B = {B} (exact on {exact:.0%})", tree, (q, qd, a), compile_
        )
        r = t[mode] / times[1, B][mode]
        label = f"N_max 100 ({SET_NEAREST} nearest) / 1, B = {B}, {mode}"
        if B == 1:  # a single state pays the selection's fixed cost: the whole set's row carries the B = 1 target
            row("sets", label, f"{r:.2f}")
        else:
            row("sets", label, f"{r:.2f}", "", "", "≤ 5", r <= 5)


#: the cloud row: points sampled on the faces of a box beyond the goals, members per control point
CLOUD_POINTS, CLOUD_K = 1000, 8


def franka_cloud_step(seed: int = 0):
    """(tree, q, q̇, aux): the Franka expert on the Panda's tree whose control points each read their ``CLOUD_K``
    nearest points of a ``CLOUD_POINTS``-point cloud (3 cm spheres): the cloud is a sphere set with ``nearest``, so
    a step is one call of the tree given the cloud (the selection and the slots are made inside it)."""
    from rmpfusion.scenes import ObstacleSet, SetsSource
    from tools.world_demo import controller

    cloud_set = ObstacleSet(shape="sphere", n_max=CLOUD_POINTS, nearest=CLOUD_K, name="points")
    tree, robot, run = controller([cloud_set])
    tree.read_aux_through(SetsSource([cloud_set], len(run.env.robot.control_points), robot.sphere_centres))
    g = torch.Generator().manual_seed(seed)
    u = torch.rand(CLOUD_POINTS, 3, generator=g, dtype=torch.float64) * 2 - 1
    u[torch.arange(CLOUD_POINTS), torch.randint(0, 3, (CLOUD_POINTS,), generator=g)] = 1.0
    cloud = u * torch.tensor([0.1, 0.3, 0.3], dtype=torch.float64) + torch.tensor([0.95, 0.0, 0.4], dtype=torch.float64)
    aux = {
        "goal": torch.tensor([[0.45, 0.35, 0.35]], dtype=torch.float64),
        "points_center": cloud[None],
        "points_radius": torch.full((1, CLOUD_POINTS, 1), 0.03, dtype=torch.float64),
        "points_mask": torch.ones(1, CLOUD_POINTS, dtype=torch.float64),
    }
    _, q, qd, _ = franka_states(1, 1, seed)
    return tree, q, qd, aux


def section_clouds(compile_: bool) -> None:
    print(
        f"\nFranka tree whose control points each read their {CLOUD_K} nearest points of a {CLOUD_POINTS}-point cloud"
    )
    print("(a step = one call of the tree given the cloud: selection, slots and tree), against the tree of one fixed")
    print("obstacle")
    one, q1, qd1, a1 = franka_states(1, 1, 1)
    tree, q, qd, aux = franka_cloud_step()
    base = _eager_and_compiled("clouds", "1 obstacle, B = 1", one, (q1, qd1, a1), compile_)
    step = _eager_and_compiled("clouds", f"cloud step (k = {CLOUD_K}), B = 1", tree, (q, qd, aux), compile_)
    for mode in base:
        r = step[mode] / base[mode]
        row("clouds", f"cloud step (k = {CLOUD_K}) / 1 obstacle, B = 1, {mode}", f"{r:.2f}", "", "", "≤ 5", r <= 5)


def section_cuda(compile_: bool) -> None:
    if not torch.cuda.is_available():
        print("\ncuda: no CUDA device on this machine (section skipped)")
        return
    print(f"\ncuda: {torch.cuda.get_device_name(0)}")
    learner, env = learner_2d2level()
    q, qd, aux = env.sample(n_envs=64, n_per_env=1024, seed=2)
    tree = learner.tree.to("cuda", torch.float32)
    args = (q.cuda().float(), qd.cuda().float(), {k: v.cuda().float() for k, v in aux.items()})

    def run():
        tree(*args)
        torch.cuda.synchronize()

    with torch.inference_mode():
        t = median_time(run)
        row("cuda", "2d2level tree, B = 65,536, float32, eager", f"{65536 / t:,.0f} /s")
    learner.double().to("cuda")
    q, qd, aux = env.sample(n_envs=4, n_per_env=50, seed=1)
    args = (q.cuda(), qd.cuda(), {k: v.cuda() for k, v in aux.items()})
    target = torch.randn(200, 2, dtype=torch.float64, device="cuda")
    opt = torch.optim.RMSprop(learner.parameters(), lr=1e-4, foreach=True)

    def step():
        opt.zero_grad(set_to_none=True)
        ((learner(*args) - target) ** 2).mean().backward()
        opt.step()
        torch.cuda.synchronize()

    row("cuda", "2d2level training step, minibatch 200, eager", _fmt_time(median_time(step)))


_PEAK_PRELUDE = """
import sys, torch
sys.argv = ['bench']
torch.set_num_threads(1)
from tools import bench


def status(key):  # KiB, from the kernel's accounting of this process
    return next(int(line.split()[1]) for line in open('/proc/self/status') if line.startswith(key))


"""


def peak_in_child(setup: str, work: str) -> tuple[int, int]:
    """(resident KiB after ``setup``, peak resident KiB while ``work`` ran after it), both Python source run in a
    child process (a fresh interpreter: no other section's memory in its peak)."""
    code = (
        _PEAK_PRELUDE
        + setup
        + "\nbefore = status('VmRSS:')\n"
        + "open('/proc/self/clear_refs', 'w').write('5')  # the peak (VmHWM) starts again from what is resident now\n"
        + work
        + "\nprint(before, status('VmHWM:'))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT).stdout
    return int(out.split()[-2]), int(out.split()[-1])


def _memory_row(label: str, before: int, peak: int) -> None:
    row(
        "memory",
        label,
        f"{peak / 1024:.0f} MiB",
        f"resident before {before / 1024:.0f} MiB",
        f"+{(peak - before) / 1024:.0f} MiB",
    )


def section_memory(iterations: int = 300) -> None:
    print(f"\npeak memory, 2d2level training ({iterations} iterations of minibatch 200, in a child process)")
    setup = """
learner, env = bench.learner_2d2level()
q, qd, aux = env.sample(n_envs=20, n_per_env=500, seed=5)  # the paper's 60,000-point training set
"""
    work = f"""
target = torch.randn(q.shape[0], 2, dtype=torch.float64)
opt = torch.optim.RMSprop(learner.parameters(), lr=1e-4)
g = torch.Generator().manual_seed(0)
for it in range({iterations}):
    idx = torch.randint(0, q.shape[0], (200,), generator=g)
    opt.zero_grad()
    loss = ((learner(q[idx], qd[idx], {{k: v[idx] for k, v in aux.items()}}) - target[idx]) ** 2).mean()
    loss.backward()
    opt.step()
"""
    _memory_row("peak RSS while training", *peak_in_child(setup, work))
    print("peak memory of one eager call of the Franka tree with a run-time sphere set, B = 1024 (in a child process)")
    work = "with torch.inference_mode():\n    tree(q, qd, a)"
    for n in sorted({n for n, _, _ in SET_STATES}):
        setup = f"tree, q, qd, a, _ = bench.franka_set_states({n}, 1024, 1024)"
        _memory_row(f"N_max = {n}, B = 1024: peak RSS of a call", *peak_in_child(setup, work))
    setup = f"tree, q, qd, a, _ = bench.franka_set_states(100, 1024, 1024, nearest={SET_NEAREST})"
    _memory_row(f"N_max = 100, {SET_NEAREST} nearest, B = 1024: peak RSS of a call", *peak_in_child(setup, work))


#: the 7-joint arm whose meshes the fit reads: the xArm7 as example-robot-data ships it (STL, package://), else the
#: KUKA iiwa of pybullet_data (OBJ/STL beside the URDF) when example-robot-data is not installed
FIT_ARMS = [
    (
        "xArm7",
        "pkg://cmeel.prefix/share/example-robot-data/robots/xarm_description/urdf/xarm7.urdf",
        [f"joint{k}" for k in range(1, 8)],
        "link_eef",
    ),
    (
        "iiwa",
        "pkg://pybullet_data/kuka_iiwa/model.urdf",
        [f"lbr_iiwa_joint_{k}" for k in range(1, 8)],
        "lbr_iiwa_link_7",
    ),
]


def section_robots(compile_: bool) -> None:
    """rmpfusion-fit-spheres on a 7-joint arm with meshes, as a user runs it: a fresh process (imports, reading and
    sampling every moved link's meshes, k-means, the coverage check, proposing a home, writing the file), once."""
    import tempfile

    from rmpfusion.maps.urdf import resolve_urdf_path

    print("\nrmpfusion-fit-spheres on a 7-joint arm with meshes (a fresh process, wall time of one run)")
    name, urdf, joints, ee = next(a for a in FIT_ARMS if os.path.isfile(_quiet_resolve(resolve_urdf_path, a[1])))
    with tempfile.TemporaryDirectory() as tmp:
        cmd = [
            sys.executable,
            "-m",
            "rmpfusion.cli.fit_spheres",
            urdf,
            "--name",
            "bench",
            "--joints",
            *joints,
            "--ee-link",
            ee,
            "--out",
            str(Path(tmp) / "bench.yaml"),
        ]
        t0 = time.perf_counter()
        done = subprocess.run(
            cmd,
            capture_output=True,
            text=True,
            cwd=ROOT,
            env={**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])},
        )
        wall = time.perf_counter() - t0
    if done.returncode != 0:
        raise RuntimeError(f"rmpfusion-fit-spheres failed: {done.stderr.strip()}")
    spheres = next((ln for ln in done.stdout.splitlines() if ln.startswith("all:")), "").split(",")[0]
    row(
        "robots",
        f"fit-spheres, {name} (7 joints, every moved link's meshes)",
        f"{wall:.1f} s",
        spheres.removeprefix("all: "),
        "",
        "≤ 60 s",
        wall <= 60.0,
    )


def _quiet_resolve(resolve: Callable[[str], str], location: str) -> str:
    try:
        return resolve(location)
    except FileNotFoundError:
        return ""


#: The batched and training sections run first: in a process where the single-state compiles (C++ wrapper) and the
#: AOTInductor packaging had run, two of the batched compiles failed in g++ and ran eagerly (the cause was not found).
#: the LASA shape of the one-shape row, and the stored 26-shape variants whose total run time is reported
LASA_SHAPE, LASA_VARIANTS = (
    "Angle",
    ("flow", "both", "weights", "map", "first_order", "both_all7", "both_radial", "seds", "seds_all7"),
)


def section_lasa(compile_: bool) -> None:
    """One LASA shape learned end to end as a user runs it (a fresh process: data, the default training, the
    evaluation's rollouts and figures) with the accuracy it reached, and what a 26-shape variant took when its runs
    were stored."""
    import tempfile

    import yaml

    print(
        f"\nLASA: one shape ({LASA_SHAPE}) learned end to end in a child process (rmpfusion-run experiment=lasa), and"
    )
    print("the stored 26-shape tables' total run time (results/lasa/runs.yaml: made on 2 cores shared with other runs)")
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        cmd = [sys.executable, "-m", "rmpfusion.cli.run", "experiment=lasa", f"data.shape={LASA_SHAPE}"]
        subprocess.run([*cmd, "logger=disabled", f"hydra.run.dir={tmp}/run"], check=True, capture_output=True)
        wall = time.perf_counter() - t0
        metrics = json.loads((Path(tmp) / "run" / "metrics.json").read_text())
    learner = next(iter(metrics["learners"].values()))
    iterations = max(int(k) for k in learner["snapshots"])
    dtw, converged = learner["reproduction_test"]["dtw"], learner["convergence"]["converged"]
    row("lasa", f"{LASA_SHAPE}: training ({iterations} iterations)", f"{learner['train_seconds']:.0f} s")
    row("lasa", f"{LASA_SHAPE}: test DTW; grid starts converged", f"{1e3 * dtw:.2f} mm; {converged:.0%}")
    row(
        "lasa",
        f"{LASA_SHAPE}: the whole run (data, training, evaluation)",
        f"{wall:.0f} s",
        "",
        "",
        "≤ 2 min",
        wall <= 120,
    )
    runs = yaml.safe_load((ROOT / "results" / "lasa" / "runs.yaml").read_text())
    for variant in LASA_VARIANTS:
        times = [r["wall_time_s"] for name, r in runs.items() if name.startswith(f"{variant}/")]
        if len(times) == 26:
            total = sum(times)
            row(
                "lasa",
                f"26 shapes, {variant}: stored runs' total",
                f"{total / 60:.0f} min",
                "",
                "",
                "≤ 2 h",
                total <= 7200,
            )


#: the collision section's rollout length (steps of 1/250 s) and starts: the recorded-arm evaluation's
#: (--collision-steps sets the steps)
COLLISIONS = {"steps": 5871, "starts": 100}


def section_collisions(compile_: bool) -> None:
    """The batched collision check against the per-configuration replay, on the Franka expert's kinematic rollouts
    (every step recorded), each timed once (the replay takes minutes at full size)."""
    from rmpfusion.envs.manipulator.collisions import CLEARANCE_TOLERANCE, check_collisions, replay_collisions

    n, steps = COLLISIONS["starts"], COLLISIONS["steps"]
    print(f"\ncollision check of a kinematic evaluation: the Franka expert, {n} starts x {steps} steps (4 ms)")
    tree, env = franka_subject(1)
    env = env.with_step(1.0 / 250.0)
    q0, qd0, aux = env.sample(10, n // 10, generator=torch.Generator().manual_seed(0))
    t0 = time.perf_counter()
    with torch.no_grad():
        ro = env.rollout(tree, q0, qd0, aux, horizon=steps * env.dt, record_every=env.dt, mode="kinematic")
    rollout = time.perf_counter() - t0
    Q, B = ro.q, ro.q.shape[1]
    world, asked = env.checker(), [0]
    clearance = world.clearance

    def counted(query: float) -> float:
        asked[0] += 1
        return clearance(query)

    world.clearance = counted  # type: ignore[method-assign]
    timed = {}
    t0 = time.perf_counter()
    timed["batched"] = check_collisions(env, Q, aux, steps, [steps] * B, [None] * B)
    timed["batched s"], queries = time.perf_counter() - t0, asked[0]
    t0 = time.perf_counter()
    timed["replay"] = replay_collisions(env, Q, aux, steps, [steps] * B, [None] * B)
    timed["replay s"] = time.perf_counter() - t0
    (got, got_t), (ref, ref_t) = timed["batched"], timed["replay"]
    if not (torch.equal(got_t, ref_t) and ((got <= 0) == (ref <= 0)).all()) or not (
        (got >= ref).all() and (got <= ref + CLEARANCE_TOLERANCE).all()
    ):
        raise RuntimeError("the batched collision check disagrees with the per-configuration replay")
    env.close()
    configurations = f"{B} x {steps + 1}"
    row("collisions", f"rollouts to check ({configurations} configurations)", f"{rollout:.1f} s")
    batched, replay = timed["batched s"], timed["replay s"]
    row(
        "collisions",
        f"batched check, {configurations} ({queries} asked of pybullet; {int((ref <= 0).sum())} collide)",
        f"{batched:.1f} s",
        f"replay {replay:.1f} s",
        f"{replay / batched:.1f}x",
        "≤ 10 s" if (B, steps) == (100, 5871) else "",
        batched <= 10.0 if (B, steps) == (100, 5871) else None,
    )


#: the rollout row: starts at rest, and integration steps in each timed call
ROLLOUT = {"starts": 100, "steps": 10}


def arm_evaluation_subject(starts: int, seed: int = 0):
    """(tree, env, q0, q̇0, aux): the tree experiment=recorded_arm evaluates first (the Panda's arm_reach tree with
    every weight 1, its learned map at its initial weights), its kinematic environment (250 Hz), and ``starts``
    states at rest in the middle half of the joint ranges that the environment accepts as starts (inside the limits,
    clear of the cylinder and the table), each reaching for another's configuration (a recording's goal and
    posture)."""
    from rmpfusion.pipeline.construct import build_expert, make_env
    from rmpfusion.pipeline.validate import typed

    run = typed(compose("recorded_arm"))
    env = make_env(run)
    tree = build_expert(run, env.aux_dims())
    lo, hi = tree.maps["ee"].chain.joint_limits()
    g = torch.Generator().manual_seed(seed)
    q = lo + (hi - lo) * (0.25 + 0.5 * torch.rand(4 * starts, len(lo), generator=g, dtype=torch.float64))
    q = q[env.recorded_starts(q)][:starts]
    if q.shape[0] < starts:
        raise RuntimeError(f"only {q.shape[0]} of {4 * starts} drawn configurations are starts the arm accepts")
    return tree, env, q, torch.zeros_like(q), env.recorded_aux(q.roll(1, 0))


def section_rollout(compile_: bool) -> None:
    """An evaluation rollout step as recorded runs take it: the kinematic simulator's integration step (the tree's
    evaluation with V and B for the monitor, semi-implicit Euler, the goal tracker, the records) for every start at
    once, eager and through the compiled tree, timed side by side; the collision check after the records is the
    collisions section's."""
    import copy

    from rmpfusion.envs.faults import IsolatingPolicy
    from rmpfusion.envs.manipulator.kinematic import integrate

    n, steps = ROLLOUT["starts"], ROLLOUT["steps"]
    print(f"\nevaluation rollout step, experiment=recorded_arm's tree (every weight 1), {n} starts at 250 Hz")
    tree, env, q0, qd0, aux = arm_evaluation_subject(n)

    def rollout(t):
        with torch.no_grad():
            integrate(env, IsolatingPolicy(t), q0, qd0, aux, steps, 1, None, [None] * n)

    fns = {"eager": lambda: rollout(tree)}
    if compile_:
        fast = copy.deepcopy(tree).compile(fixed_structure=True, vectorize=False)  # as recorded runs compile it
        t0 = time.perf_counter()
        rollout(fast)
        compile_s = time.perf_counter() - t0
        fns["compiled"] = lambda: rollout(fast)
    times = side_by_side(fns, rounds=5, min_time=2.0, warmup=1)
    eager = statistics.median(times["eager"]) / steps
    row("rollout", f"eager step, {n} starts", _fmt_time(eager))
    if compile_:
        r = Ratio.of(times["compiled"], times["eager"])
        what = f"compiled step, {n} starts ({compile_s:.0f} s to compile) / eager"
        step = _fmt_time(statistics.median(times["compiled"]) / steps)
        row("rollout", what, step, f"eager {_fmt_time(eager)}", r, "≤ 0.05", r.value <= 0.05, key="compiled_step")
    env.close()


SECTIONS = {
    "batched": section_batched,
    "train": section_train,
    "reference": section_reference,
    "rollout": section_rollout,
    "latency": section_latency,
    "compile": section_compile,
    "scaling": section_scaling,
    "sets": section_sets,
    "clouds": section_clouds,
    "cuda": section_cuda,
    "robots": section_robots,
    "lasa": section_lasa,
    "collisions": section_collisions,
}


def _arguments(argv) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--only", choices=[*SECTIONS, "memory"], action="append")
    ap.add_argument("--no-compile", action="store_true", help="skip the torch.compile rows")
    ap.add_argument("--no-export", action="store_true", help="skip the AOTInductor rows (a minute of packaging each)")
    ap.add_argument("--json", type=Path, help="also write the rows here")
    ap.add_argument("--collision-steps", type=int, default=COLLISIONS["steps"], help="the collision section's steps")
    ap.add_argument("--markdown", type=Path, help="also write the table as markdown here (the README's table)")
    ap.add_argument(
        "--check",
        action="store_true",
        help="compare the ratios with this machine kind's baseline; exit 1 if one rose beyond noise",
    )
    ap.add_argument(
        "--store-baseline", action="store_true", help="write this run's ratios as this machine kind's baseline"
    )
    ap.add_argument("--baseline", type=Path, default=baseline.BASELINE, help="the baseline file (default: %(default)s)")
    return ap.parse_args(argv)


def _markdown(path: Path) -> None:
    lines = ["| section | what | value | reference | ratio | target | met |", "|---|---|---|---|---|---|---|"]
    for r in ROWS:
        met = "" if r["met"] is None else ("yes" if r["met"] else "**no**")
        lines.append(
            f"| {r['section']} | {r['what']} | {r['value']} | {r['reference']} | {r['ratio']} | {r['target']} | {met} |"
        )
    path.write_text("\n".join(lines) + "\n")


def _baseline(args: argparse.Namespace, info: dict) -> int:
    """``--check`` and ``--store-baseline`` after the table: 1 if a ratio regressed (then nothing is stored)."""
    kind = baseline.machine_kind()
    if args.check:
        lines, regressed = baseline.check(ROWS, baseline.load(args.baseline), kind)
        print(f"\nratios against the baseline of {kind} ({args.baseline.name}):")
        print("\n".join(lines))
        if regressed:
            print(f"{len(regressed)} ratio(s) regressed beyond noise: {', '.join(regressed)}")
            if args.store_baseline:
                print("the baseline is not replaced by a run that regressed")
            return 1
    if args.store_baseline:
        n = baseline.store(ROWS, args.baseline, kind, info)
        print(f"stored {n} ratio(s) as the baseline of {kind} in {args.baseline}")
    return 0


def main(argv=None) -> int:
    args = _arguments(argv)
    COLLISIONS["steps"] = args.collision_steps
    AHEAD_OF_TIME["on"] = not args.no_export
    torch.set_num_threads(1)
    info = {
        "torch": torch.__version__,
        "rmpfusion": getattr(rmpfusion, "__version__", "?"),
        "python": platform.python_version(),
        "machine": f"{platform.machine()} {platform.processor() or ''}".strip(),
        "cpus": os.cpu_count(),
        "cpu": baseline.cpu_model(),
        "threads": "1 unless a row says otherwise",
        "platform": platform.platform(),
    }
    print("rmpfusion benchmark  " + "  ".join(f"{k}={v}" for k, v in info.items()))
    print(f"  {'what':<58} {'value':>16} {'reference':>22} {'ratio':>8} {'target':>14}")
    for name in args.only or [*SECTIONS, "memory"]:
        if name == "memory":
            section_memory()
        else:
            SECTIONS[name](not args.no_compile)
    if args.json:
        args.json.write_text(json.dumps({"info": info, "rows": ROWS}, indent=1))
    if args.markdown:
        _markdown(args.markdown)
    missed = [r["what"] for r in ROWS if r["met"] is False]
    print(
        f"\n{len([r for r in ROWS if r['met']])} targets met, {len(missed)} missed"
        + (": " + "; ".join(missed) if missed else "")
    )
    return _baseline(args, info)


if __name__ == "__main__":
    sys.exit(main())
