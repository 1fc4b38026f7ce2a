"""The paper's 2D table (paper §4.1, appendix D.1): per experiment the expert, the tree with unit weights
(RMPflow), learner-rmp untrained (the paper's learner-0), then every learner trained, with the paper's numbers beside
ours where it printed them. Row labels are the experiments' names as the paper's table gives them.
"""

from __future__ import annotations

PAPER = {  # (experiment, learner): batch, online, success, collision   (None = not reported)
    ("2d1level", "learner-rmp"): (5.42e-5, 5.82e-5, None, None),
    ("2d2level", "learner-rmp"): (2.45e-4, 2.78e-4, 1.00, None),
    ("2d2level", "learner-un"): (0.111, 12.203, 0.00, 0.28),
    ("2d2level", "learner-un-large"): (0.065, 0.393, 0.00, 0.16),
    ("2d2level_per_edge", "learner-rmp"): (None, None, None, None),
}


LEARNER_NAMES = {"rmp": "learner-rmp", "un": "learner-un", "un_large": "learner-un-large"}


HEADER = (
    "| experiment | policy | parameters | validation loss | batch-loss (ours / paper) | online-loss (ours / paper) "
    "| online-loss, median over trajectories | online-loss before first collision | success (ours / paper) "
    "| collisions (ours / paper) | time to 0.1 (s) | closest approach to an obstacle | V_r monotone |"
)


def number(x) -> str:
    """Two significant digits, in scientific notation below 1e-3 and from 1e3 on: 3.2e-6, 0.27, 2.8e9; – when
    absent."""
    if x is None:
        return "–"
    if x != 0 and not 1e-3 <= abs(x) < 1e3:
        mantissa, exponent = f"{x:.1e}".split("e")
        return f"{mantissa}e{int(exponent)}"
    return f"{x:.2g}"


def paper_number(x) -> str:
    """A number the paper prints, with its three digits: 5.42e-5, 0.111, 12.2."""
    mantissa, _, exponent = f"{x:.3g}".partition("e")
    return f"{mantissa}e{int(exponent)}" if exponent else mantissa


def _task(m: dict, key: str, stat: str, digits: int = 2) -> str:
    """A statistic of the environment's per-trajectory task metric ``key`` over the test rollouts."""
    x = ((m.get("task") or {}).get(key) or {}).get(stat)
    return f"{x:.{digits}g}" if x is not None and 1e-3 <= abs(x) < 1e3 else number(x)


def percent(x) -> str:
    return "–" if x is None else f"{100 * x:.0f} %"


def _ours_paper(ours: str, paper: str | None) -> str:
    return ours if paper is None else f"{ours} / {paper}"


def _monotone(fractions: list) -> str:
    """The Lyapunov monitor's fraction of monotone rollouts: the worst over the snapshots given."""
    fractions = [f for f in fractions if f is not None]
    if not fractions:
        return "–"
    return percent(min(fractions)) + (f" (every one of {len(fractions)} snapshots)" if len(fractions) > 1 else "")


def _policy_row(
    exp: str, policy: str, m: dict, parameters="–", val=None, batch=None, paper=(None,) * 4, monotone: str | None = None
) -> str:
    given = [None if p is None else (percent(p) if i >= 2 else paper_number(p)) for i, p in enumerate(paper)]
    cells = [
        exp,
        policy,
        str(parameters),
        number(val),
        _ours_paper(number(batch), given[0]),
        _ours_paper(number(m.get("online_loss")), given[1]),
        number(m.get("online_loss_median")),
        number(m.get("online_loss_before_collision")),
        _ours_paper(percent(m.get("success")), given[2]),
        _ours_paper(percent(m.get("collision")), given[3]),
        _task(m, "time", "mean", digits=3),
        _task(m, "min_clearance", "min"),
        monotone if monotone is not None else _monotone([m.get("lyapunov_monotone_fraction")]),
    ]
    return "| " + " | ".join(cells) + " |"


def rows(exp: str, metrics: dict) -> list[str]:
    """The rows of one experiment: the expert, the same tree with unit weights (RMPflow) when the run evaluated
    it, learner-rmp untrained (snapshot 0, the paper's learner-0), then every learner trained."""
    out = [_policy_row(exp, "expert", metrics["expert"])]
    if "unit_weights" in metrics:
        out.append(_policy_row(exp, "unit weights (RMPflow)", metrics["unit_weights"]))
    learners = {LEARNER_NAMES.get(k, k): v for k, v in metrics["learners"].items()}
    rmp = learners.get("learner-rmp")
    if rmp is not None and "0" in rmp["snapshots"]:
        s0 = rmp["snapshots"]["0"]
        out.append(
            _policy_row(
                exp, "learner-rmp @ 0 (learner-0)", s0, rmp["num_parameters"], s0.get("val_loss"), s0.get("batch_loss")
            )
        )
    for name, r in learners.items():
        paper = PAPER.get((exp, name), (None,) * 4)
        monotone = _monotone([s.get("lyapunov_monotone_fraction") for s in r["snapshots"].values()])
        out.append(
            _policy_row(exp, name, r, r["num_parameters"], r.get("val_loss"), r.get("batch_loss"), paper, monotone)
        )
    return out


def table(results: dict) -> str:
    """The README's table of the runs in ``results`` ({table row: metrics.json}), in the order given."""
    lines = [HEADER, "|" + "---|" * (HEADER.count("|") - 1)]
    for exp, metrics in results.items():
        lines += rows(exp, metrics)
    return "\n".join(lines) + "\n"
