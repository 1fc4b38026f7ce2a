#!/usr/bin/env python
"""A learned motion meets an obstacle it never saw: a finished ``experiment=lasa`` run's tree, a disc put on a held-out
demonstration's path, and the same tree with one obstacle leaf more rolled out beside it.

A stable first-order learner (SEDS, Euclideanizing flows) must be trained again to avoid anything. A tree takes a leaf:
the disc's distance (``sphere_distance`` reading the aux entries ``obstacle1_center`` and ``obstacle1_radius``, so the
disc's place is run-time state, not a constant) under the barrier leaf ``collision_avoidance``, pulled back beside the
learned flow by pullback* (Theorem 2 still holds); nothing of the trained tree changes. Where the barrier is out of
reach (its support ``r_w`` beyond the disc's surface) the tree is the trained one exactly, so the demonstrated motion is
kept wherever the obstacle is not in the way.

    python tools/unseen_obstacle.py --out <dir> data.shape=GShape      # trains experiment=lasa into <dir>/run first
    python tools/unseen_obstacle.py --run <run dir> --out <dir>         # a finished experiment=lasa run instead

The disc sits at the middle of the held-out (test) demonstration by default (``--fraction``).

Measured, with and without the disc, from the test demonstration's start and from the run's starts at rest (those
beyond the barrier's reach): DTW to the demonstration, how far the path departs from it (the largest distance of a
rollout point to the demonstrated path, over the whole rollout and over its points beyond the barrier's reach: the
disc's radius and the barrier's support from its centre), the least clearance to the disc, collisions, and
convergence (within the run's tolerance at 3 and at 10 times the longest demonstration). Writes ``metrics.json`` and ``unseen_obstacle.png`` into ``--out``.
"""

from __future__ import annotations

import argparse
import copy
import json
import subprocess
import sys
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch
from matplotlib.patches import Circle

from rmpfusion.evaluate.reproduction import dtw_distance, pairwise_distances
from rmpfusion.files import atomic_write_json
from rmpfusion.pipeline.finished import finished_run
from rmpfusion.pipeline.recorded import convergence_starts
from rmpfusion.plots.figures import save_figure, subplots

#: the obstacle's leaf: RMPflow's barrier, in the tree's normalised units (``normalize`` of conf/tree/lasa_flow.yaml:
#: 0.02 m), where the leaves' numbers are made for coordinates of order one: RMPflow's gating (σ 0.5, ε 0.2, no
#: damping) and the potential gain of the arm trees' obstacle barrier (conf/tree/arm_reach.yaml: α 0.01; RMPflow's
#: 1e-5 leaves the approach braked by the velocity-gated metric alone, which lets a fast motion reach the disc's
#: surface). The support of half a unit (1 cm from the disc) is ours; none of these was tuned on LASA rollouts.
BARRIER = {"type": "collision_avoidance", "r_w": 0.5, "sigma": 0.5, "epsilon": 0.2, "alpha": 1e-2, "eta": 0.0}


def normalising_scale(tree_spec: dict) -> float:
    """The scale of the tree's ``normalize`` map: the length that is one unit for its leaves."""
    scales = [n["map"]["scale"] for n in tree_spec["nodes"].values() if n.get("map", {}).get("type") == "normalize"]
    if len(scales) != 1 or not isinstance(scales[0], int | float):
        raise SystemExit("the run's tree has no single normalize map with one scale; this tool reads experiment=lasa's")
    return float(scales[0])


def with_disc(tree_spec: dict, barrier: dict) -> dict:
    """The tree spec with the disc's leaf beside its others: the root's distance to the disc's surface, in the tree's
    normalised units, under the barrier."""
    spec = copy.deepcopy(tree_spec)
    spec["nodes"]["unseen_obstacle_distance"] = {
        "parent": spec["root"]["name"],
        "map": {"type": "sphere_distance", "center": "obstacle1_center", "radius": "obstacle1_radius"},
    }
    spec["nodes"]["unseen_obstacle"] = {
        "parent": "unseen_obstacle_distance",
        "map": {"type": "normalize", "scale": normalising_scale(tree_spec)},
        "rmp": dict(barrier),
    }
    return spec


def on_path(demo: np.ndarray, fraction: float) -> np.ndarray:
    """The point ``fraction`` of the way along the path ``demo`` (T, 2), by arc length."""
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(demo, axis=0), axis=-1))])
    k = int(np.searchsorted(s, fraction * s[-1]))
    return demo[min(k, len(demo) - 1)]


def departure(path: np.ndarray, demo: np.ndarray, centre: np.ndarray, reach: float) -> dict:
    """The largest distance of a point of ``path`` to the demonstrated path: everywhere, and away from the disc."""
    d = pairwise_distances(path, demo).min(1)
    away = np.linalg.norm(path - centre, axis=-1) > reach
    return {"max": float(d.max()), "max_away_from_obstacle": float(d[away].max()) if away.any() else 0.0}


def _rollout(exp, tree, q0, qd0, goal, disc, horizon):
    n = q0.shape[0]
    aux = {"goal": goal.expand(n, -1).clone()}
    aux.update({"obstacle1_center": disc[0].expand(n, -1).clone(), "obstacle1_radius": disc[1].expand(n, 1).clone()})
    return exp.env.rollout(tree, q0, qd0, aux, horizon, exp.env.dt)


def measure(exp, trees, demo, goal, disc, starts, horizons, reach: float) -> dict:
    """Each tree's rollouts from the demonstration's start and the starts at rest, measured."""
    centre = disc[0][0].numpy()
    q0 = torch.cat([torch.as_tensor(demo.q[:1]), starts])
    qd0 = torch.cat([torch.as_tensor(demo.qd[:1]), torch.zeros_like(starts)])
    out, paths = {}, {}
    for name, tree in trees.items():
        ro = _rollout(exp, tree, q0, qd0, goal, disc, horizons[-1])
        at = [round(h / exp.env.dt) for h in horizons]
        dist = ro.goal_distance
        path = ro.q[:, 0].numpy()
        tol = exp.recorded_data.tolerance
        out[name] = {
            "dtw": dtw_distance(path[: len(demo.t)], demo.q),
            "departure": departure(path, demo.q, centre, reach),
            "min_clearance": float(ro.min_clearance[0]),
            "collided": bool(ro.collided[0]),
            "final_distance": float(dist[at[0], 0]),
            "starts": int(starts.shape[0]),
            "starts_min_clearance": float(ro.min_clearance[1:].min()),
            "starts_collided": int(ro.collided[1:].sum()),
            **{f"converged_at_{f:g}x": float((dist[a, 1:] <= tol).double().mean()) for f, a in zip((3, 10), at)},
        }
        paths[name] = ro.q.numpy()
    return {"measures": out, "paths": paths}


def figure(out: Path, demos, demo, disc, paths, horizon_steps: int) -> Path:
    """Side by side, the trained tree and the tree with the disc: the demonstrations (grey), the test one (orange),
    the rollout from its start (red), those from the starts at rest (thin), the disc (blue, dashed where the policy
    does not know it), zoomed to the demonstrations' box."""
    fig, axes = subplots(1, len(paths), figsize=(5.0 * len(paths), 4.6))
    centre, radius = disc[0][0].numpy(), float(disc[1])
    q = np.concatenate([s.q for s in demos])
    lo, hi = q.min(0), q.max(0)
    pad = 0.25 * (hi - lo).max()
    for ax, (name, p) in zip(np.atleast_1d(axes), paths.items()):
        for b in range(1, p.shape[1]):
            ax.plot(p[:horizon_steps, b, 0], p[:horizon_steps, b, 1], color="0.35", lw=0.4, zorder=1)
        for s in demos:
            ax.plot(s.q[:, 0], s.q[:, 1], color="0.7", lw=3, zorder=2)
        ax.plot(demo.q[:, 0], demo.q[:, 1], color="tab:orange", lw=3, zorder=3, label="test demonstration")
        ax.plot(p[:horizon_steps, 0, 0], p[:horizon_steps, 0, 1], "r--", lw=2, zorder=4, label="rollout from its start")
        known = "disc" in name
        ax.add_patch(
            Circle(
                centre,
                radius,
                facecolor="tab:blue" if known else "none",
                edgecolor="tab:blue",
                alpha=0.6,
                ls="-" if known else "--",
                lw=1.5,
                zorder=5,
                label="the disc" if known else "the disc (not in the tree)",
            )
        )
        ax.plot(*demo.goal, "k*", ms=12, zorder=6)
        ax.set_xlim(lo[0] - pad, hi[0] + pad)
        ax.set_ylim(lo[1] - pad, hi[1] + pad)
        ax.set_title(name)
        ax.set_aspect("equal")
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
        ax.legend(fontsize=7, loc="best")
    return save_figure(fig, out / "unseen_obstacle.png")


def counting_the_disc(config: dict) -> dict:
    """The run config whose plane counts collisions with one disc (aux obstacle1_center, obstacle1_radius)."""
    return {**config, "env": {**config["env"], "n_obstacles": 1}}


def with_the_disc(config: dict) -> dict:
    """The run config counting the disc, its tree with the disc's leaf."""
    config = counting_the_disc(config)
    return {**config, "tree": with_disc(config["tree"], BARRIER)}


def run(run_dir: Path, out: Path, fraction: float, radius: float, learner: str = "rmp") -> dict:
    """The disc on ``run_dir``'s test demonstration, both trees measured; metrics.json and the figure into ``out``.
    Its timing adds this measurement's seconds to the run's own (training and evaluation)."""
    started = time.perf_counter()
    with finished_run(run_dir, learner, counting_the_disc) as plain:
        exp, demos, every, trained = plain.exp, plain.demos, plain.every, plain.model.tree
    with finished_run(run_dir, learner, with_the_disc, new_nodes=("unseen_obstacle",)) as disc_run:
        tree = disc_run.model.tree
    if not demos.get("test"):
        raise SystemExit(
            f"{run_dir}: the run holds no test demonstration to put the disc on (data.split=all?); train with a "
            "held-out split (experiment=lasa's default)"
        )
    demo = demos["test"][0]
    goal = torch.as_tensor(demo.goal)[None]
    disc = (torch.as_tensor(on_path(demo.q, fraction))[None], torch.tensor([[radius]], dtype=torch.float64))
    grid = torch.as_tensor(convergence_starts(exp.env, every, exp.recorded_data, exp.run.seed))
    support = BARRIER["r_w"] * normalising_scale(
        exp.run.tree.model_dump()
    )  # the barrier's reach from the disc, in metres
    starts = grid[(grid - disc[0]).norm(dim=-1) > radius + support]
    longest = max(float(s.t[-1]) for s in every)
    horizons = [exp.env.dt * round(f * longest / exp.env.dt) for f in (3.0, 10.0)]
    found = measure(
        exp,
        {"trained tree": trained, "with the unseen disc": tree},
        demo,
        goal,
        disc,
        starts,
        horizons,
        radius + support,
    )
    run_s = float(json.loads((run_dir / "metrics.json").read_text())["timing"]["total_s"])
    metrics = {
        "run": str(run_dir),
        "seed": exp.run.seed,
        "demonstration": demo.source,
        "disc": {"center": disc[0][0].tolist(), "radius": radius, "fraction_along_path": fraction},
        "barrier": BARRIER,
        "barrier_reach": radius + support,
        **found["measures"],
    }
    out.mkdir(parents=True, exist_ok=True)
    metrics["figure"] = str(figure(out, every, demo, disc, found["paths"], round(horizons[0] / exp.env.dt) + 1))
    measure_s = time.perf_counter() - started
    metrics["timing"] = {"run_s": run_s, "measure_s": measure_s, "total_s": run_s + measure_s}
    atomic_write_json(out / "metrics.json", metrics)
    return metrics


def trained_run(out: Path, overrides: Sequence[str]) -> Path:
    """``experiment=lasa`` with ``overrides`` trained and evaluated into ``out/run``, or the run already there."""
    run_dir = out / "run"
    if (run_dir / "checkpoints" / "rmp" / "final.pt").is_file() and (run_dir / "metrics.json").is_file():
        return run_dir
    command = [sys.executable, "-m", "rmpfusion.cli.run", "experiment=lasa", *overrides]
    subprocess.run([*command, "logger=disabled", f"hydra.run.dir={run_dir}"], check=True)
    return run_dir


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("overrides", nargs="*", help="experiment=lasa overrides of the run trained first (no --run)")
    ap.add_argument("--run", type=Path, help="a finished experiment=lasa run (default: train one into OUT/run)")
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--fraction", type=float, default=0.5, help="where along the test demonstration the disc sits")
    ap.add_argument("--radius", type=float, default=0.004, help="the disc's radius (m)")
    a = ap.parse_args(argv)
    if a.run is not None and a.overrides:
        ap.error(f"--run names a finished run; the overrides {a.overrides} would be ignored: give one or the other")
    if a.run is not None and not (a.run / "checkpoints" / "rmp" / "final.pt").is_file():
        print(f"{a.run}: no checkpoints/rmp/final.pt; give a finished experiment=lasa run", file=sys.stderr)
        return 1
    try:
        run_dir = a.run if a.run is not None else trained_run(a.out, a.overrides)
    except subprocess.CalledProcessError as e:
        print(f"the experiment=lasa run failed (exit {e.returncode}); see its messages above", file=sys.stderr)
        return 1
    m = run(run_dir, a.out, a.fraction, a.radius)
    for name in ("trained tree", "with the unseen disc"):
        r = m[name]
        print(
            f"{name}: DTW {1e3 * r['dtw']:.2f} mm, departs {1e3 * r['departure']['max']:.2f} mm "
            f"({1e3 * r['departure']['max_away_from_obstacle']:.2f} mm away from the disc), clearance "
            f"{1e3 * r['min_clearance']:.2f} mm, collided {r['collided']}; {r['starts']} starts at rest: "
            f"converged {r['converged_at_3x']:.0%} at 3x, {r['converged_at_10x']:.0%} at 10x, "
            f"{r['starts_collided']} collided, least clearance {1e3 * r['starts_min_clearance']:.2f} mm"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
