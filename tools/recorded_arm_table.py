#!/usr/bin/env python
"""The table of an arm run on joint-space recordings (``experiment=recorded_arm``) from its metrics.json.

    python tools/recorded_arm_table.py outputs/recorded_arm/<time>/metrics.json

One row per policy (the configured tree with every weight 1, then learner-rmp at every snapshot): on the held-out
test and validation recordings, from each one's first state, the DTW per sample of the joint path (rad) and of the
end-effector path (m), the end effector's distance to the goal after the horizon, how many came within the tolerance
(test and validation) and how many collided; from the starts at rest in the recordings' enlarged joint box, how many
converged, came to rest short of the goal (and which leaves hold them there), collided, and kept V_r
non-increasing; the final learner's certificate and training time.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

HEADER = (
    "| run | policy | test DTW (rad) | test end-effector DTW (mm) | test final distance (mm) | test reached "
    "| test collisions | validation end-effector DTW (mm) | validation reached | starts converged "
    "| starts stopped short (held by) "
    "| starts collided | V_r monotone | certificate | train s |"
)


def _policies(m: dict) -> list[tuple[str, dict]]:
    """(row name, results) of the reference tree and of every learner snapshot; the last snapshot carries the
    learner's training time (its certificate is in the snapshot's own results)."""
    out = [("tree (every weight 1)", m["tree"])]
    for name, r in m["learners"].items():
        last = max(r["snapshots"], key=int)
        for it, snap in sorted(r["snapshots"].items(), key=lambda kv: int(kv[0])):
            timing = {"train_seconds": r["train_seconds"]} if it == last else {}
            out.append((f"learner-{name}-{it}", {**snap, **timing}))
    return out


def _row(label: str, policy: str, r: dict) -> str:
    test, val, conv = r["reproduction_test"], r.get("reproduction_val") or {}, r["convergence"]
    n_test, n_val = len(test["per_demonstration"]), len(val.get("per_demonstration", []))
    n = conv["starts"]
    cert = r.get("certificate")
    cells = [
        label,
        policy,
        f"{test['dtw']:.3f}",
        f"{1000 * test['ee_dtw']:.1f}",
        f"{1000 * test['final_distance']:.1f}",
        f"{round(test['reached'] * n_test)} / {n_test}",
        f"{test['collisions']} / {n_test}",
        f"{1000 * val['ee_dtw']:.1f}" if "ee_dtw" in val else "–",
        f"{round(val['reached'] * n_val)} / {n_val}" if n_val else "–",
        f"{round(conv['converged'] * n)} / {n}",
        _stopped_short(conv),
        f"{conv['collisions']} / {n}",
        f"{round(conv['lyapunov_monotone_fraction'] * n)} / {n}" if "lyapunov_monotone_fraction" in conv else "–",
        "–" if cert is None else ("ok" if cert["ok"] else "FAILS"),
        f"{r['train_seconds']:.0f}" if "train_seconds" in r else "–",
    ]
    return "| " + " | ".join(cells) + " |"


def _stopped_short(conv: dict) -> str:
    """How many starts came to rest away from the goal, and the two leaves whose forces hold most of them there
    (``convergence.held_by``; runs made before it was measured have none)."""
    held = list(conv.get("held_by") or {})[:2]
    return f"{conv['stalled_count']} / {conv['starts']}" + (f" ({', '.join(held)})" if held else "")


def table(runs: dict[str, dict]) -> str:
    """The markdown table of runs given as {label: metrics} (``tests/test_results.py`` regenerates the stored one)."""
    lines = [HEADER, "|" + "---|" * (HEADER.count("|") - 1)]
    for label, m in runs.items():
        lines += [_row(label, policy, r) for policy, r in _policies(m)]
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("metrics", nargs="+", type=Path, help="metrics.json of a recorded_arm run")
    a = ap.parse_args(argv)
    runs = {json.loads(p.read_text())["name"]: json.loads(p.read_text()) for p in a.metrics}
    print(table(runs), end="")
    return 0


if __name__ == "__main__":
    sys.exit(main())
