#!/usr/bin/env python
"""The LASA table: every single-pattern shape of the LASA handwriting dataset learned by experiment=lasa, per
variant of the tree, as one Hydra multirun per variant (so a joblib or SLURM launcher runs it unchanged).

    python tools/lasa_table.py                                  # the 26 shapes, every variant (hours on 2 cores)
    python tools/lasa_table.py --variants both --shapes Angle Sshape --out outputs/lasa_table
    python tools/lasa_table.py --variants both -- hydra/launcher=joblib hydra.launcher.n_jobs=2
    python tools/lasa_table.py --summarize-only --out outputs/lasa_table   # the table of runs already made

Variants (the tree and what the learner learns; conf/experiment/lasa.yaml):
  weights  tree=lasa: normalising map -> attractor; a learned weight on the attractor edge (the force points at
           the goal, so the path stays straight: the baseline)
  map      tree=lasa_map, learners.rmp.edges=[]: the learned map (a diffeomorphism) without a weight
  both     tree=lasa_map: the learned map and the weight
  both_all7  both under the protocol most published LASA numbers use: trained and evaluated on all 7
           demonstrations (data.split=all; the other variants hold one out for validation and one for the test)
  both_radial  both with the attractor's weight a learned radial profile about the latent origin (never
           decreasing with the distance: it shapes the speed but adds no equilibrium, docs/math.md §12)
The trees also learn the attractor's gain, softness and damping.
  first_order  not a tree: the first-order baseline (a velocity field through the same kind of learned map,
           Euclideanizing-Flows style, executed by velocity tracking; rmpfusion/learn/first_order.py)
  seds     not a tree: SEDS (Khansari-Zadeh & Billard 2011), Gaussian mixture regression with every component
           contracting, started from EM and executed by the same velocity tracking (rmpfusion/learn/seds.py)
  seds_all7  seds trained and evaluated on all 7 demonstrations (data.split=all), as SEDS's own papers did
  seds_k3, seds_k6  seds with 3 and 6 Gaussians (seds has 10, chosen among the three on validation: --choose)
The "tree" row of a shape is the first variant's tree with every weight 1, nothing learned. Arguments after ``--``
go to every run.

Writes ``<out>/lasa_table.md`` (the table: test DTW per sample, swept error area, final distance, whether the rollout from the test
demonstration's start came within the tolerance of the goal, convergence from the grid of starts at rest, V_r monotone, the certificate, training time; the mean over shapes as the last row),
``<out>/lasa_table.json`` (every number), ``<out>/lasa_grid.png`` (the rollouts figure of every run: with
several variants, each shape's side by side) and, with several variants, ``<out>/lasa_dtw.png`` (each shape's test
DTW by variant); ``--report DIR`` writes them to DIR instead. A shape whose run failed or is still running is listed, not silently left out.
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from rmpfusion.recordings import SINGLE_PATTERN_SHAPES

VARIANTS = {
    "weights": ["tree=lasa"],
    "map": ["learners.rmp.edges=[]"],
    "both": [],
    "first_order": ["~learners.rmp", "+learner@learners.first_order=first_order"],
    "seds": ["~learners.rmp", "+learner@learners.seds=seds"],
    "seds_all7": ["~learners.rmp", "+learner@learners.seds=seds", "data.split=all"],
    "seds_k3": ["~learners.rmp", "+learner@learners.seds=seds", "learners.seds.components=3"],
    "seds_k6": ["~learners.rmp", "+learner@learners.seds=seds", "learners.seds.components=6"],
    "both_all7": ["data.split=all"],
    "both_radial": ["~learners.rmp.weights", "+learners.rmp.weights={type: radial, center: [0.0, 0.0], reach: 3.0}"],
}
COLUMNS = (
    ("test DTW (mm)", lambda r: 1e3 * r["reproduction_test"]["dtw"]),
    ("swept area (mm²)", lambda r: 1e6 * r["reproduction_test"]["swept_error_area"]),
    ("final distance (mm)", lambda r: 1e3 * r["reproduction_test"]["final_distance"]),
    ("test start reached", lambda r: r["reproduction_test"]["reached"]),
    ("converged", lambda r: r["convergence"]["converged"]),
    ("V_r monotone", lambda r: r["convergence"].get("lyapunov_monotone_fraction", float("nan"))),
)


def run_variant(variant: str, shapes: list[str], out: Path, extra: list[str]) -> int:
    """One multirun over the shapes; returns its exit status (failed jobs are listed by rmpfusion-run)."""
    cmd = [
        sys.executable,
        "-m",
        "rmpfusion.cli.run",
        "-m",
        "experiment=lasa",
        f"data.shape={','.join(shapes)}",
        *VARIANTS[variant],
        f"hydra.sweep.dir={out / variant}",
        "hydra.sweep.subdir=${data.shape}",
        *extra,
    ]
    print("$", " ".join(cmd), flush=True)
    return subprocess.call(cmd, cwd=ROOT)


def read_runs(out: Path, variant: str, shapes: list[str]) -> tuple[dict[str, dict], list[str]]:
    found, missing = {}, []
    for shape in shapes:
        path = out / variant / shape / "metrics.json"
        if path.is_file():
            found[shape] = json.loads(path.read_text())
        else:
            missing.append(shape)
    return found, missing


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


def grid_figure(out: Path, variants: list[str], shapes: list[str], to: Path) -> Path | None:
    """Every run's rollouts figure (the tree with every weight 1, then the trained learner, from the grid of starts
    at rest): one variant, four shapes a row; several variants, one shape a row and one variant a column, so the
    variants' rollouts of a shape sit side by side."""
    import matplotlib.image as mpimg
    from matplotlib.figure import Figure

    cells = [(s, v, out / v / s / "figures" / "rollouts.png") for s in shapes for v in variants]
    cells = [(s, v, p) for s, v, p in cells if p.is_file()]
    if not cells:
        return None
    one = len(variants) == 1
    cols = 4 if one else len(variants)
    rows_of = list(dict.fromkeys(s for s, _, _ in cells))
    places = [divmod(k, cols) if one else (rows_of.index(s), variants.index(v)) for k, (s, v, _) in enumerate(cells)]
    rows_n = 1 + max(r for r, _ in places)
    fig = Figure(figsize=(4.2 * cols, 2.4 * rows_n), layout="constrained")
    axes = fig.subplots(rows_n, cols, squeeze=False)
    for ax in axes.flat:
        ax.axis("off")
    for (r, c), (shape, variant, p) in zip(places, cells):
        axes[r][c].imshow(mpimg.imread(p))
        axes[r][c].set_title(shape if one else f"{shape}, {variant}", fontsize=9)
    what = f"variant '{variants[0]}'" if one else "variants " + ", ".join(f"'{v}'" for v in variants)
    fig.suptitle(f"LASA, {what}: the tree (left) and the trained learner (right) of each run")
    path = to / "lasa_grid.png"
    fig.savefig(path, dpi=120)
    return path


def dtw_figure(runs: dict[str, dict], variants: list[str], path: Path) -> Path | None:
    """Test DTW of every shape, one marker per variant (log scale): where the table's means hide which shapes a
    variant wins and loses. None with fewer than two variants."""
    from matplotlib.figure import Figure

    present = [v for v in variants if any(label.startswith(f"{v}/") for label in runs)]
    if len(present) < 2:
        return None
    shapes = list(dict.fromkeys(label.split("/", 1)[1] for label in runs))
    fig = Figure(figsize=(max(8.0, 0.42 * len(shapes)), 4.2), layout="constrained")
    ax = fig.subplots()
    markers = "osD^vP*Xh"
    for k, variant in enumerate(present):
        xs, ys = [], []
        for i, shape in enumerate(shapes):
            if (m := runs.get(f"{variant}/{shape}")) is not None:
                xs.append(i + (k - (len(present) - 1) / 2) * 0.09)
                ys.append(COLUMNS[0][1](learner_results(m)))
        mean = sum(ys) / len(ys)
        ax.scatter(xs, ys, s=18, marker=markers[k % len(markers)], label=f"{variant} (mean {mean:.2f} mm)")
    ax.set_yscale("log")
    ax.set_xticks(range(len(shapes)), shapes, rotation=60, ha="right", fontsize=8)
    ax.set_ylabel("test DTW per sample (mm)")
    ax.grid(axis="y", which="both", alpha=0.3)
    ax.legend(fontsize=8, ncol=min(3, len(present)))
    ax.set_title("LASA: test DTW of each shape's held-out demonstration, by variant")
    fig.savefig(path, dpi=120)
    return path


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--shapes", nargs="+", default=list(SINGLE_PATTERN_SHAPES), choices=SINGLE_PATTERN_SHAPES)
    ap.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    ap.add_argument("--out", type=Path, default=ROOT / "outputs" / "lasa_table")
    ap.add_argument("--summarize-only", action="store_true", help="read the runs already in --out; run nothing")
    ap.add_argument("--report", type=Path, help="where the table and figures go (default: --out)")
    ap.add_argument(
        "--choose",
        action="store_true",
        help="also write lasa_choice.md: the variants' means, the one with the lowest validation DTW kept",
    )
    args, extra = ap.parse_known_args(argv)
    extra = [e for e in extra if e != "--"]
    args.out = args.out.resolve()
    if not args.summarize_only:
        for variant in args.variants:
            run_variant(variant, args.shapes, args.out, extra)
    runs, report = {}, {}
    for variant in args.variants:
        found, missing = read_runs(args.out, variant, args.shapes)
        if missing:
            print(f"{variant}: no metrics.json for {', '.join(missing)} (failed or not run)")
        report[variant] = {"runs": {s: str(args.out / variant / s) for s in found}, "missing": missing}
        runs.update({f"{variant}/{shape}": m for shape, m in found.items()})
    if not runs:
        print("no finished run to tabulate", file=sys.stderr)
        return 1
    order = {s: k for k, s in enumerate(args.shapes)}
    runs = dict(
        sorted(runs.items(), key=lambda kv: (order[kv[0].split("/", 1)[1]], args.variants.index(kv[0].split("/")[0])))
    )
    text = table_of(runs).rstrip("\n")
    to = (args.report or args.out).resolve()
    to.mkdir(parents=True, exist_ok=True)
    (to / "lasa_table.md").write_text(text + "\n")
    (to / "lasa_table.json").write_text(json.dumps({"runs": report}, indent=1))
    figures = [
        grid_figure(args.out, args.variants, args.shapes, to),
        dtw_figure(runs, args.variants, to / "lasa_dtw.png"),
    ]
    print(text)
    if args.choose:
        choice = choice_table(runs)
        (to / "lasa_choice.md").write_text(choice)
        print(choice.rstrip("\n"))
    print(f"wrote {to / 'lasa_table.md'}" + "".join(f" and {f}" for f in figures if f is not None))
    return 0


if __name__ == "__main__":
    sys.exit(main())
