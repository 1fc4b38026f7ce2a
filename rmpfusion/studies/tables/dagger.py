"""Behavior cloning against DAgger at equal expert labels: one row per learner and method, with the
reference rows (the expert, unit weights, each learner untrained) above them.
"""

from __future__ import annotations

LEARNERS = {"rmp": "learner-rmp", "un": "learner-un"}


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
