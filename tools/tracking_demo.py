"""How closely a robot's end effector follows a goal moving on a circle: goal_attractor against moving_goal_attractor.

Both trees are the same but for the end-effector leaf: forward kinematics to the end effector, the attractor with
the same gains (gain 5, alpha 10, eta 5), a damper on the joints (w 0.1, eta 2) and the identity metric. The goal
circles at ``--speed`` rad/s on a horizontal circle of radius ``--radius`` in front of the robot; aux carries its
position and velocity at every integration stage (RK4, 0.01 s). docs/math.md §8 ("Moving goals", 4.) says why no
theorem bounds this error on a robot; this measures it, for the Panda and the KUKA iiwa of pybullet_data.

    python tools/tracking_demo.py                  # the README's table
    python tools/tracking_demo.py --speed 2.0
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import pybullet_data
import torch

import rmpfusion

IIWA = str(Path(pybullet_data.getDataPath()) / "kuka_iiwa" / "model.urdf")
#: robot -> (how the maps name it, end-effector link, point in it, start configuration, circle centre)
ROBOTS = {
    "Panda": (
        {"urdf": "pkg://pybullet_data/franka_panda/panda.urdf", "joints": [f"panda_joint{i}" for i in range(1, 8)]},
        "panda_hand",
        [0.0, 0.0, 0.1034],
        [0.0, -0.3, 0.0, -2.2, 0.0, 2.0, 0.8],
        [0.45, 0.0, 0.45],
    ),
    "KUKA iiwa": (
        {"urdf": IIWA},
        "lbr_iiwa_link_7",
        [0.0, 0.0, 0.05],
        [0.0, 0.6, 0.0, -1.4, 0.0, 0.8, 0.0],
        [0.5, 0.0, 0.5],
    ),
}
LEAVES = ("goal_attractor", "moving_goal_attractor")
GAINS = {"gain": 5.0, "alpha": 10.0, "eta": 5.0}


def tracking_tree(robot: str, leaf: str) -> rmpfusion.RMPTree:
    source, link, offset = ROBOTS[robot][:3]
    if leaf == "moving_goal_attractor":
        attractor = {"map": {"type": "moving_offset", "origin": "goal", "velocity": "goal_velocity"}}
    else:
        attractor = {"map": {"type": "offset", "origin": "goal"}}
    return rmpfusion.build_tree(
        {
            "root": {"name": "q", "dim": 7},
            "aux": {"goal": 3, "goal_velocity": 3},
            "nodes": {
                "ee": {"parent": "q", "map": {"type": "forward_kinematics", **source, "link": link, "offset": offset}},
                "attractor": {"parent": "ee", **attractor, "rmp": {"type": leaf, **GAINS}},
                "damper": {"parent": "q", "map": {"type": "identity"}, "rmp": {"type": "damper", "w": 0.1, "eta": 2.0}},
                "regulariser": {"parent": "q", "map": {"type": "identity"}, "rmp": {"type": "identity_metric"}},
            },
        }
    )


def circle(centre: list[float], radius: float, speed: float):
    """aux(t): the goal's position and velocity on the circle, (1, 3) each."""
    c = torch.tensor(centre, dtype=torch.float64)

    def at(t: float) -> dict[str, torch.Tensor]:
        cos, sin = math.cos(speed * t), math.sin(speed * t)
        return {
            "goal": (c + radius * torch.tensor([cos, sin, 0.0], dtype=torch.float64))[None],
            "goal_velocity": (radius * speed * torch.tensor([-sin, cos, 0.0], dtype=torch.float64))[None],
        }

    return at


def end_effector_errors(tree, q, at, dt: float, steps: int) -> torch.Tensor:
    """RK4 of q̈ = tree(q, q̇, aux(t)), aux evaluated at each stage's time; the end effector's distance to the goal
    at every step."""
    acc = lambda t, q_, qd_: tree(q_, qd_, at(t)).qdd
    qd, errors = torch.zeros_like(q), []
    with torch.no_grad():
        for k in range(steps):
            t = k * dt
            errors.append(float((tree.maps["ee"].psi(q, None) - at(t)["goal"]).norm()))
            k1 = acc(t, q, qd)
            k2x, k2v = qd + 0.5 * dt * k1, acc(t + 0.5 * dt, q + 0.5 * dt * qd, qd + 0.5 * dt * k1)
            k3x, k3v = qd + 0.5 * dt * k2v, acc(t + 0.5 * dt, q + 0.5 * dt * k2x, qd + 0.5 * dt * k2v)
            k4x, k4v = qd + dt * k3v, acc(t + dt, q + dt * k3x, qd + dt * k3v)
            q, qd = q + dt / 6 * (qd + 2 * k2x + 2 * k3x + k4x), qd + dt / 6 * (k1 + 2 * k2v + 2 * k3v + k4v)
    return torch.tensor(errors)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--speed", type=float, default=1.0, help="angular speed of the goal on its circle (rad/s)")
    ap.add_argument("--radius", type=float, default=0.15, help="radius of the circle (m)")
    ap.add_argument("--seconds", type=float, default=8.0, help="duration; the error is averaged over its second half")
    args = ap.parse_args()
    torch.set_num_threads(1)
    dt = 0.01
    steps = round(args.seconds / dt)
    print(
        f"goal on a circle of radius {args.radius} m at {args.speed} rad/s ({args.radius * args.speed:.3f} m/s); "
        f"end-effector distance to the goal over the last {args.seconds / 2:g} s of {args.seconds:g} s\n"
    )
    print("| robot | leaf | mean error (m) | max error (m) | wall time (s) |\n| --- | --- | --- | --- | --- |")
    for robot, (_, _, _, start, centre) in ROBOTS.items():
        for leaf in LEAVES:
            t0 = time.perf_counter()
            err = end_effector_errors(
                tracking_tree(robot, leaf),
                torch.tensor([start], dtype=torch.float64),
                circle(centre, args.radius, args.speed),
                dt,
                steps,
            )[steps // 2 :]
            print(
                f"| {robot} | `{leaf}` | {float(err.mean()):.4f} | {float(err.max()):.4f} | "
                f"{time.perf_counter() - t0:.1f} |"
            )


if __name__ == "__main__":
    main()
