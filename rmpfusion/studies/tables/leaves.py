"""The learnable-leaves table: a run whose learner learns leaf parameters (e.g. experiment=2d1level
learned_leaves=2d1level) as one row per snapshot: the learned goal gain, goal damping and obstacle support,
batch-loss, success and the Lyapunov monitor, from its metrics.json; above them the expert and its tree with every
weight 1 (RMPflow) on the same starts.
"""

from __future__ import annotations

#: (column, the learned parameter's name in metrics.json)
COLUMNS = (("goal gain", "goal.gain"), ("goal damping η", "goal.eta"), ("obstacle support r_w", "obstacle.r_w"))


def _learned(snapshot: dict, name: str) -> str:
    value = snapshot.get("learned_leaf_parameters", {}).get(name)
    return "–" if value is None else f"{value:.3g}" if abs(value) < 1 else f"{value:.4g}"


def table(runs: dict[str, dict], learner: str = "rmp") -> str:
    """The Markdown table of the (one) run in ``runs`` ({label: metrics}), one row per snapshot of ``learner``."""
    (metrics,) = runs.values()
    snapshots = metrics["learners"][learner]["snapshots"]
    header = ["snapshot", *(c for c, _ in COLUMNS), "batch-loss", "success", "V_r monotone"]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for label, key in (("expert", "expert"), ("unit weights (RMPflow)", "unit_weights")):
        if key in metrics:  # the expert's tree and leaves, its weights as designed or all 1: nothing learned
            r = metrics[key]
            cells = [label, *("–" for _ in COLUMNS), "–", f"{100 * r['success']:.0f} %"]
            lines.append("| " + " | ".join([*cells, f"{100 * r['lyapunov_monotone_fraction']:.0f} %"]) + " |")
    for it in sorted(snapshots, key=int):
        s = snapshots[it]
        cells = [
            f"{int(it):,}",
            *(_learned(s, name) for _, name in COLUMNS),
            f"{s['batch_loss']:.1e}",
            f"{100 * s['success']:.0f} %",
            f"{100 * s['lyapunov_monotone_fraction']:.0f} %",
        ]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"
