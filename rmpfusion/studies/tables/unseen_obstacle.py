"""The unseen-obstacle table: per shape, a learned LASA motion with and without a disc it never saw on its held-out
demonstration's path, from the files ``tools/unseen_obstacle.py`` stores (one per shape).
"""

from __future__ import annotations

#: the two policies a file measures, in the order rows show them
POLICIES = ("trained tree", "with the unseen disc")


def table(runs: dict[str, dict]) -> str:
    """The Markdown table of unseen_obstacle's metrics.json files ({shape: file's content}): for each, the trained
    tree and the same tree with the disc's barrier leaf, from the test demonstration's start and from the starts at
    rest. The disc and the barrier's reach are in each file (``disc``, ``barrier_reach``) and the page's prose."""
    head = (
        "| shape | policy | test DTW (mm) | departs from the demonstration (mm): anywhere / beyond the barrier's reach "
        "| least clearance (mm) | touches the disc | starts at rest: converged at 3× / 10× | their collisions "
        "| their least clearance (mm) |"
    )
    lines = [head, "|---" * (head.count("|") - 1) + "|"]
    for shape, m in runs.items():
        for policy in POLICIES:
            r = m[policy]
            d = r["departure"]
            lines.append(
                f"| {shape} | {policy} | {1e3 * r['dtw']:.2f} | {1e3 * d['max']:.1f} / "
                f"{1e3 * d['max_away_from_obstacle']:.1f} | {1e3 * r['min_clearance']:.1f} "
                f"| {'yes' if r['collided'] else 'no'} | {r['converged_at_3x']:.0%} / {r['converged_at_10x']:.0%} "
                f"of {r['starts']} | {r['starts_collided']} | {1e3 * r['starts_min_clearance']:.1f} |"
            )
    return "\n".join(lines) + "\n"
