#!/usr/bin/env python
"""Summarise a sweep directory: mean ± std over seeds for every setting and learner, as a table and a figure.

    python tools/summarize_sweep.py outputs/multirun/2026-01-01_12-00-00
    python tools/summarize_sweep.py outputs/multirun/<time> --out reports/lr_sweep

Every job directory of the sweep (one holding ``.hydra/overrides.yaml``) is read: its overrides say which
setting it ran, its ``metrics.json`` what came out. Jobs are grouped by their overrides without ``seed``
(only the overrides that vary across the sweep name a setting); for each setting and learner the table gives
the mean ± sample standard deviation over the seeds of batch-loss, online-loss, success, collision and the
fraction of rollouts whose Lyapunov function V_r never increased. The expert is a row of its own.

Writes ``summary.md`` (the table), ``summary.json`` (the same numbers) and ``summary.png`` (one panel per metric,
error bars = std) into ``--out`` (default: the sweep directory), and prints the table. Jobs without a
``metrics.json`` (still running, killed, failed) are listed and left out; if no job has finished, the command
exits with status 1 naming them.
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
from pathlib import Path
from typing import Any

#: (metrics.json key, column title); the expert has no losses
METRICS = (
    ("val_loss", "validation loss"),
    ("batch_loss", "batch-loss"),
    ("online_loss", "online-loss"),
    ("success", "success"),
    ("collision", "collision"),
    ("lyapunov_monotone_fraction", "V_r monotone"),
)
SEED_KEYS = ("seed", "+seed", "++seed")


class SweepError(RuntimeError):
    pass


def _overrides(path: Path) -> list[str]:
    import yaml

    try:
        data = yaml.safe_load(path.read_text()) or []
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as e:
        first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise SweepError(f"{path} is damaged ({type(e).__name__}: {first}); the job's overrides are unknown") from None
    if not isinstance(data, list):
        raise SweepError(f"{path} is not a Hydra overrides list")
    return [str(o) for o in data]


def _split(override: str) -> tuple[str, str]:
    key, _, value = override.partition("=")
    return key, value


def find_jobs(sweep_dir: Path) -> tuple[list[dict], list[dict]]:
    """(finished jobs, unfinished jobs), each ``{"dir", "overrides", "metrics"?, "reason"?}``, in job order."""
    if not sweep_dir.is_dir():
        raise SweepError(f"{sweep_dir} is not a directory")
    dirs = sorted(
        {
            p.parent.parent
            for p in sweep_dir.rglob(".hydra/overrides.yaml")
            if ".submitit" not in p.parts and "accepted" not in p.parts
        },
        key=_job_order,
    )
    if not dirs:
        raise SweepError(
            f"{sweep_dir} holds no Hydra jobs (no */.hydra/overrides.yaml): is it a sweep directory "
            "(outputs/multirun/<time>)?"
        )
    done, pending = [], []
    for d in dirs:
        try:
            job = {"dir": d, "overrides": _overrides(d / ".hydra" / "overrides.yaml")}
        except SweepError as e:  # one damaged job is left out, named; the rest are summarised
            pending.append({"dir": d, "overrides": [], "reason": f"{e}; left out of the summary"})
            continue
        m = d / "metrics.json"
        if not m.is_file():
            job["reason"] = "no metrics.json (still running, killed or failed: see its console.log)"
            pending.append(job)
            continue
        try:
            job["metrics"] = json.loads(m.read_text())
        except ValueError as e:
            job["reason"] = f"metrics.json unreadable ({e})"
            pending.append(job)
            continue
        done.append(job)
    return done, pending


def _job_order(d: Path):
    head = d.name.split("_", 1)[0]
    return (0, int(head), d.name) if head.isdigit() else (1, 0, d.name)


def _seed(job: dict) -> Any:
    for o in job["overrides"]:
        k, v = _split(o)
        if k in SEED_KEYS:
            return v
    return job["metrics"].get("seed")


def settings(jobs: list[dict]) -> tuple[list[str], list[str]]:
    """Per job, the label of its setting (the overrides that vary across the sweep, seed excluded), and the
    overrides every job shares."""
    keyed = [{k: v for k, v in map(_split, j["overrides"]) if k not in SEED_KEYS} for j in jobs]
    keys = sorted({k for kv in keyed for k in kv})
    varying = [k for k in keys if len({kv.get(k) for kv in keyed}) > 1]
    common = [f"{k}={keyed[0][k]}" for k in keys if k not in varying and k in keyed[0]]
    labels = [" ".join(f"{k}={kv.get(k, '<default>')}" for k in varying) or "(all jobs)" for kv in keyed]
    return labels, common


def _stats(values: list[float]) -> dict:
    vals = [float(v) for v in values if isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)]
    out = {"n": len(vals), "mean": None, "std": None}
    if vals:
        out["mean"] = statistics.fmean(vals)
        out["std"] = statistics.stdev(vals) if len(vals) > 1 else None
    return out


def summarize(jobs: list[dict]) -> list[dict]:
    """One row per (setting, learner): the seeds and mean/std/n of every metric."""
    labels, _ = settings(jobs)
    groups: dict[str, list[dict]] = {}
    for label, job in zip(labels, jobs):
        groups.setdefault(label, []).append(job)
    rows = []
    for label, members in groups.items():
        learners: list[str] = []
        for j in members:
            learners += [n for n in (j["metrics"].get("learners") or {}) if n not in learners]
        for name in [*learners, "expert"]:
            per = [
                (j["metrics"].get("learners") or {}).get(name) if name != "expert" else j["metrics"].get("expert")
                for j in members
            ]
            have = [(j, p) for j, p in zip(members, per) if isinstance(p, dict)]
            if not have:
                continue
            rows.append(
                {
                    "setting": label,
                    "learner": name,
                    "seeds": [_seed(j) for j, _ in have],
                    "jobs": [j["dir"].name for j, _ in have],
                    **{key: _stats([p.get(key) for _, p in have]) for key, _ in METRICS},
                }
            )
    return rows


def _fmt(s: dict, pct: bool) -> str:
    if s["mean"] is None:
        return "–"
    f = (lambda x: f"{100 * x:.1f}%") if pct else (lambda x: f"{x:.4g}")
    return f(s["mean"]) if s["std"] is None else f"{f(s['mean'])} ± {f(s['std'])}"


def markdown(rows: list[dict], common: list[str], sweep_dir: Path, pending: list[dict]) -> str:
    pct = {"success", "collision", "lyapunov_monotone_fraction"}
    lines = [f"# Sweep {sweep_dir}", ""]
    if common:
        lines += [f"Shared overrides: `{' '.join(common)}`", ""]
    lines += [
        "Mean ± sample std over seeds (n = number of seeds).",
        "",
        "| setting | learner | n | seeds | " + " | ".join(t for _, t in METRICS) + " |",
        "|---|---|---|---|" + "---|" * len(METRICS),
    ]
    for r in rows:
        lines.append(
            f"| {r['setting']} | {r['learner']} | {len(r['seeds'])} | {', '.join(map(str, r['seeds']))} | "
            + " | ".join(_fmt(r[k], k in pct) for k, _ in METRICS)
            + " |"
        )
    if pending:
        lines += [
            "",
            f"Not finished ({len(pending)}, left out): "
            + ", ".join(f"{j['dir'].name} ({j['reason']})" for j in pending),
        ]
    return "\n".join(lines) + "\n"


def figure(rows: list[dict], path: Path, title: str) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    settings_ = list(dict.fromkeys(r["setting"] for r in rows))
    learners = list(dict.fromkeys(r["learner"] for r in rows))
    fig, axes = plt.subplots(1, len(METRICS), figsize=(3.4 * len(METRICS), 3.6), squeeze=False)
    width = 0.8 / max(1, len(learners))
    for ax, (key, name) in zip(axes[0], METRICS):
        for li, learner in enumerate(learners):
            xs, ys, es = [], [], []
            for si, s in enumerate(settings_):
                r = next((r for r in rows if r["setting"] == s and r["learner"] == learner), None)
                if r is None or r[key]["mean"] is None:
                    continue
                xs.append(si + (li - (len(learners) - 1) / 2) * width)
                ys.append(r[key]["mean"])
                es.append(r[key]["std"] or 0.0)
            if xs:
                ax.bar(xs, ys, width=width, yerr=es, capsize=3, label=learner)
        if key.endswith("loss") and any(r[key]["mean"] for r in rows):
            ax.set_yscale("log")
        ax.set_title(name)
        ax.set_xticks(range(len(settings_)))
        ax.set_xticklabels(settings_, rotation=30, ha="right", fontsize=7)
    axes[0][0].legend(fontsize=7)
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("sweep_dir", type=Path, help="a Hydra multirun directory, e.g. outputs/multirun/<time>")
    ap.add_argument("--out", type=Path, default=None, help="where summary.md/.json/.png go (default: sweep_dir)")
    args = ap.parse_args(argv)
    try:
        done, pending = find_jobs(args.sweep_dir)
        if not done:
            raise SweepError(
                f"no finished job in {args.sweep_dir}: " + "; ".join(f"{j['dir'].name}: {j['reason']}" for j in pending)
            )
    except SweepError as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    for j in pending:
        print(f"warning: {j['dir'].name} left out: {j['reason']}", file=sys.stderr)
    rows = summarize(done)
    _, common = settings(done)
    out = args.out or args.sweep_dir
    out.mkdir(parents=True, exist_ok=True)
    md = markdown(rows, common, args.sweep_dir, pending)
    (out / "summary.md").write_text(md)
    (out / "summary.json").write_text(
        json.dumps(
            {
                "sweep_dir": str(args.sweep_dir),
                "shared_overrides": common,
                "unfinished": [{"job": j["dir"].name, "reason": j["reason"]} for j in pending],
                "rows": rows,
            },
            indent=2,
            default=str,
        )
        + "\n"
    )
    figure(rows, out / "summary.png", f"{args.sweep_dir.name}: mean ± std over seeds")
    print(md)
    print(f"wrote {out / 'summary.md'}, {out / 'summary.json'}, {out / 'summary.png'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
