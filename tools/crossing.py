#!/usr/bin/env python
"""Is the obstacle in the way? For an experiment's generators and seed, the straight end-effector reach of every
training, validation and test start to its goal (exactly the starts and goals the run's demonstrations use), how
many cross an obstacle and how far they pass from its surface (``rmpfusion/scenes/crossing.py``).

    python tools/crossing.py --experiment franka
    python tools/crossing.py --experiment reach robot=iiwa
    python tools/crossing.py --experiment franka --json crossing.json

A reach crosses when its segment comes within the end effector's control-sphere radius of an obstacle's surface.
Prints per split: paths, crossing fraction, and quantiles of each path's clearance (m, negative: through the
obstacle). Sampling starts checks them in pybullet, so this takes a few seconds per split.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import torch

from rmpfusion.pipeline.collect import SPLIT_SEED_OFFSET
from rmpfusion.pipeline.compose import compose_run
from rmpfusion.pipeline.construct import make_env
from rmpfusion.scenes.crossing import QUANTILES, summarize

SPLITS = ("train", "val", "test")


def split_summaries(run, env) -> dict[str, dict]:
    """Per split: the crossing summary of its starts and goals, drawn as the collect stage draws them."""
    d, out = run.data, {}
    sizes = {
        "train": (d.train_envs, d.train_trajectories),
        "val": (d.val_envs, d.val_trajectories),
        "test": (d.test_envs, d.test_trajectories),
    }
    for split in SPLITS:
        n_envs, n_traj = sizes[split]
        if n_envs == 0:
            continue
        gen = torch.Generator().manual_seed(run.seed + SPLIT_SEED_OFFSET[split])
        q0, _, aux = env.sample_initial_states(env.sample_envs(n_envs, gen, split=split), n_traj, gen)
        out[split] = summarize(env.path_clearance(q0, aux), env.ee_radius).as_dict()
    return out


def table(summaries: dict[str, dict]) -> str:
    head = f"{'split':6s} {'paths':>5s} {'crossing':>8s} " + " ".join(f"{q:>7s}" for q in QUANTILES)
    lines = [head]
    for split, s in summaries.items():
        qs = " ".join(f"{s['clearance_quantiles'].get(q, float('nan')):7.3f}" for q in QUANTILES)
        lines.append(f"{split:6s} {s['paths']:5d} {s['crossing_fraction']:8.2f} {qs}")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--experiment", default="franka", help="the experiment (conf/experiment/)")
    ap.add_argument("--json", type=Path, help="also write the summaries to this file")
    ap.add_argument("overrides", nargs="*", help="further Hydra overrides, e.g. robot=iiwa seed=1")
    a = ap.parse_args(argv)
    torch.set_num_threads(1)
    run = compose_run([f"experiment={a.experiment}", "logger=disabled", *a.overrides])
    env = make_env(run)
    summaries = split_summaries(run, env)
    env.close()
    print(
        f"{run.name}, seed {run.seed}: a reach crosses when its straight end-effector path passes within "
        f"{env.ee_radius:.3f} m (the end effector's control sphere) of an obstacle; clearance quantiles in m"
    )
    print(table(summaries))
    if a.json:
        a.json.write_text(json.dumps({"experiment": run.name, "seed": run.seed, "splits": summaries}, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
