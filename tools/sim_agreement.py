#!/usr/bin/env python
"""How closely the simulators agree with rmpfusion and with each other, on every robot of conf/robot/:

    python tools/sim_agreement.py            # a Markdown table, about a minute
    python tools/sim_agreement.py --samples 20

Per robot: the largest difference between rmpfusion's link frames (its chain from the URDF) and each simulator's
(positions in m, rotation-matrix entries), over random configurations within the joint limits; the largest
difference of the inverse dynamics M(q)q̈ + C(q, q̇)q̇ + g(q) between pybullet and MuJoCo, relative to the largest
torque, at random states; and the largest difference of the signed distance between the robot and a sphere, box,
cylinder or capsule placed beside one of its links (m).
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np
import torch
import yaml

from rmpfusion.robots import RobotDescription, URDFRobot, build_robot
from rmpfusion.sims import Obstacle, SimulatorParams, WorldSettings, open_world
from rmpfusion.sims.obstacles import rotation_z_to

CONF = Path(__file__).resolve().parents[1] / "conf"
SIMS = ("pybullet", "mujoco")


def _full(r: URDFRobot, q: np.ndarray) -> np.ndarray:
    return r.simulated_state(q)[0]


def agreement(name: str, samples: int, seed: int = 0) -> dict[str, float]:
    """The differences the module docstring lists, for conf/robot/<name>.yaml."""
    r = build_robot(RobotDescription.model_validate(yaml.safe_load((CONF / "robot" / f"{name}.yaml").read_text())))
    worlds = {s: open_world(r, WorldSettings(), SimulatorParams(type=s)) for s in SIMS}
    g = np.random.default_rng(seed)
    lo, hi = np.maximum(r.lower.numpy(), -math.pi), np.minimum(r.upper.numpy(), math.pi)
    n = r.dof + len(r.held_joints())
    out = {f"{s}_frames": 0.0 for s in SIMS} | {"inverse_dynamics": 0.0, "distance": 0.0}
    try:
        for _ in range(samples):
            q = lo + (hi - lo) * g.random(r.dof)
            fk = r.chain.forward_kinematics(torch.tensor(q[None]))
            for s, w in worlds.items():
                w.reset(_full(r, q), np.zeros(n))
                for link, (p, R) in w.link_frames().items():
                    if link in fk:
                        err = max(np.abs(fk[link][1][0].numpy() - p).max(), np.abs(fk[link][0][0].numpy() - R).max())
                        out[f"{s}_frames"] = max(out[f"{s}_frames"], float(err))
            qd, qdd = g.standard_normal(n), g.standard_normal(n)
            tau = [w.inverse_dynamics(_full(r, q), qd, qdd) for w in worlds.values()]
            out["inverse_dynamics"] = max(
                out["inverse_dynamics"], float(np.abs(tau[0] - tau[1]).max() / np.abs(tau[0]).max())
            )
            centres = r.sphere_centres(torch.tensor(q[None]))[0].numpy()
            beside = centres[g.integers(len(centres))] + [0.08, 0.0, 0.0] + 0.03 * g.standard_normal(3)
            R = rotation_z_to(g.standard_normal(3))
            for o in (
                Obstacle("sphere", beside, radius=0.05),
                Obstacle("box", beside, R, half_extents=(0.04, 0.05, 0.06)),
                Obstacle("cylinder", beside, R, radius=0.04, half_length=0.1),
                Obstacle("capsule", beside, R, radius=0.04, half_length=0.1),
            ):
                d = []
                for w in worlds.values():
                    w.set_obstacles([o])
                    d.append(w.obstacle_distance(0.3))
                out["distance"] = max(out["distance"], abs(d[0] - d[1]))
    finally:
        for w in worlds.values():
            w.close()
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--samples", type=int, default=10, help="configurations (and states) per robot")
    a = ap.parse_args(argv)
    print(
        "| robot | link frames: pybullet | link frames: MuJoCo | inverse dynamics, pybullet vs MuJoCo (relative) | distance, pybullet vs MuJoCo (m) |"
    )
    print("|---|---|---|---|---|")
    for name in sorted(p.stem for p in (CONF / "robot").glob("*.yaml")):
        x = agreement(name, a.samples)
        print(
            f"| {name} | {x['pybullet_frames']:.1e} | {x['mujoco_frames']:.1e} | {x['inverse_dynamics']:.1e} | {x['distance']:.1e} |"
        )
        sys.stdout.flush()
    return 0


if __name__ == "__main__":
    sys.exit(main())
