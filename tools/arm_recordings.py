#!/usr/bin/env python
"""Recordings of an arm that no RMP tree made: a joint-space spline planner's trajectories through a via point
around an obstacle, written as a user's logger would write them (a CSV of time and joint angles, irregular time
stamps, dropped samples, measurement noise), for ``experiment=recorded_arm`` to read back like a user's file.

    python tools/arm_recordings.py                       # rmpfusion/recordings/files/panda_via_points.csv
    python tools/arm_recordings.py --out my.csv --demos 8 --seed 3

The planner (ours, standing in for a motion planner or a person teaching the arm): the environment and scene of
``experiment=recorded_arm`` (the Panda and the Franka experiment's cylinder); each demonstration starts at a
configuration drawn around the environment's start centre, ends at rest at a configuration whose end effector is in
the goal region behind the cylinder (damped least-squares inverse kinematics), and passes a via point in front of the
cylinder (between it and the robot), its height between the start's and the goal's. The joints follow one clamped
cubic spline through the three configurations (at rest at both ends) over a random duration. A plan is kept only if
every configuration along it stays inside the joint limits and clear of the cylinder and the table by
``--clearance``; the tool says how many plans it drew for the demonstrations it kept.

The recording: at rest for a moment before and after the motion, sampled at ``--rate`` Hz with jittered time stamps
(Gaussian, ``--jitter`` s), ``--drop`` of the samples lost, a clock that does not start at 0, and Gaussian noise of
``--noise`` rad on every angle. Columns: demo, t, then the robot's joint names.
"""

from __future__ import annotations

import argparse
import csv
import io
import sys
from pathlib import Path

import numpy as np
import torch
from omegaconf import OmegaConf
from scipy.interpolate import CubicSpline

from rmpfusion.envs.manipulator.worlds import sample_aux
from rmpfusion.files import atomic_write_bytes
from rmpfusion.pipeline.compose import compose_config
from rmpfusion.recordings.source import SHIPPED_DIR
from rmpfusion.registry import ENVS

DEFAULT_OUT = SHIPPED_DIR / "panda_via_points.csv"
#: the via point's place in front of the cylinder (m, world frame): x, ± y, and its height's jitter about the
#: mean of the start's and the goal's
VIA_X = (0.33, 0.38)
VIA_Y = 0.04
VIA_Z = 0.05
#: the cylinder's aux entry, which --cylinder-shift moves for each demonstration (written as the columns ox, oy, oz)
CYLINDER = "obstacle1_center"


def environment(overrides: list[str]):
    """The recorded_arm experiment's environment (robot, scene, start centre, goal region), built from its env
    block alone: the experiment's data are what this tool makes."""
    cfg = compose_config(["experiment=recorded_arm", *overrides])
    block = OmegaConf.to_container(cfg.env, resolve=True)
    kind = ENVS.get(block.pop("type")).obj
    return kind(kind.Params.model_validate(block))


def inverse_kinematics(env, target: np.ndarray, seed: np.ndarray, iters: int = 200) -> tuple[np.ndarray, float]:
    """A configuration near ``seed`` whose end effector is at ``target``: damped least squares on the position
    with a pull towards the seed (the null space of a 7-joint arm), clipped inside the limits."""
    q = torch.tensor(seed, dtype=torch.float64)
    x = torch.tensor(target, dtype=torch.float64)
    lo, hi = env.lower + 0.05, env.upper - 0.05
    s = q.clone()
    for _ in range(iters):
        J = torch.autograd.functional.jacobian(lambda v: env.ee_position(v[None])[0], q)
        e = x - env.ee_position(q[None])[0]
        JJt = J @ J.T + 1e-4 * torch.eye(3, dtype=torch.float64)
        dq = J.T @ torch.linalg.solve(JJt, e)
        null = torch.eye(len(q), dtype=torch.float64) - J.T @ torch.linalg.solve(JJt, J)
        q = torch.clamp(q + dq + 0.1 * null @ (s - q), lo, hi)
    err = float((x - env.ee_position(q[None])[0]).norm())
    return q.numpy(), err


def plan(
    env, rng: np.random.Generator, duration: float, shift: np.ndarray | None = None
) -> tuple[CubicSpline, np.ndarray] | None:
    """One start -> via -> goal joint spline, or None when the inverse kinematics misses (> 2 mm); the via point
    follows the cylinder across the reach when it stands ``shift`` from the scene's place."""
    p = env.params
    centre, spread = np.array(p.start_centre()), np.array(p.spread())
    q_start = centre + rng.uniform(-spread, spread)
    region = np.array(p.goal_region)
    goal = rng.uniform(region[:, 0], region[:, 1])
    ee_start = env.ee_position(torch.tensor(q_start[None]))[0].numpy()
    seed_goal = centre.copy()
    seed_goal[0] = np.arctan2(goal[1], goal[0])
    q_goal, e1 = inverse_kinematics(env, goal, seed_goal)
    via = np.array(
        [
            rng.uniform(*VIA_X),
            rng.uniform(-VIA_Y, VIA_Y) + (0.0 if shift is None else float(shift[1])),
            0.5 * (ee_start[2] + goal[2]) + rng.uniform(-VIA_Z, VIA_Z),
        ]
    )
    q_via, e2 = inverse_kinematics(env, via, 0.5 * (q_start + q_goal))
    if max(e1, e2) > 2e-3:
        return None
    knots = np.array([0.0, duration * rng.uniform(0.4, 0.6), duration])
    return CubicSpline(knots, np.stack([q_start, q_via, q_goal]), bc_type="clamped"), q_goal


def clear(env, spline: CubicSpline, duration: float, clearance: float, centre: np.ndarray | None = None) -> bool:
    """Every configuration along the plan (50 Hz) inside the limits and ``clearance`` from the cylinder (standing at
    ``centre``, default the scene's place) and the table."""
    q = torch.tensor(spline(np.linspace(0.0, duration, int(50 * duration) + 1)), dtype=torch.float64)
    if not bool(((q > env.lower + 0.02) & (q < env.upper - 0.02)).all()):
        return False
    aux = env.recorded_aux(q[-1:].expand(len(q), -1))
    if centre is not None:
        aux[CYLINDER] = torch.tensor(centre, dtype=torch.float64).expand(len(q), 3).contiguous()
    sc, p = env.checker(), env.params
    for b in range(len(q)):
        sc.set_env(env.scene, sample_aux(aux, b))
        sc.reset(q[b].numpy())
        if sc.start_margin(clearance, p.clearance_query) < 0:
            return False
    return True


def record(spline: CubicSpline, duration: float, rng: np.random.Generator, a) -> tuple[np.ndarray, np.ndarray]:
    """The plan as a logger records it: rest before and after, jittered stamps, dropped samples, noise."""
    before, after = rng.uniform(0.3, 0.6), rng.uniform(0.5, 0.8)
    n = int((before + duration + after) * a.rate)
    t = np.arange(n) / a.rate + rng.normal(0.0, a.jitter, n)
    t = np.sort(t)
    keep = rng.uniform(size=n) >= a.drop
    keep[[0, -1]] = True
    t = t[keep]
    t = t[np.concatenate([[True], np.diff(t) > 1e-4])]
    q = spline(np.clip(t - before, 0.0, duration))
    q += rng.normal(0.0, a.noise, q.shape)
    return t + rng.uniform(5.0, 50.0), q


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT)
    ap.add_argument("--demos", type=int, default=24)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--rate", type=float, default=100.0, help="the logger's nominal rate (Hz)")
    ap.add_argument("--jitter", type=float, default=0.002, help="std of the time stamps' jitter (s)")
    ap.add_argument("--drop", type=float, default=0.03, help="fraction of samples lost")
    ap.add_argument("--noise", type=float, default=0.001, help="std of the angles' noise (rad)")
    ap.add_argument("--duration", type=float, nargs=2, default=(2.5, 3.5), help="the motion's duration range (s)")
    ap.add_argument("--clearance", type=float, default=0.03, help="m from the cylinder and the table along a plan")
    ap.add_argument(
        "--cylinder-shift",
        type=float,
        nargs=2,
        metavar=("DX", "DY"),
        help="move the cylinder for each demonstration by up to ±DX, ±DY (m) and write where it stood (ox, oy, oz)",
    )
    ap.add_argument("overrides", nargs="*", help="Hydra overrides of experiment=recorded_arm (e.g. robot=...)")
    a = ap.parse_args(argv)
    env = environment(a.overrides)
    rng = np.random.default_rng(a.seed)
    names = list(env.params.robot.joints)
    rows, drawn = [], 0
    while len(rows) < a.demos:
        drawn += 1
        if drawn > 50 * a.demos:
            print(f"only {len(rows)} of {a.demos} plans clear after {drawn - 1} draws", file=sys.stderr)
            return 1
        shift, centre = None, None
        if a.cylinder_shift:  # drawn only when asked, so the default file is the same draw for draw
            shift = np.array([*rng.uniform(-np.array(a.cylinder_shift), np.array(a.cylinder_shift)), 0.0])
            centre = np.array(env.scene.obstacles[0].center) + shift
        duration = rng.uniform(*a.duration)
        made = plan(env, rng, duration, shift)
        if made is None or not clear(env, made[0], duration, a.clearance, centre):
            continue
        t, q = record(made[0], duration, rng, a)
        rows.append((len(rows), t, q, centre))
    lines = []
    for demo, t, q, centre in rows:
        where = [f"{v:.4f}" for v in centre] if centre is not None else []
        lines += [[f"demo{demo:02d}", f"{tk:.4f}", *(f"{v:.5f}" for v in qk), *where] for tk, qk in zip(t, q)]
    a.out.parent.mkdir(parents=True, exist_ok=True)
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["demo", "t", *names, *(["ox", "oy", "oz"] if a.cylinder_shift else [])])
    w.writerows(lines)
    atomic_write_bytes(a.out, buf.getvalue().encode())
    print(f"{a.out}: {len(rows)} demonstrations, {len(lines)} rows ({drawn} plans drawn)")
    env.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
