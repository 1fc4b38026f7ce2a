#!/usr/bin/env python
"""The expert-design table of the reach experiment, one block of rows per robot, from the metrics.json files
``tools/expert_design.py --out DIR`` writes:

    python tools/expert_design_table.py panda=results/reach_expert_design/panda ur5=results/reach_expert_design/ur5

Per policy (the expert, unit weights (RMPflow), the expert's attractor with unit obstacle weights, learner-0) over the
validation starts: reached, time to 0.05 m (mean ± std), the goal distance at the 10 s time-out (m), collisions, close
passes (within 10 mm, no collision) and each rollout's closest approach of any link to an obstacle, least / median
over the starts (cm).
"""

from __future__ import annotations

import argparse
import sys

from compare_metrics import read_labelled_runs

HEADER = (
    "| robot | policy | reached | time (s) | goal distance at 10 s (m) | collisions | close passes | clearance (cm) |\n"
    "|---|---|---|---|---|---|---|---|\n"
)
#: a policy's row label, by the name expert_design.py stores it under
LABELS = {
    "expert": "expert",
    "unit weights (RMPflow)": "unit weights",
    "unit obstacle weights": "unit obstacle weights",
    "learner-0": "learner-0",
}


def _cm(x: float) -> str:
    """Two significant digits, a true minus sign: a clearance below zero is a penetration."""
    return f"{100.0 * x:.2g}".replace("-", "−")


def rows(robot: str, metrics: dict) -> list[str]:
    n = metrics["trajectories"]
    out = []
    for name, p in metrics["policies"].items():
        c = p["min_clearance"]
        out.append(
            f"| {robot} | {LABELS.get(name, name)} | {p['reached']} / {n} | {p['time']['mean']:.2f} ± "
            f"{p['time']['std']:.2f} | {p['timeout_goal_distance']:.3f} | {p['collisions']} | {p['close_passes']} | "
            f"{_cm(c['least'])} / {_cm(c['median'])} |"
        )
    return out


def table(runs: dict[str, dict]) -> str:
    """The markdown table of ``{robot: metrics}`` (rows in the order given)."""
    return HEADER + "".join(line + "\n" for robot, m in runs.items() for line in rows(robot, m))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("runs", nargs="+", help="ROBOT=DIR (DIR/metrics.json from expert_design.py --out DIR)")
    a = ap.parse_args(argv)
    print(table(read_labelled_runs(ap, a.runs, form="ROBOT=DIR")), end="")
    return 0


if __name__ == "__main__":
    sys.exit(main())
