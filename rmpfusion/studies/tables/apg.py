"""The table of policy optimisation through the simulator (APG): the rows ``tools/apg_rows.py`` stores, one per
policy (the expert, unit weights, every snapshot of the optimised learner), with V_r checked at the run's step and a finer
one.
"""

from __future__ import annotations


def _f(x, pct: bool = False) -> str:
    if x is None:
        return "–"
    return f"{100 * x:.0f} %" if pct else f"{x:.3g}"


def table(rs: list[dict], dt: float, fine_dt: float) -> str:
    """The Markdown table of the rows ``rs``; a run that learns leaf numbers gets a column of them."""
    leaves = any(r.get("leaves") for r in rs)
    head = (
        "| policy | task cost (APG's, test starts) | success | collisions | time to 0.1 (s) | path length "
        f"| final distance | closest approach to an obstacle | V_r monotone (RK4 at {dt} s) "
        f"| V_r monotone (RK4 at {fine_dt} s) |" + (" learned leaf numbers |" if leaves else "")
    )
    lines = [head, "|---" * (head.count("|") - 1) + "|"]
    for r in rs:
        learned = ", ".join(f"{k} = {v:.3g}" for k, v in (r.get("leaves") or {}).items()) or "–"
        lines.append(
            f"| {r['policy']} | {_f(r['cost'])} | {_f(r['success'], True)} | {_f(r['collision'], True)} "
            f"| {_f(r.get('time'))} | {_f(r.get('path_length'))} | {_f(r.get('final_distance'))} "
            f"| {_f(r.get('min_clearance'))} | {_f(r['lyapunov'], True)} | {_f(r['lyapunov_fine'], True)} |"
            + (f" {learned} |" if leaves else "")
        )
    return "\n".join(lines) + "\n"


def table_of(runs: dict[str, dict]) -> str:
    """The table of the (one) stored run in ``runs`` ({label: the metrics.json this tool wrote})."""
    (m,) = runs.values()
    return table(m["rows"], m["dt"], m["fine_dt"])
