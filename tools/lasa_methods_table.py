#!/usr/bin/env python
"""How the training methods compare on LASA shapes: every snapshot of each run (learner-0, the behavior-cloning
iterate, the trajectory-matching iterate), validation first, from the runs' metrics.json.

    python tools/lasa_methods_table.py "bc (mse)=outputs/a/metrics.json" "match=outputs/b/metrics.json"

One row per run and snapshot: the validation and test DTW per sample (mm), the test swept area and final distance,
the fraction of the 100 starts at rest that converged, V_r monotone on them, and the run's training time. The
validation column is the one settings are chosen on; the test columns are reported, never chosen on.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from compare_metrics import read_labelled_runs

HEADER = (
    "| run | shape | iteration | validation DTW (mm) | test DTW (mm) | test swept area (mm²) | test final distance (mm) "
    "| converged | V_r monotone | train s |"
)


def _shape(m: dict) -> str:
    return m["name"].removeprefix("lasa_")  # experiment=lasa names its runs lasa_<shape>


def _row(label: str, shape: str, iteration: str, r: dict, seconds: str) -> str:
    val, test, conv = r["reproduction_val"], r["reproduction_test"], r["convergence"]
    cells = [
        label,
        shape,
        iteration,
        f"{1e3 * val['dtw']:.2f}",
        f"{1e3 * test['dtw']:.2f}",
        f"{1e6 * test['swept_error_area']:.0f}",
        f"{1e3 * test['final_distance']:.2f}",
        f"{conv['converged']:.2f}",
        f"{conv['lyapunov_monotone_fraction']:.2f}",
        seconds,
    ]
    return "| " + " | ".join(cells) + " |"


def _rows(label: str, m: dict) -> list[str]:
    learner = next(iter(m["learners"].values()))
    snapshots = sorted(learner["snapshots"].items(), key=lambda kv: int(kv[0]))
    last = snapshots[-1][0]
    return [
        _row(label, _shape(m), it, r, f"{learner['train_seconds']:.0f}" if it == last else "–") for it, r in snapshots
    ]


def table(runs: dict[str, dict]) -> str:
    """The table of runs labelled by what they trained with, in the given order; before each shape's first run, the
    configured tree with every weight 1 (its untrained map; nothing learned) from that run."""
    lines = [HEADER, "|" + "---|" * HEADER.count(" | ") + "---|"]
    shown = set()
    for label, m in runs.items():
        if _shape(m) not in shown and "tree" in m:
            shown.add(_shape(m))
            lines.append(_row("tree (every weight 1)", _shape(m), "–", m["tree"], "–"))
        lines += _rows(label, m)
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("runs", nargs="+", help="LABEL=PATH: a run's metrics.json (or its directory) and its row label")
    args = ap.parse_args(argv)
    print(table(read_labelled_runs(ap, args.runs)), end="")
    return 0


if __name__ == "__main__":
    sys.exit(main())
