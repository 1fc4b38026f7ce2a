#!/usr/bin/env python
"""Reproduce the paper's 2D table (§4.1, App. D.1): 2d1level learner-rmp; 2d2level learner-rmp, learner-un,
learner-un-large. Writes <out>/table.md with our numbers beside the paper's, plus each run's directory.

    python tools/reproduce_2d.py                 # the paper protocol (20x50x60 demos, 20k iterations)
    python tools/reproduce_2d.py --scale 0.1     # 10% of the trajectories per env and of the iterations
    python tools/reproduce_2d.py --only 2d2level_per_edge   # one experiment
    python tools/reproduce_2d.py --only 2d1level_hard_test 2d2level_hard_test   # the harder test splits (ours)
    python tools/reproduce_2d.py --table-only --out results # the README's table from the stored runs

Each experiment's rows: the expert, the same tree with unit weights (RMPflow), learner-rmp before training (the
paper's learner-0), then every learner trained. 2d2level_per_edge (ours, not in the paper) is learner-rmp with each
weight reading only its own edge's aux; *_hard_test (ours) train as the paper does and test on starts that are
harder to get right (conf/experiment/2d1level_hard_test.yaml says how, and how it was chosen).
The validation loss (5 × 10 trajectories in environments drawn like the training ones) is the one settings are
chosen on; the test losses are only reported.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from rmpfusion.pipeline.config import RunConfig
from rmpfusion.pipeline.run import run_experiment

PAPER = {  # (experiment, learner): batch, online, success, collision   (None = not reported)
    ("2d1level", "learner-rmp"): (5.42e-5, 5.82e-5, None, None),
    ("2d2level", "learner-rmp"): (2.45e-4, 2.78e-4, 1.00, None),
    ("2d2level", "learner-un"): (0.111, 12.203, 0.00, 0.28),
    ("2d2level", "learner-un-large"): (0.065, 0.393, 0.00, 0.16),
    ("2d2level_per_edge", "learner-rmp"): (None, None, None, None),
}


LEARNER_NAMES = {"rmp": "learner-rmp", "un": "learner-un", "un_large": "learner-un-large"}
# table row -> conf/experiment
EXPERIMENTS = {
    "2d1level": "2d1level",
    "2d2level": "2d2level_unstructured",
    "2d2level_per_edge": "2d2level_per_edge",
    "2d1level_hard_test": "2d1level_hard_test",
    "2d2level_hard_test": "2d2level_hard_test",
}
#: the paper's table; the harder test splits (ours) are run with --only
PAPER_EXPERIMENTS = ("2d1level", "2d2level", "2d2level_per_edge")
HEADER = (
    "| experiment | policy | parameters | validation loss | batch-loss (ours / paper) | online-loss (ours / paper) "
    "| online-loss, median over trajectories | online-loss before first collision | success (ours / paper) "
    "| collisions (ours / paper) | time to 0.1 (s) | closest approach to an obstacle | V_r monotone |"
)


def config(exp: str, scale: float, seed: int, lr: float | None, cache: str | None, extra: list[str]) -> RunConfig:
    """The paper experiment as composed from conf/ (the same YAML `rmpfusion-run experiment=...` uses)."""
    from hydra import compose, initialize_config_dir

    from rmpfusion.cli import CONF_DIR
    from rmpfusion.pipeline.validate import resolve_and_validate

    it = max(10, round(20000 * scale))
    snaps = sorted({0, it // 20, it // 4, it})
    over = [
        f"experiment={EXPERIMENTS[exp]}",
        f"seed={seed}",
        "logger=disabled",
        f"data.train_trajectories={max(1, round(50 * scale))}",
        f"train.iterations={it}",
        f"train.snapshots=[{','.join(map(str, snaps))}]",
        f"train.checkpoint_every={max(1, it // 10)}",
        f"train.log_every={max(1, it // 100)}",
    ]
    if lr is not None:
        over.append(f"train.lr={lr}")
    if cache:
        over.append(f"data.cache_dir={cache}")
    with initialize_config_dir(config_dir=CONF_DIR, version_base="1.3"):
        return resolve_and_validate(compose("config", overrides=over + list(extra)))


def number(x) -> str:
    """Two significant digits, in scientific notation below 1e-3 and from 1e3 on: 3.2e-6, 0.27, 2.8e9; – when
    absent."""
    if x is None:
        return "–"
    if x != 0 and not 1e-3 <= abs(x) < 1e3:
        mantissa, exponent = f"{x:.1e}".split("e")
        return f"{mantissa}e{int(exponent)}"
    return f"{x:.2g}"


def paper_number(x) -> str:
    """A number the paper prints, with its three digits: 5.42e-5, 0.111, 12.2."""
    mantissa, _, exponent = f"{x:.3g}".partition("e")
    return f"{mantissa}e{int(exponent)}" if exponent else mantissa


def _task(m: dict, key: str, stat: str, digits: int = 2) -> str:
    """A statistic of the environment's per-trajectory task metric ``key`` over the test rollouts."""
    x = ((m.get("task") or {}).get(key) or {}).get(stat)
    return f"{x:.{digits}g}" if x is not None and 1e-3 <= abs(x) < 1e3 else number(x)


def percent(x) -> str:
    return "–" if x is None else f"{100 * x:.0f} %"


def _ours_paper(ours: str, paper: str | None) -> str:
    return ours if paper is None else f"{ours} / {paper}"


def _monotone(fractions: list) -> str:
    """The Lyapunov monitor's fraction of monotone rollouts: the worst over the snapshots given."""
    fractions = [f for f in fractions if f is not None]
    if not fractions:
        return "–"
    return percent(min(fractions)) + (f" (every one of {len(fractions)} snapshots)" if len(fractions) > 1 else "")


def _policy_row(
    exp: str, policy: str, m: dict, parameters="–", val=None, batch=None, paper=(None,) * 4, monotone: str | None = None
) -> str:
    given = [None if p is None else (percent(p) if i >= 2 else paper_number(p)) for i, p in enumerate(paper)]
    cells = [
        exp,
        policy,
        str(parameters),
        number(val),
        _ours_paper(number(batch), given[0]),
        _ours_paper(number(m.get("online_loss")), given[1]),
        number(m.get("online_loss_median")),
        number(m.get("online_loss_before_collision")),
        _ours_paper(percent(m.get("success")), given[2]),
        _ours_paper(percent(m.get("collision")), given[3]),
        _task(m, "time", "mean", digits=3),
        _task(m, "min_clearance", "min"),
        monotone if monotone is not None else _monotone([m.get("lyapunov_monotone_fraction")]),
    ]
    return "| " + " | ".join(cells) + " |"


def rows(exp: str, metrics: dict) -> list[str]:
    """The rows of one experiment: the expert, the same tree with unit weights (RMPflow) when the run evaluated
    it, learner-rmp untrained (snapshot 0, the paper's learner-0), then every learner trained."""
    out = [_policy_row(exp, "expert", metrics["expert"])]
    if "unit_weights" in metrics:
        out.append(_policy_row(exp, "unit weights (RMPflow)", metrics["unit_weights"]))
    learners = {LEARNER_NAMES.get(k, k): v for k, v in metrics["learners"].items()}
    rmp = learners.get("learner-rmp")
    if rmp is not None and "0" in rmp["snapshots"]:
        s0 = rmp["snapshots"]["0"]
        out.append(
            _policy_row(
                exp, "learner-rmp @ 0 (learner-0)", s0, rmp["num_parameters"], s0.get("val_loss"), s0.get("batch_loss")
            )
        )
    for name, r in learners.items():
        paper = PAPER.get((exp, name), (None,) * 4)
        monotone = _monotone([s.get("lyapunov_monotone_fraction") for s in r["snapshots"].values()])
        out.append(
            _policy_row(exp, name, r, r["num_parameters"], r.get("val_loss"), r.get("batch_loss"), paper, monotone)
        )
    return out


def table(results: dict) -> str:
    """The README's table of the runs in ``results`` ({table row: metrics.json}), in the order given."""
    lines = [HEADER, "|" + "---|" * (HEADER.count("|") - 1)]
    for exp, metrics in results.items():
        lines += rows(exp, metrics)
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scale", type=float, default=1.0, help="fraction of trajectories per env and of iterations")
    ap.add_argument("--out", type=Path, default=Path("outputs/reproduce_2d"))
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument(
        "--only",
        choices=list(EXPERIMENTS),
        nargs="*",
        default=list(PAPER_EXPERIMENTS),
        help="these experiments (default: the paper's three; *_hard_test are ours)",
    )
    ap.add_argument("--lr", type=float, default=None, help="override train.lr (default: conf/train/bc_rmsprop.yaml)")
    ap.add_argument("overrides", nargs="*", help="further Hydra overrides, e.g. weights@learners.rmp.weights=mlp_small")
    ap.add_argument("--cache", default=None, help="shared dataset cache directory")
    ap.add_argument(
        "--table-only",
        action="store_true",
        help="run nothing: write the table from the metrics.json already in <out>/<experiment>/",
    )
    a = ap.parse_args(argv)
    if not 0 < a.scale <= 1:
        ap.error("--scale must be in (0, 1]")
    results = {}
    t0 = time.time()
    for exp in a.only:
        if a.table_only:
            if (a.out / exp / "metrics.json").exists():
                results[exp] = json.loads((a.out / exp / "metrics.json").read_text())
            continue
        results[exp] = run_experiment(config(exp, a.scale, a.seed, a.lr, a.cache, a.overrides), a.out / exp)
    md = f"# 2D experiments (scale {a.scale}, seed {a.seed}, {time.time() - t0:.0f} s)\n\n" + table(results)
    a.out.mkdir(parents=True, exist_ok=True)
    (a.out / "table.md").write_text(md)
    (a.out / "results.json").write_text(json.dumps(results, indent=1, default=str))
    print(md)
    return 0


if __name__ == "__main__":
    sys.exit(main())
