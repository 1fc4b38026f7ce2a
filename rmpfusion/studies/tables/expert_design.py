"""The expert-design table of the reach experiment, one block of rows per robot, from the metrics.json files
``tools/expert_design.py --out DIR`` writes:
"""

from __future__ import annotations

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
