"""The depth-camera table: per policy (the trained learner, its initialisation, unit weights) the tree given the
obstacles exactly, then each camera setting's row, from the files ``tools/camera_run.py`` stores.
"""

from __future__ import annotations

import math


def _policy_label(settings: dict) -> str:
    """What a camera row's tree was fed, from the settings it ran with."""
    if settings["reduction"] == "nearest":
        return f"camera, each control point's {settings['k']} nearest points, radius {100 * settings['point_radius']:.0f} cm"
    voxel = settings["voxel"]
    label = (
        f"camera, voxels: {settings['n_max']} members of {100 * voxel:.0f} cm cubes, "
        f"radius {100 * math.sqrt(3) / 2 * voxel:.1f} cm"
    )
    return label + (", velocities from successive frames" if settings.get("velocities") else "")


def _rises(row: dict) -> str:
    """Where V_r rose between changes of the tree's aux: in all, and before any contact (where Theorem 2 speaks),
    with the largest of those rises relative to V_r."""
    worst = row["vr_max_relative_rise_before_contact"]
    size = f"{worst:.2g}× V_r" if worst >= 1 else f"{100 * worst:.2g} % of V_r"
    return (
        f"{row['vr_rises_between_changes']} of {row['records_checked']:,} record pairs; "
        f"{row['vr_rises_before_contact']} before any contact, the largest {size}"
    )


#: how a row names the policy a file ran (``--policy``)
POLICY_NAMES = {"trained": "", "learner-0": "learner-0 (untrained): ", "unit": "unit weights (RMPflow): "}


def table(runs: dict[str, dict]) -> str:
    """The Markdown table of camera_run's --json files ({label: file's content}): per policy (the trained learner,
    its initialisation, unit weights), the exact tree's row from the first file that ran it, then each file's camera
    row."""
    head = (
        "| policy | reached | collided | least clearance (mm) | goal distance at 10 s (mm) "
        "| V_r rises between changes of its aux |"
    )
    lines = [head, "|---" * (head.count("|") - 1) + "|"]

    def row(label: str, r: dict, rises: str) -> str:
        return (
            f"| {label} | {r['reached']} / {r['n']} | {r['collided']} / {r['n']} | {1000 * r['min_clearance_m']:.1f} "
            f"| {1000 * r['final_goal_distance_m']:.0f} | {rises} |"
        )

    exact_done = set()
    for m in runs.values():
        policy = m["settings"].get("policy", "trained")
        who = POLICY_NAMES[policy]
        if "exact" in m and policy not in exact_done:
            exact_done.add(policy)
            unchecked = "not checked: the moving sphere changes its aux at every step"
            lines.append(row(f"{who}the obstacles given exactly", m["exact"], unchecked))
        lines.append(row(who + _policy_label(m["settings"]), m["camera"], _rises(m["camera"])))
    return "\n".join(lines) + "\n"
