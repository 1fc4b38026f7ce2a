"""Stage 3, evaluate: the expert and every learner snapshot rolled out from the test split's initial states.

Each learner is evaluated at every training snapshot (the paper's learner-0 … learner-N): batch, online and
validation losses, rates, the Lyapunov monitor, the environment's task metrics and their ratios to the
expert where it has them, and learner-rmp's weights beside the expert's.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import torch
from torch import Tensor

from ..envs.demonstrations import Dataset
from ..envs.protocol import HasTaskMetrics
from ..evaluate.divergence import divergence
from ..evaluate.metrics import StageResult, evaluate_learner, online_loss, rollout_rates, task_stage
from ..evaluate.weights import edge_weights, learned_edges, summarize_weights
from ..learn.learner import Learner
from ..learn.loop import load_snapshot
from ..learn.objectives import dataset_loss
from .certificates import certificate
from .collect import Splits, expert_diverged
from .construct import build_unit_weights
from .experiment import COMPILING, Experiment, clean, compiles
from .fit import Fitted
from .recorded import RecordedEval, evaluate_recorded, evaluation_batch


@dataclass
class ExpertEval:
    """The expert on the test initial states: the reference for rates, ratios and the dashed lines of figures;
    with ``eval.unit_weights``, the same tree with every weight 1 (RMPflow) beside it in ``unit``."""

    rollout: Any
    metrics: dict
    stage: StageResult | None  # task metrics, for environments that have them
    unit: ExpertEval | None = None


def task_line(st: StageResult) -> str:
    parts = [f"{k}={v['mean']:.4g}±{v['std']:.2g}" for k, v in st.summary.items()]
    if st.ratios:
        parts += [f"ratio.{k}={v['mean']:.3f}±{v['std']:.3f}" for k, v in st.ratios.items()]
    return ", ".join(parts)


UNIT_WEIGHTS = "unit weights (RMPflow)"


def _evaluate_tree(
    exp: Experiment, test: Dataset, label: str, tree, expert: StageResult | None = None, online_losses: bool = False
) -> ExpertEval:
    """A fixed tree rolled out from the test initial states: rates, the Lyapunov monitor, the online losses
    against the expert when asked (the expert's own are 0), and the task metrics (with their ratios to ``expert``
    when given) for environments that have them."""
    exp.say.say(f"eval: {label}")
    q0, qd0, aux0 = test.initial_states()
    ev, d = exp.run.eval, exp.expert_data
    online = online_loss(
        tree,
        exp.expert_at(),
        exp.env,
        q0,
        qd0,
        aux0,
        exp.horizon,
        d.interval,
        exp.fine_interval,
        exp.say.bar(f"rollout {label}"),
    )
    ro = online.rollout
    metrics: dict[str, Any] = rollout_rates(ro, ev.lyapunov_rtol, ev.lyapunov_atol)
    if online_losses:
        metrics.update(online.metrics())
    stage = None
    if isinstance(exp.env, HasTaskMetrics):
        stage = task_stage(label, ro, exp.env, expert, rtol=ev.lyapunov_rtol, atol=ev.lyapunov_atol)
        metrics["task"] = stage.summary
        exp.say.say(f"{label}: " + task_line(stage))
    return ExpertEval(ro, metrics, stage)


def evaluate_expert(exp: Experiment, test: Dataset) -> ExpertEval:
    t0 = time.time()
    out = _evaluate_tree(exp, test, "expert", exp.expert_at())
    ro = out.rollout
    if (found := divergence(ro.q, ro.qd, ro.V, theorem2_applies=not ro.moving)) is not None:
        raise expert_diverged("test rollouts", found)
    if exp.run.eval.unit_weights:
        out.unit = _evaluate_tree(
            exp,
            test,
            UNIT_WEIGHTS,
            build_unit_weights(exp.run, exp.env.aux_dims()).to(device=exp.device),
            out.stage,
            online_losses=True,
        )
    exp.timing["expert_eval_s"] = time.time() - t0
    return out


class WeightReport:
    """The weights of learner-rmp's learned edges over the test states at every snapshot, beside the expert's on
    the same states (an edge the expert leaves unweighted has w = 1 there): summaries for metrics.json, values
    along one test trajectory for the figure."""

    def __init__(self, exp: Experiment, model: Learner, test: Dataset):
        assert model.tree is not None, "a weight report is made of a learner that is a tree"
        self.edges = learned_edges(model.tree)
        self.states = (test.q, test.qd, test.aux)
        self.along = test.traj_id == test.traj_id[0]  # the first test trajectory
        self.times = test.t[self.along]
        weighted = [e for e in self.edges if e in exp.expert.weights]
        values = edge_weights(exp.expert, *self.states, weighted)
        ones = torch.ones(len(test), dtype=test.q.dtype)
        self.expert = {e: values.get(e, ones) for e in self.edges}
        self.traces: dict[str, dict[str, Tensor]] = {}

    def expert_summary(self) -> dict:
        return summarize_weights(self.expert)

    def expert_traces(self) -> dict[str, Tensor]:
        return {e: w[self.along] for e, w in self.expert.items()}

    def snapshot(self, label: str, model: Learner) -> dict:
        assert model.tree is not None, "a snapshot of the learner the report was made of"
        values = edge_weights(model.tree, *self.states, self.edges)
        self.traces[label] = {e: w[self.along] for e, w in values.items()}
        return summarize_weights(values)


@dataclass
class LearnerEval:
    """One learner evaluated at every snapshot; ``final`` holds the metrics at ``train.iterations``."""

    final: dict
    final_rollout: Any
    snapshots: dict[str, dict] = field(default_factory=dict)
    panels: list[dict] = field(default_factory=list)  # test environment 0 per snapshot: the progression figure
    task_stages: list[StageResult] = field(default_factory=list)
    weights: WeightReport | None = None
    seconds: float = 0.0


class _SnapshotEvaluator:
    """Evaluates one learner's snapshots against the expert on the test split."""

    def __init__(self, exp: Experiment, name: str, splits: Splits, expert: ExpertEval):
        self.exp, self.name, self.splits, self.expert = exp, name, splits, expert
        self.plot_idx = exp.environment_0(splits.test)[0]

    def with_task(self, met: dict, ro, it: int, out: LearnerEval) -> dict:
        if self.expert.stage is None or not isinstance(self.exp.env, HasTaskMetrics):
            return met  # the expert has task metrics exactly when the environment does
        ev = self.exp.run.eval
        label = f"learner-{it}" if len(self.exp.run.learners) == 1 else f"{self.name}-{it}"  # the paper's names
        st = task_stage(
            label,
            ro,
            self.exp.env,
            self.expert.stage,
            ev.lyapunov_rtol,
            ev.lyapunov_atol,
            learner=self.name,
            iteration=it,
        )
        out.task_stages.append(st)
        self.exp.say.say(f"{label}: " + task_line(st))
        return {**met, "task": st.summary, "ratio_to_expert": st.ratios, "lyapunov": st.lyapunov}

    def metrics(self, model: Learner, bar_label: str):
        exp, ev = self.exp, self.exp.run.eval
        return evaluate_learner(
            model,
            exp.expert_at(),
            exp.env,
            self.splits.test,
            exp.horizon,
            exp.expert_data.interval,
            ev.lyapunov_rtol,
            ev.lyapunov_atol,
            exp.fine_interval,
            exp.say.bar(bar_label),
            loss=lambda m, ds: dataset_loss(m, ds, exp.run.train.batch_loss_objective),
        )

    def snapshot(self, model: Learner, it: int, out: LearnerEval):
        met, onl = self.metrics(model, f"eval {self.name}@{it}")
        met = self.with_task(met, onl.rollout, it, out)
        if self.splits.val is not None:
            met["val_loss"] = dataset_loss(model, self.splits.val, self.exp.run.train.batch_loss_objective)
        if out.weights is not None:
            met["weights"] = out.weights.snapshot(f"{self.name} @ {it}", model)
        if learned := model.learned_numbers():
            met["learned_leaf_parameters"] = learned
        ro = onl.rollout
        out.snapshots[str(it)] = clean(met)
        out.panels.append(
            {
                "label": f"{self.name} @ {it}",
                "q": ro.q[:, self.plot_idx],
                "times": ro.times,
                "V": ro.V[:, self.plot_idx] if ro.V is not None else None,
            }
        )
        self.exp.log_scalars(
            self.name,
            {"iteration": float(it), **{f"snapshot_{k}": v for k, v in met.items() if isinstance(v, (int, float))}},
        )
        return met, onl


def evaluate_model(exp: Experiment, model: Learner, splits: Splits, label: str):
    """One model's metrics on the test split and its online rollout (``rmpfusion-evaluate-checkpoint``)."""
    return _SnapshotEvaluator(exp, label, splits, ExpertEval(None, {}, None)).metrics(model, label)


def evaluate_fitted(exp: Experiment, name: str, fitted: Fitted, splits: Splits, expert: ExpertEval) -> LearnerEval:
    """Every snapshot of one trained learner, in float64 (docs/math.md §11); the model is left in its dtype."""
    t0 = time.time()
    model = fitted.model
    dtype = next(model.parameters()).dtype
    model.to(torch.float64)
    if compiles(exp.run.eval):
        model.compile()
        exp.say.say(COMPILING.format(what=f"learner {name} for evaluation"))
    ev = _SnapshotEvaluator(exp, name, splits, expert)
    out = LearnerEval(final={}, final_rollout=None)
    if model.tree is not None:
        out.weights = WeightReport(exp, model, splits.test)
    final = None
    for it in sorted(fitted.result.snapshots):
        met, onl = ev.snapshot(load_snapshot(model, fitted.result.snapshots[it]).to(torch.float64), it, out)
        if it == exp.run.train.iterations:
            final = (met, onl)
    if final is None:  # the trained learner is not among the snapshots: evaluate it as it is
        met, onl = ev.metrics(model, f"eval {name}")
        met = ev.with_task(met, onl.rollout, exp.run.train.iterations, out)
        if splits.val is not None:
            met["val_loss"] = dataset_loss(model, splits.val, exp.run.train.batch_loss_objective)
        final = (met, onl)
    out.final, out.final_rollout = final[0], final[1].rollout
    if model.tree is not None:
        out.final["certificate"] = certificate(model, out.final_rollout, splits.test.initial_states()[2])
    flag_divergence(exp, name, out)
    model.to(dtype)
    out.seconds = time.time() - t0
    return out


def flag_divergence(exp: Experiment, name: str, out: LearnerEval) -> None:
    """A trained learner whose test rollouts diverge is kept and evaluated (it is a result), but said loudly: in
    the console and as ``diverged`` in its metrics (absent for a learner that did not)."""
    ro = out.final_rollout
    found = divergence(ro.q, ro.qd, ro.V, theorem2_applies=not ro.moving)
    if found is None:
        return
    out.final["diverged"] = found.as_dict()
    exp.say.say(
        f"WARNING: learner {name} DIVERGED on {len(found.samples)} of {found.total} test rollouts: "
        f"{found.reason}; its metrics describe a policy that does not work (metrics.json: "
        f"learners.{name}.diverged)"
    )


def evaluate(
    exp: Experiment, splits: Splits, fitted: dict[str, Fitted], expert: ExpertEval | None = None
) -> tuple[ExpertEval, dict[str, LearnerEval]] | RecordedEval:
    """The expert (unless its evaluation is given), then every learner in config order; on recorded demonstrations
    (no expert), the configured tree and every learner against the held-out demonstrations (``recorded.py``)."""
    if splits.demos is not None and splits.every_demo is not None:
        return evaluate_recorded(exp, fitted, evaluation_batch(exp, splits.demos, splits.every_demo))
    expert = expert if expert is not None else evaluate_expert(exp, splits.test)
    return expert, {name: evaluate_fitted(exp, name, f, splits, expert) for name, f in fitted.items()}
