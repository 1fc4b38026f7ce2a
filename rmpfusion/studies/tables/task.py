"""The table of a manipulator experiment (paper Fig. 5b as numbers) from the metrics.json of one or more runs."""

from __future__ import annotations

RATIOS = ("time", "cspace_length", "ee_length")


HEADER = (
    "| run | policy | time to 0.05 m (s) | reached | ratio time | ratio c-space length | ratio e-e length "
    "| goal distance at time-out (mm) | ratio goal distance at time-out | collisions | close passes (< 10 mm) "
    "| min clearance (mm), least / median | V_r monotone |"
)


def _pm(d: dict | None, scale: float = 1.0, digits: int = 2) -> str:
    if not d or d.get("mean") is None:
        return "–"
    std = d.get("std")
    return (
        f"{scale * d['mean']:.{digits}f} ± {scale * std:.{digits}f}"
        if std is not None
        else f"{scale * d['mean']:.{digits}f}"
    )


def _count(k: int | None, n: int) -> str:
    return "–" if k is None else f"{k} / {n}"


def _clearance(c: dict | None) -> str:
    """The closest any rollout came to an obstacle and the median rollout's closest (mm); pybullet resolves
    distances up to env.clearance_query (0.3 m), so larger ones read as that."""
    return "–" if not c else f"{1000 * c['least']:.1f} / {1000 * c['median']:.1f}"


def rows(metrics: dict, with_expert: bool, label: str | None = None) -> list[str]:
    """The table's lines of one run, labelled ``label`` (default the run's name)."""
    out = []
    for r in metrics["task_table"]:
        if r["policy"] == "expert" and not with_expert:
            continue
        ratio = r.get("ratio") or {}
        lyap = r.get("lyapunov") or {}
        mono = lyap.get("monotone_fraction")
        n = r["trajectories"]
        expert = r["policy"] == "expert"
        count = f"{round(mono * n) if mono is not None else '–'} / {n}"
        if lyap.get("theorem2_applies") is False:
            count = f"n/a, obstacle moving ({count})"
        out.append(
            " | ".join(
                [
                    f"| {label or metrics['name']}",
                    r["policy"],
                    _pm(r.get("time")),
                    f"{round(r['reached']['mean'] * n)} / {n}",
                    *("1" if expert else _pm(ratio.get(k)) for k in RATIOS),
                    _pm(r.get("timeout_goal_distance"), 1000.0, 1),
                    "1" if expert else _pm(ratio.get("timeout_goal_distance"), digits=2),
                    f"{r['collisions']} / {n}",
                    _count(r.get("close_passes"), n),
                    _clearance(r.get("clearance")),
                    count,
                ]
            )
            + " |"
        )
    return out


def table(runs: dict[str, dict]) -> str:
    """The markdown table of runs given as {label: metrics}, in that order, each run's rows labelled with its key
    (``tests/test_results.py`` regenerates stored tables from ``results/`` with this function)."""
    lines = [HEADER, "|" + "---|" * (HEADER.count("|") - 1)]
    experts: list = []
    for label, m in runs.items():
        expert = next(r for r in m["task_table"] if r["policy"] == "expert")
        lines += rows(m, with_expert=expert not in experts, label=label)
        experts.append(expert)
    return "\n".join(lines) + "\n"
