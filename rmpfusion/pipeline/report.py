"""Stage 4, report: the figures and ``metrics.json`` of a run, from what the other stages returned."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

from ..envs.protocol import HasRatioMetrics, PlanarWorkspace, Renders
from ..evaluate.metrics import StageResult
from ..files import atomic_write_json
from ..plots import plot_learning_curves, plot_lyapunov, plot_progression, plot_trajectories, plot_weights
from ..plots.manipulator import manipulator_figures
from .collect import Splits, data_hash
from .evaluation import ExpertEval, LearnerEval
from .experiment import Experiment, clean
from .fit import Fitted


def _curves(f: Fitted) -> dict:
    return {"train": f.result.curve, "val": f.result.val_curve, "test": f.result.test_curve}


def _planar_figures(exp: Experiment, name: str, ev: LearnerEval, expert: ExpertEval, test) -> list[Path]:
    """Configuration-space figures of test environment 0: trajectories and V_r(t)."""
    idx, q0, qd0, aux = exp.environment_0(test)
    ro, out = ev.final_rollout, []
    out.append(
        plot_trajectories(
            exp.dir / "figures" / f"trajectories_{name}.png",
            aux,
            expert.rollout.q[:, idx],
            {name: ro.q[:, idx]},
            q0,
            qd0,
            title=f"{exp.run.name}: expert (dashed) vs {name}, test environment 0",
        )
    )
    if ro.V is not None:
        out.append(
            plot_lyapunov(
                exp.dir / "figures" / f"lyapunov_{name}.png",
                ro.times,
                ro.V[:, idx],
                title=f"{exp.run.name}: {name}'s $V_r(t)$, test environment 0",
            )
        )
    return out


def _progression_figure(exp: Experiment, name: str, ev: LearnerEval, expert: ExpertEval, test) -> Path:
    """Test environment 0 at every snapshot beside the expert (paper Fig. 4)."""
    idx, q0, qd0, aux = exp.environment_0(test)
    return plot_progression(
        exp.dir / "figures" / f"progression_{name}.png",
        aux,
        expert.rollout.q[:, idx],
        ev.panels,
        q0,
        qd0,
        title=f"{exp.run.name}: {name} vs the expert at each training "
        f"snapshot (columns: {name} @ iteration), test environment 0",
    )


def _learner_figures(
    exp: Experiment, name: str, f: Fitted, ev: LearnerEval, expert: ExpertEval, splits: Splits
) -> list[Path]:
    fig_dir, out = exp.dir / "figures", []
    planar = isinstance(exp.env, PlanarWorkspace)
    if planar:
        out += _planar_figures(exp, name, ev, expert, splits.test)
    out.append(
        plot_learning_curves(
            fig_dir / f"learning_curve_{name}.png",
            {name: _curves(f)},
            {name: sorted(f.result.snapshots)},
            title=f"{exp.run.name}: learning curve of {name} ({exp.run.train.method})",
            unit="a.u./s²" if planar else "rad/s²",
            measure=f.result.measure,
        )
    )
    if ev.weights is not None and ev.weights.traces:
        out.append(
            plot_weights(
                fig_dir / f"weights_{name}.png",
                ev.weights.times,
                ev.weights.expert_traces(),
                ev.weights.traces,
                title=f"{exp.run.name}: {name}'s weights vs the expert's (dashed) "
                "along test trajectory 0 (test environment 0)",
            )
        )
    if planar and ev.panels:
        out.append(_progression_figure(exp, name, ev, expert, splits.test))
    return out


def figures(
    exp: Experiment, splits: Splits, fitted: dict[str, Fitted], expert: ExpertEval, evals: dict[str, LearnerEval]
) -> list[str]:
    """Every figure of the run; an environment that renders (a manipulator) adds its own (paper Fig. 5b, 6)."""
    out: list[Path] = []
    for name, ev in evals.items():
        out += _learner_figures(exp, name, fitted[name], ev, expert, splits)
    if evals:
        out.append(
            plot_learning_curves(
                exp.dir / "figures" / "learning_curves.png",
                {n: _curves(f) for n, f in fitted.items()},
                title=f"{exp.run.name}: learning curves of every learner ({exp.run.train.method})",
                unit="a.u./s²" if isinstance(exp.env, PlanarWorkspace) else "rad/s²",
                measure=next(iter(fitted.values())).result.measure,
            )
        )
    if isinstance(exp.env, Renders) and expert.stage is not None:
        t0 = time.time()
        exp.say.say("figures: " + exp.run.name)
        stages = [st for ev in evals.values() for st in ev.task_stages]
        out += manipulator_figures(
            exp.env, exp.dir / "figures", expert.stage, stages, splits.test.initial_states()[2], title=exp.run.name
        )
        exp.timing["figures_s"] = time.time() - t0
    return [str(p) for p in out]


def _learner_entry(exp: Experiment, name: str, f: Fitted, ev: LearnerEval) -> dict:
    res = clean(ev.final)
    res.update(
        {
            "num_parameters": f.model.num_parameters(),
            "type": exp.run.learners[name].type,
            "train_seconds": f.seconds,
            "eval_seconds": ev.seconds,
            "snapshots": ev.snapshots,
            "final_train_loss": f.result.curve[-1][1] if f.result.curve else None,
            "resumed_from": f.result.resumed_from,
            "training": clean({"method": exp.run.train.method, "measure": f.result.measure, **f.result.info}),
            **f.model.describe(),
        }
    )
    return res


def task_table(expert: StageResult, stages: list[StageResult], ratio_keys) -> list[dict]:
    """One row per policy (expert, then every learner snapshot): task-metric means ± std, ratios to the expert,
    collisions and the Lyapunov monitor: the numbers of the paper's Fig. 5b in one place."""
    rows = []
    for st in [expert, *stages]:
        row: dict[str, Any] = {"policy": st.label, "learner": st.learner, "iteration": st.iteration}
        for k, v in st.summary.items():
            row[k] = {"mean": v["mean"], "std": v["std"]}
        collided = st.per_trajectory.get("collided")
        row["collisions"] = round(float(collided.sum())) if collided is not None else None
        close, clearance = st.per_trajectory.get("close_pass"), st.per_trajectory.get("min_clearance")
        if close is not None:
            row["close_passes"] = round(float(close.sum()))
        if clearance is not None and clearance.numel():
            # beside min_clearance's mean ± std: the closest any rollout came, and the (lower) median rollout's
            row["clearance"] = {"least": float(clearance.min()), "median": float(clearance.median())}
        row["trajectories"] = int(st.rollout.q.shape[1])
        if st.ratios:
            row["ratio"] = {k: {"mean": v["mean"], "std": v["std"]} for k, v in st.ratios.items() if k in ratio_keys}
        if st.lyapunov:
            row["lyapunov"] = dict(st.lyapunov)
        rows.append(row)
    return rows


def report(
    exp: Experiment,
    splits: Splits,
    fitted: dict[str, Fitted],
    expert: ExpertEval,
    evals: dict[str, LearnerEval],
    started: float,
) -> dict:
    """Figures (when ``eval.figures``) and metrics.json; returns the metrics."""
    expert_metrics = dict(expert.metrics)
    for ev in evals.values():
        if ev.weights is not None:
            expert_metrics.setdefault("weights", {}).update(ev.weights.expert_summary())
    results = {name: _learner_entry(exp, name, fitted[name], ev) for name, ev in evals.items()}
    for name, res in results.items():
        exp.say.say(
            f"learner {name}: "
            + ", ".join(
                f"{k}={v:.4g}"
                for k, v in res.items()
                if isinstance(v, float) and k not in ("train_seconds", "eval_seconds")
            )
        )
    metrics = {
        "name": exp.run.name,
        "seed": exp.run.seed,
        "config_hash": data_hash(exp.run),
        "data": splits.info,
        "expert": clean(expert_metrics),
        "learners": results,
        "figures": [],
        "timing": exp.timing,
    }
    if expert.unit is not None:
        metrics["unit_weights"] = clean(expert.unit.metrics)
    if expert.stage is not None:
        keys = exp.env.ratio_metrics if isinstance(exp.env, HasRatioMetrics) else ()
        stages = [st for ev in evals.values() for st in ev.task_stages]
        if expert.unit is not None and expert.unit.stage is not None:  # it has one when the expert has
            stages.insert(0, expert.unit.stage)
        metrics["task_table"] = clean(task_table(expert.stage, stages, keys))
    if exp.run.eval.figures:  # the numbers first: a figure that cannot be written (a full disk) loses no result
        atomic_write_json(exp.dir / "metrics.json", metrics)
        metrics["figures"] = figures(exp, splits, fitted, expert, evals)
    exp.timing["total_s"] = time.time() - started
    atomic_write_json(exp.dir / "metrics.json", metrics)
    exp.say.say(f"done in {exp.timing['total_s']:.1f}s: {exp.dir / 'metrics.json'}")
    return metrics
