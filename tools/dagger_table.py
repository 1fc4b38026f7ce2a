#!/usr/bin/env python
"""Behavior cloning against DAgger on 2d2level, for learner-rmp and learner-un, at equal expert queries.

Both runs are experiment=2d2level_unstructured without learner-un-large, seed 0, the same demonstrations and the
same 20,000 RMSprop steps (conf/train/bc_rmsprop.yaml). Behavior cloning trains on all 1,000 demonstrations (60,000
expert labels); DAgger (conf/train/dagger.yaml) on 500 of them, then 5 rounds that roll the learner out from 100
training starts and label 60 records of every rollout (30,000 labels more): 60,000 either way, counted by the runs
themselves (metrics.json "training").

    python tools/dagger_table.py                  # the paper's data sizes (~1 h on 2 shared cores)
    python tools/dagger_table.py --scale 0.1      # 10 % of the iterations and of the demonstrations per round
    python tools/dagger_table.py --table-only     # the table of the runs already in --out

Writes <out>/table.md and <out>/{bc,dagger}/ (each a run directory: metrics.json, figures, checkpoints).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from rmpfusion.pipeline.config import RunConfig
from rmpfusion.pipeline.run import run_experiment

METHODS = {"bc": "bc_rmsprop", "dagger": "dagger"}
LEARNERS = {"rmp": "learner-rmp", "un": "learner-un"}


def config(method: str, scale: float, seed: int, extra: list[str]) -> RunConfig:
    """experiment=2d2level_unstructured without learner-un-large, trained by ``method``, as composed from conf/."""
    from hydra import compose, initialize_config_dir

    from rmpfusion.cli import CONF_DIR
    from rmpfusion.pipeline.validate import resolve_and_validate

    it = max(30, round(20000 * scale))
    over = [
        "experiment=2d2level_unstructured",
        "~learners.un_large",
        f"train={METHODS[method]}",
        f"seed={seed}",
        "logger=disabled",
        f"train.iterations={it}",
        f"train.snapshots=[0,{it // 20},{it // 4},{it}]",
        f"train.checkpoint_every={max(1, it // 10)}",
        f"train.log_every={max(1, it // 100)}",
    ]
    if scale < 1:  # the same share of demonstrations for both methods: 1000·scale of them, half of them DAgger's
        n = max(2, round(50 * scale))
        over.append(f"data.train_trajectories={n}")
        if method == "dagger":
            over += [f"train.initial_trajectories={10 * n}", f"train.trajectories_per_round={2 * n}"]
    with initialize_config_dir(config_dir=CONF_DIR, version_base="1.3"):
        return resolve_and_validate(compose("config", overrides=over + list(extra)))


def _f(x, pct: bool = False) -> str:
    if x is None:
        return "–"
    return f"{100 * x:.0f} %" if pct else f"{x:.2g}"


def _lyapunov(r: dict) -> str:
    values = [s.get("lyapunov_monotone_fraction") for s in r["snapshots"].values()]
    if not values or values[0] is None:
        return "–"
    return f"{100 * min(values):.0f} % (every one of {len(values)} snapshots)"


def table(results: dict) -> str:
    """The table of ``results`` ({method: metrics}) and, below it, what DAgger's own rollouts did round by round."""
    rounds = round_lines(results)
    return markdown_table(results) + ("\n" + "\n".join(rounds) + "\n" if rounds else "")


def markdown_table(results: dict) -> str:
    """The markdown table alone (``tests/test_results.py`` regenerates the stored one with it)."""
    rows = [
        (
            "| learner | method | expert labels | expert calls while acting | validation loss | batch-loss "
            "| online-loss | online-loss, median | online-loss before first collision | success | collisions "
            "| V_r monotone | train s |"
        ),
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
        *reference_rows(next(iter(results.values()))),
    ]
    for key, name in LEARNERS.items():
        for method, m in results.items():
            r = m["learners"].get(key)
            if r is None:
                continue
            t = r.get("training", {})
            rows.append(
                f"| {name} | {method} | {t.get('expert_queries', '–')} | {t.get('expert_calls_in_rollouts', 0)} "
                f"| {_f(r.get('val_loss'))} | {_f(r['batch_loss'])} | {_f(r['online_loss'])} "
                f"| {_f(r.get('online_loss_median'))} | {_f(r.get('online_loss_before_collision'))} "
                f"| {_f(r['success'], True)} | {_f(r['collision'], True)} | {_lyapunov(r)} "
                f"| {r['train_seconds']:.0f} |"
            )
    return "\n".join(rows) + "\n"


def _untrained_row(label: str, r: dict, losses: bool) -> str:
    """A reference row: no labels, calls or training time; the losses against the expert where ``losses``."""
    val_batch = f"{_f(r.get('val_loss'))} | {_f(r['batch_loss'])}" if "batch_loss" in r else "– | –"
    online = (
        f"{_f(r['online_loss'])} | {_f(r.get('online_loss_median'))} | {_f(r.get('online_loss_before_collision'))}"
        if losses
        else "– | – | –"
    )
    return (
        f"| {label} | – | – | – | {val_batch} | {online} | {_f(r['success'], True)} | {_f(r['collision'], True)} "
        f"| {_f(r.get('lyapunov_monotone_fraction'), True)} | – |"
    )


def reference_rows(m: dict) -> list[str]:
    """What training starts from and aims at, from one run (both methods share the seed, so the same data, expert
    and initial learners): the expert (losses 0 by definition: not shown), the tree with every weight 1 (RMPflow)
    against the expert, and each learner at its random initialisation (snapshot 0)."""
    rows = [_untrained_row("expert", m["expert"], losses=False)]
    if "unit_weights" in m:
        rows.append(_untrained_row("unit weights (RMPflow)", m["unit_weights"], losses=True))
    for key, name in LEARNERS.items():
        s0 = m["learners"].get(key, {}).get("snapshots", {}).get("0")
        if s0 is not None:
            rows.append(_untrained_row(f"{name}-0 (untrained)", s0, losses=True))
    return rows


def round_lines(results: dict) -> list[str]:
    """Per learner, how often DAgger's own rollouts collided and reached the goal in each round."""
    rounds = []
    for key, name in LEARNERS.items():
        r = results.get("dagger", {}).get("learners", {}).get(key)
        if r is not None:
            per = r["training"]["rounds"][1:]
            rounds.append(
                f"- {name}, DAgger's own rollouts in rounds 1..{len(per)}: collided "
                + ", ".join(f"{100 * x['learner_collision_rate']:.0f} %" for x in per)
                + "; reached the goal "
                + ", ".join(f"{100 * x['learner_success_rate']:.0f} %" for x in per)
            )
    return rounds


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scale", type=float, default=1.0, help="fraction of the iterations and of the demonstrations")
    ap.add_argument("--out", type=Path, default=Path("outputs/dagger_table"))
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--only", choices=list(METHODS), nargs="*", default=list(METHODS))
    ap.add_argument("--table-only", action="store_true", help="run nothing: the table of <out>/<method>/metrics.json")
    ap.add_argument("overrides", nargs="*", help="further Hydra overrides for both runs")
    a = ap.parse_args(argv)
    if not 0 < a.scale <= 1:
        ap.error("--scale must be in (0, 1]")
    results, t0 = {}, time.time()
    for method in METHODS:
        path = a.out / method / "metrics.json"
        if a.table_only or method not in a.only:
            if path.exists():
                results[method] = json.loads(path.read_text())
            continue
        results[method] = run_experiment(config(method, a.scale, a.seed, a.overrides), a.out / method)
    md = (
        f"# 2d2level: behavior cloning vs DAgger at equal expert labels (scale {a.scale}, seed {a.seed}, "
        f"{time.time() - t0:.0f} s)\n\n" + table(results)
    )
    a.out.mkdir(parents=True, exist_ok=True)
    (a.out / "table.md").write_text(md)
    print(md)
    return 0


if __name__ == "__main__":
    sys.exit(main())
