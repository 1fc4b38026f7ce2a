"""How the training methods compare on LASA shapes: every snapshot of each run (learner-0, the behavior-cloning
iterate, the trajectory-matching iterate), validation first, from the runs' metrics.json.
"""

from __future__ import annotations

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
