"""Theorem 2 on a batch of 2d1level rollouts of a hand-designed RMPfusion tree (no learning).

Samples environments, rolls the closed loop q̈ = π(q, q̇) out for the whole batch, checks Theorem 2 on
every rollout (V_r non-increasing, dV_r/dt = −q̇ᵀB_r q̇), and writes figures and metrics.json to a new
run directory under outputs/.
"""

from __future__ import annotations

import json
import sys
import time
from datetime import datetime
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import torch

import rmpfusion
from rmpfusion.envs.particle2d import Particle2D
from rmpfusion.evaluate.lyapunov import energy_rate_residual, lyapunov_monotone

TREE = {
    "root": {"name": "q", "dim": 2},
    "nodes": {
        "obstacle": {
            "parent": "q",
            "map": {"type": "sphere_distance", "center": "obstacle1_center", "radius": "obstacle1_radius"},
            "weight": {
                "type": "logistic",
                "low": 0.5,
                "high": 4.0,
                "center": "obstacle1_center",
                "radius": "obstacle1_radius",
                "steepness": -4.0,
                "switch_distance": 0.5,
            },
            "rmp": {"type": "collision_avoidance", "r_w": 1.0, "alpha": 1e-3, "eta": 0.5},
        },
        "goal": {
            "parent": "q",
            "map": {"type": "offset", "origin": "goal"},
            "weight": {"type": "rbf", "low": 1.0, "high": 3.0, "center": "goal", "sigma": 1.0},
            "rmp": {"type": "goal_attractor", "gain": 2.0, "eta": 2.0},
        },
    },
}


def main() -> int:
    torch.set_num_threads(1)
    torch.manual_seed(0)
    run_dir = Path("outputs") / "lyapunov_demo" / datetime.now().strftime("%Y-%m-%d_%H-%M-%S")
    (run_dir / "figures").mkdir(parents=True, exist_ok=False)
    env = Particle2D(n_obstacles=1)
    tree = rmpfusion.build_tree(TREE, aux_dims=env.aux_dims())
    print(tree.describe())
    q0, qd0, aux = env.sample(n_envs=8, n_per_env=8, seed=0)
    t0 = time.perf_counter()
    last = [0.0]

    def progress(step, total):
        now = time.perf_counter()
        if now - last[0] > 2 or step == total:
            last[0] = now
            print(f"rollout {step}/{total} records ({now - t0:.1f}s)", flush=True)

    ro = env.rollout(tree, q0, qd0, aux, horizon=12.0, record_every=0.1, progress=progress)
    wall = time.perf_counter() - t0
    mono = lyapunov_monotone(ro.V)
    resid = energy_rate_residual(ro.times, ro.V, ro.dissipation)
    metrics = {
        "trajectories": ro.batch_size,
        "success_rate": float(ro.success.double().mean()),
        "collision_rate": float(ro.collided.double().mean()),
        "lyapunov_monotone_fraction": float(mono.double().mean()),
        "max_energy_rate_residual": float(resid.abs().max()),
        "rollout_wall_time_s": wall,
    }
    (run_dir / "metrics.json").write_text(json.dumps(metrics, indent=2))

    fig, (ax, axv) = plt.subplots(1, 2, figsize=(11, 5))
    env_id = 0
    sl = slice(env_id * 8, env_id * 8 + 8)
    c, r = aux["obstacle1_center"][sl.start], aux["obstacle1_radius"][sl.start]
    ax.add_patch(plt.Circle(c.tolist(), float(r), color="tab:red", alpha=0.4))
    gl = aux["goal"][sl.start]
    ax.plot(*gl.tolist(), "s", color="orange", ms=10, label="goal")
    for b in range(sl.start, sl.stop):
        ax.plot(ro.q[:, b, 0], ro.q[:, b, 1], "-", lw=1.5)
        ax.plot(*ro.q[0, b].tolist(), "ko", ms=4)
        ax.arrow(*ro.q[0, b].tolist(), *(0.5 * ro.qd[0, b]).tolist(), head_width=0.1, color="k")
    ax.set_aspect("equal")
    ax.set_title("trajectories in one environment")
    ax.legend()
    for b in range(sl.start, sl.stop):
        axv.plot(ro.times, ro.V[:, b])
    axv.set_xlabel("t [s]")
    axv.set_ylabel("V_r")
    axv.set_title("Lyapunov function (non-increasing)")
    fig.tight_layout()
    fig.savefig(run_dir / "figures" / "trajectories_lyapunov.png", dpi=120)
    print(json.dumps(metrics, indent=2))
    print(f"run directory: {run_dir}")
    return 0 if metrics["lyapunov_monotone_fraction"] == 1.0 and metrics["collision_rate"] == 0.0 else 1


if __name__ == "__main__":
    sys.exit(main())
