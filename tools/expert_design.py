#!/usr/bin/env python
"""Do an experiment's expert weights matter? The expert (conf/expert/) beside the same tree with unit weights
(RMPflow) and with its attractor weight but unit obstacle weights, from the validation split's starts (the obstacles
in their training placement): designing the expert never looks at the test set.

    python tools/expert_design.py                              # experiment=franka, kinematic rollouts at 250 Hz
    python tools/expert_design.py --experiment reach robot=iiwa --rate 1000 --mode torque
    python tools/expert_design.py --experiment reach robot=iiwa --only expert env.reach_layout.turn=1.0
    python tools/expert_design.py --experiment reach robot=ur5 --out results/reach_expert_design/ur5

With --where-stopped, every rollout that did not reach its goal is described where it ended: its distance from
the goal, the joints within AT_LIMIT rad of a limit and the final configuration (a policy held by a joint limit
against an obstacle is a local minimum that obstacle weights cannot remove).

With --out DIR the numbers are also written to DIR/metrics.json (the command, the seed, the wall time and every
policy's numbers), which tools/expert_design_table.py turns into the documentation's table.

Prints, per policy (and learner-0, learner-rmp with the initial weights a run with this seed draws): time to 0.05 m,
fraction reached, path lengths, goal distance at the 10 s time-out, collisions, close passes (no collision but within
CLOSE_PASS = 10 mm of an obstacle) and the closest approach of any link to an obstacle (least and median over starts).
An expert whose weights are what make it
succeed reaches the goal where the unit-weight tree does not; obstacle weights that matter keep the arm
further from the obstacles than unit ones do.
"""

from __future__ import annotations

import argparse
import shlex
import sys
import time
from pathlib import Path

import torch

from rmpfusion.assembly.tree import build_tree
from rmpfusion.files import atomic_write_json
from rmpfusion.pipeline.collect import SPLIT_SEED_OFFSET
from rmpfusion.pipeline.compose import compose_run
from rmpfusion.pipeline.construct import build_all, build_learners, expert_spec
from rmpfusion.pipeline.experiment import learner_seed


def variants(expert: dict) -> dict[str, dict]:
    """Expert weight sets: as designed, all 1 (RMPflow), and the designed attractor with unit obstacle weights."""
    unit = {"type": "constant", "value": 1.0}
    return {
        "expert": expert,
        "unit weights (RMPflow)": {k: unit for k in expert},
        "unit obstacle weights": {k: (v if k == "attractor" else unit) for k, v in expert.items()},
    }


def policies(run, env, keep: set[str]):
    """(label, policy) of each policy asked for: the weight variants as trees, and learner-rmp as the run would draw
    it before training (its seed's initial weights)."""
    for label, weights in variants(dict(run.expert)).items():
        if label in keep:
            yield label, build_tree(expert_spec(run.model_copy(update={"expert": weights})), aux_dims=env.aux_dims())
    if "learner-0" in keep and "rmp" in run.learners:
        with torch.random.fork_rng():
            torch.manual_seed(learner_seed(run.seed, "rmp"))
            learner = build_learners(run.model_copy(update={"learners": {"rmp": run.learners["rmp"]}}), env.aux_dims())[
                "rmp"
            ]
        yield "learner-0", learner.policy


AT_LIMIT = 0.02  # rad (or m): a joint this close to a limit is at it


def stopped_short(env, ro, goal: torch.Tensor) -> list[str]:
    """One line per rollout of ``ro`` that did not reach its goal: where it ended and which joints are at a limit."""
    robot, q = env.robot, ro.q[-1]
    at_limit = ((q - robot.lower) < AT_LIMIT) | ((robot.upper - q) < AT_LIMIT)
    short = (robot.ee_position(q) - goal).norm(dim=-1)
    lines = []
    for n in (~ro.reached).nonzero().flatten().tolist():
        held = [robot.params.joints[j] for j in at_limit[n].nonzero().flatten().tolist()]
        lines.append(
            f"    start {n}: {float(short[n]):.3f} m from the goal; joints at a limit: {', '.join(held) or 'none'}; "
            f"q = [{', '.join(f'{float(v):.2f}' for v in q[n])}]"
        )
    return lines


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--experiment", default="franka", help="the experiment (conf/experiment/) whose expert to run")
    ap.add_argument("--rate", type=float, default=250.0, help="control rate (Hz); the experiment evaluates at 1000")
    ap.add_argument("--mode", choices=["kinematic", "torque"], default="kinematic")
    ap.add_argument("--trajectories", type=int, default=20)
    ap.add_argument(
        "--only",
        nargs="+",
        choices=["expert", "unit", "unit-obstacle", "learner-0"],
        default=None,
        help="run only these policies (default: all four)",
    )
    ap.add_argument("--out", type=Path, default=None, help="also write the numbers to OUT/metrics.json")
    ap.add_argument(
        "--where-stopped", action="store_true", help="describe where each rollout that missed its goal ended"
    )
    ap.add_argument("overrides", nargs="*", help="further Hydra overrides, e.g. expert.attractor.low=20")
    a = ap.parse_args(argv)
    started = time.time()
    torch.set_num_threads(1)
    over = [
        f"experiment={a.experiment}",
        "logger=disabled",
        f"env.mode={a.mode}",
        f"env.control_rate={a.rate}",
        *a.overrides,
    ]
    run = compose_run(over)
    env, _, _ = build_all(run)
    gen = torch.Generator().manual_seed(run.seed + SPLIT_SEED_OFFSET["val"])
    q0, qd0, aux = env.sample_initial_states(env.sample_envs(1, gen, split="val"), a.trajectories, gen)
    print(
        f"{'policy':24s} {'time (s)':>11s} {'reached':>8s} {'c-space':>8s} {'e-e (m)':>8s} "
        f"{'dist@10s':>9s} {'collisions':>10s} {'close':>6s} {'clearance least/median':>23s}"
    )
    chosen = {
        "expert": "expert",
        "unit": "unit weights (RMPflow)",
        "unit-obstacle": "unit obstacle weights",
        "learner-0": "learner-0",
    }
    keep = set(chosen.values()) if a.only is None else {chosen[k] for k in a.only}
    found: dict[str, dict] = {}
    for label, policy in policies(run, env, keep):
        t0 = time.time()
        ro = env.rollout(policy, q0, qd0, aux, horizon=10.0, record_every=0.1)
        s = found[label] = summary(env.task_metrics(ro))
        print(
            f"{label:24s} {s['time']['mean']:5.2f}±{s['time']['std']:4.2f} {s['reached'] / len(q0):8.2f} "
            f"{s['cspace_length']:8.2f} {s['ee_length']:8.2f} {s['timeout_goal_distance']:9.3f} "
            f"{s['collisions']:10d} {s['close_passes']:6d} "
            f"{s['min_clearance']['least']:11.4f}/{s['min_clearance']['median']:.4f}   "
            f"({time.time() - t0:.0f} s)",
            flush=True,
        )
        if a.where_stopped:
            print("\n".join(stopped_short(env, ro, aux["goal"])), flush=True)
    env.close()
    if a.out is not None:
        command = "python tools/expert_design.py " + " ".join(shlex.quote(x) for x in (argv or sys.argv[1:]))
        atomic_write_json(
            a.out / "metrics.json",
            {
                "command": command,
                "seed": run.seed,
                "trajectories": a.trajectories,
                "rate": a.rate,
                "mode": a.mode,
                "policies": found,
                "timing": {"total_s": round(time.time() - started, 1)},
            },
        )
        print(f"written: {a.out / 'metrics.json'}")
    return 0


def summary(m: dict) -> dict:
    """One policy's numbers over the starts, as the table prints them (distances in m)."""
    return {
        "time": {"mean": float(m["time"].mean()), "std": float(m["time"].std())},
        "reached": int(m["reached"].sum()),
        "cspace_length": float(m["cspace_length"].mean()),
        "ee_length": float(m["ee_length"].mean()),
        "timeout_goal_distance": float(m["timeout_goal_distance"].mean()),
        "collisions": int(m["collided"].sum()),
        "close_passes": int(m["close_pass"].sum()),
        "min_clearance": {"least": float(m["min_clearance"].min()), "median": float(m["min_clearance"].median())},
    }


if __name__ == "__main__":
    sys.exit(main())
