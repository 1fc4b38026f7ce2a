"""The table of an arm run on joint-space recordings (``experiment=recorded_arm``) from its metrics.json."""

from __future__ import annotations

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
