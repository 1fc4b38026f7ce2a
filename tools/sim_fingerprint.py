#!/usr/bin/env python
"""What a change to the simulator layer must leave alone: a fingerprint of the manipulator environment's numbers,
written at one commit and compared with another's.

    python tools/sim_fingerprint.py outputs/before.json          # at the old commit
    python tools/sim_fingerprint.py outputs/after.json           # at the new one
    python tools/sim_fingerprint.py --compare outputs/before.json outputs/after.json

For experiment=franka, franka_three_obstacles (a moving obstacle) and reach robot=ur5 (a ground the shoulder cannot
leave): starts sampled from the test split (clearance checks in the simulator), the expert's torque-mode and
kinematic rollouts of 0.5 s from them (q, q̇, minimum clearance, first collision, reached), the clearance at the
starts, and a small render. ``--compare`` prints the largest difference of every entry (0 where bit-identical).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import torch

CASES = {"franka": [], "franka_three_obstacles": [], "reach": ["robot=ur5"]}


def fingerprint(sim: str = "pybullet") -> dict:
    from rmpfusion.pipeline.compose import compose_run
    from rmpfusion.pipeline.construct import build_expert, make_env

    out = {}
    for experiment, overrides in CASES.items():
        run = compose_run([f"experiment={experiment}", *overrides, *([f"sim={sim}"] if sim != "pybullet" else [])])
        env = make_env(run)
        tree = build_expert(run, env.aux_dims()).double()
        g = torch.Generator().manual_seed(3)
        q0, qd0, aux = env.sample_initial_states(env.sample_envs(2, g, split="test"), 2, g)
        case = {"q0": q0.tolist(), "goal": aux["goal"].tolist(), "clearance": env.clearance(q0, aux).tolist()}
        for mode in ("torque", "kinematic"):
            with torch.no_grad():
                ro = env.rollout(tree, q0, qd0, aux, horizon=0.5, record_every=0.1, mode=mode)
            case[mode] = {
                k: getattr(ro, k).tolist() for k in ("q", "qd", "min_clearance", "first_collision_time", "reached")
            } | {"error": ro.error}
        case["render"] = env.render(q0[0], aux, 64, 48).astype(int).tolist()
        out[experiment] = case
        env.close()
    return out


def differences(a, b, path: str = "") -> list[tuple[str, float]]:
    """(entry, largest absolute difference) of every numeric leaf; inf where they disagree in kind or shape."""
    if isinstance(a, dict):
        return [d for k in a for d in differences(a[k], b.get(k), f"{path}/{k}")]
    if isinstance(a, list) and a and isinstance(a[0], str | type(None)):
        return [(path, 0.0 if a == b else float("inf"))]
    x, y = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    if x.shape != y.shape:
        return [(path, float("inf"))]
    same = (x == y) | (np.isnan(x) & np.isnan(y))
    return [(path, 0.0 if same.all() else float(np.nanmax(np.abs(np.where(same, 0.0, x - y)))))]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("out", nargs="?", type=Path, help="where to write this commit's fingerprint (JSON)")
    ap.add_argument("--sim", default="pybullet")
    ap.add_argument("--compare", nargs=2, type=Path, metavar=("BEFORE", "AFTER"))
    a = ap.parse_args(argv)
    if a.compare:
        before, after = (json.loads(p.read_text()) for p in a.compare)
        for entry, d in differences(before, after):
            print(f"{entry:45s} {d:.3g}")
        return 0
    if a.out is None:
        ap.error("give the file to write, or --compare BEFORE AFTER")
    a.out.write_text(json.dumps(fingerprint(a.sim)))
    print(f"wrote {a.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
