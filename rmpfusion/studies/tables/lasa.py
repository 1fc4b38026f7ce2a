"""The LASA tables: every single-pattern shape learned by ``experiment=lasa``, one row per shape and variant of
the tree (runs labelled ``<variant>/<shape>``), the configured tree with every weight 1 before each shape's rows and
the means over the shapes last; and the variants of one learner side by side by their means, validation first.
"""

from __future__ import annotations

import math

NAN = float("nan")


def _long(r: dict, key: str) -> float:
    """A number of the starts at rest's long-horizon outcomes (nan for a run made before they were measured)."""
    o = r["convergence"].get("at_long_horizon")
    if o is None:
        return NAN
    if key == "slowest":
        slowest = o["time_to_tolerance"]["max"]
        return NAN if slowest is None or o["time_to_tolerance"]["starts"] < o["starts"] else slowest
    return o[key] / o["starts"] if key == "converged" else o[key]


COLUMNS = (
    ("test DTW (mm)", lambda r: 1e3 * r["reproduction_test"]["dtw"]),
    ("swept area (mm²)", lambda r: 1e6 * r["reproduction_test"]["swept_error_area"]),
    ("final distance (mm)", lambda r: 1e3 * r["reproduction_test"]["final_distance"]),
    ("test start reached", lambda r: r["reproduction_test"]["reached"]),
    ("converged at 3×", lambda r: r["convergence"]["converged"]),
    ("converged at 10×", lambda r: _long(r, "converged")),
    ("at rest away", lambda r: _long(r, "at_rest_away")),
    ("slowest to 1 mm (s)", lambda r: _long(r, "slowest")),
    ("V_r monotone", lambda r: r["convergence"].get("lyapunov_monotone_fraction", NAN)),
)


def learner_results(m: dict) -> dict:
    """A LASA run's one learner's results (each run trains one learner)."""
    return next(iter(m["learners"].values()))


def row(shape: str, m: dict, policy: str) -> dict:
    r = m["tree"] if policy == "tree" else learner_results(m)
    out = {"shape": shape, "policy": policy, **{title: f(r) for title, f in COLUMNS}}
    if policy != "tree":
        out["certificate"] = bool(r["certificate"]["ok"]) if "certificate" in r else None  # None: not a tree
        out["train s"] = r.get("train_seconds")
    return out


def untrained_row(shape: str, m: dict, variant: str) -> dict | None:
    """The variant's learner at its random initialisation (snapshot 0), where the run evaluated it."""
    r = learner_results(m).get("snapshots", {}).get("0")
    if r is None:
        return None
    return {"shape": shape, "policy": f"{variant} (learner-0)", **{title: f(r) for title, f in COLUMNS}}


def fmt(v) -> str:
    if isinstance(v, bool):
        return "ok" if v else "FAILS"
    if isinstance(v, float):
        return "–" if math.isnan(v) else f"{v:.3g}"
    return "–" if v is None else str(v)


def table(rows: list[dict]) -> str:
    keys = ["shape", "policy", *(t for t, _ in COLUMNS), "certificate", "train s"]
    lines = ["| " + " | ".join(keys) + " |", "|" + "---|" * len(keys)]
    lines += ["| " + " | ".join(fmt(r.get(k)) for k in keys) + " |" for r in rows]
    return "\n".join(lines)


def mean_rows(rows: list[dict]) -> list[dict]:
    out = []
    for policy in dict.fromkeys(r["policy"] for r in rows):
        mine = [r for r in rows if r["policy"] == policy]
        mean = {"shape": f"mean of {len(mine)}", "policy": policy}
        for title, _ in COLUMNS:
            mean[title] = sum(r[title] for r in mine) / len(mine)
        if "certificate" in mine[0]:
            mean["certificate"] = all(r["certificate"] for r in mine) if mine[0]["certificate"] is not None else None
            mean["train s"] = sum(r["train s"] or 0.0 for r in mine) / len(mine)
        out.append(mean)
    return out


def table_of(runs: dict[str, dict]) -> str:
    """The table (with the mean rows) of runs labelled ``<variant>/<shape>``, in label order: the tree row of each
    shape from the first variant listed for it; each variant's untrained learner (learner-0) only in the mean rows.
    What the README shows and tests/test_results.py regenerates from results/."""
    rows, untrained, seen = [], [], set()
    for label, m in runs.items():
        variant, shape = label.split("/", 1)
        if shape not in seen:
            rows.append(row(shape, m, "tree"))
            seen.add(shape)
        rows.append(row(shape, m, variant))
        untrained += [r for r in [untrained_row(shape, m, variant)] if r is not None]
    shapes = list(dict.fromkeys(r["shape"] for r in rows))
    rows = sorted(rows, key=lambda r: (shapes.index(r["shape"]), r["policy"] != "tree"))
    return table(rows + mean_rows(rows) + mean_rows(untrained)) + "\n"


def choice_table(runs: dict[str, dict]) -> str:
    """Variants of one learner side by side by their means over the shapes, validation first: the one with the
    lowest mean validation DTW is kept (the test columns are reported, never chosen by). Runs labelled
    ``<variant>/<shape>``; every variant must cover the same shapes."""
    by_variant: dict[str, dict[str, dict]] = {}
    for label, m in runs.items():
        variant, shape = label.split("/", 1)
        by_variant.setdefault(variant, {})[shape] = learner_results(m)
    shapes = {frozenset(v) for v in by_variant.values()}
    if len(shapes) != 1:
        raise ValueError(f"the variants cover different shapes: {sorted(by_variant)}")
    mean = lambda rs, f: sum(f(r) for r in rs) / len(rs)
    rows = {
        v: {
            "validation DTW (mm)": mean(rs.values(), lambda r: 1e3 * r["reproduction_val"]["dtw"]),
            "test DTW (mm)": mean(rs.values(), COLUMNS[0][1]),
            "converged": mean(rs.values(), lambda r: r["convergence"]["converged"]),
            "train s": mean(rs.values(), lambda r: r["train_seconds"]),
        }
        for v, rs in by_variant.items()
    }
    kept = min(rows, key=lambda v: rows[v]["validation DTW (mm)"])
    keys = ["validation DTW (mm)", "test DTW (mm)", "converged", "train s"]
    n = len(next(iter(by_variant.values())))
    lines = [f"| variant (mean of {n} shapes) | " + " | ".join(keys) + " | kept |", "|" + "---|" * (len(keys) + 2)]
    lines += [
        f"| {v} | " + " | ".join(fmt(r[k]) for k in keys) + f" | {'yes' if v == kept else ''} |"
        for v, r in rows.items()
    ]
    return "\n".join(lines) + "\n"


#: Euclideanizing flows (Rana, Li, Wang, Ratliff & Boots, L4DC 2020) on six LASA shapes, from a separate run of its
#: public code with its own settings (coupling layers with random Fourier features, 2000 full-batch epochs, trained and
#: evaluated on all 7 demonstrations, on 2 cores): DTW per sample (mm), measured by rmpfusion's
#: ``reproduction.dtw_distance`` on its rollouts and the demonstrations. Quoted, not recomputed here.
EUCLIDEANIZING_FLOWS_DTW_MM = {
    "Angle": 1.79,
    "GShape": 1.40,
    "Khamesh": 0.74,
    "Snake": 1.04,
    "Sshape": 1.12,
    "Worm": 0.45,
}


def peer_table(runs: dict[str, dict]) -> str:
    """The shapes Euclideanizing flows was run on, its DTW (quoted) beside each policy's on the training
    demonstrations (runs labelled ``<policy>/<shape>``, trained and evaluated on all 7), and whether each policy's DTW
    is at most the peer's."""
    by_shape: dict[str, dict[str, float]] = {}
    for label, m in runs.items():
        policy, shape = label.split("/", 1)
        if shape not in EUCLIDEANIZING_FLOWS_DTW_MM:
            raise ValueError(f"{label}: Euclideanizing flows was run on {', '.join(EUCLIDEANIZING_FLOWS_DTW_MM)} only")
        by_shape.setdefault(shape, {})[policy] = COLUMNS[0][1](learner_results(m))
    policies = list(dict.fromkeys(label.split("/", 1)[0] for label in runs))
    head = ["shape", "Euclideanizing flows (quoted)", *(f"{p} (mm)" for p in policies)]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for shape, ours in by_shape.items():
        peer = EUCLIDEANIZING_FLOWS_DTW_MM[shape]
        cells = [f"{fmt(ours[p])}{' ≤' if ours[p] <= peer else ''}" if p in ours else "–" for p in policies]
        lines.append(f"| {shape} | {peer:.2f} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"
