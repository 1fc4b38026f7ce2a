#!/usr/bin/env python
"""Policy optimisation through the simulator on 2d2level (experiment=2d2level train=apg): the tree optimised by APG
against the expert and against the same tree with unit weights (RMPflow), on the test split's starts: one run of
the training_methods study (conf/study/training_methods.yaml).

Runs the experiment (no expert data in training; conf/train/apg.yaml), then evaluates the unit-weight tree with
the pipeline's own evaluation, and the task cost APG minimises on the test starts for every policy. Writes
<out>/table.md and <out>/metrics.json (the rows, with the run's command, seed and wall time: what results/ stores and
``rmpfusion-study table training_methods`` turns back into the documentation's table) beside the run directory <out>/run/
(its own metrics.json; figures/learning_curve_rmp.png is the learning curve, figures/progression_rmp.png the
snapshots' trajectories).

    python tools/apg_rows.py                     # conf/train/apg.yaml as it is
    python tools/apg_rows.py --table-only        # the table of the run already in --out
    python tools/apg_rows.py train.iterations=20 train.snapshots=[0,20]   # any overrides
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
import time
from pathlib import Path

import torch

from rmpfusion.evaluate.lyapunov import lyapunov_monotone
from rmpfusion.evaluate.metrics import summarize
from rmpfusion.files import atomic_write_json
from rmpfusion.learn.learners import build_learner
from rmpfusion.learn.loop import load_snapshot
from rmpfusion.learn.methods.apg import RolloutCost
from rmpfusion.pipeline.collect import collect
from rmpfusion.pipeline.compose import compose_run
from rmpfusion.pipeline.construct import UNIT_WEIGHT_LEARNER
from rmpfusion.pipeline.evaluation import evaluate_model
from rmpfusion.pipeline.fit import fit
from rmpfusion.pipeline.run import run_experiment, start
from rmpfusion.studies.tables.apg import table

TASK = ("time", "path_length", "final_distance", "min_clearance")


#: the run this tool makes unless told otherwise: 2d2level trained by APG
DEFAULT_RUN = ["experiment=2d2level", "train=apg", "eval=eager", "name=2d2level_apg"]


def config(overrides: list[str]):
    """The validated run of ``overrides`` (the whole run: experiment and method), wandb off."""
    return compose_run([*overrides, "logger=disabled"])


def unit_weights(exp):
    """learner-rmp's tree with every learned edge at weight 1: RMPflow's combination of the same leaves."""
    return build_learner(
        UNIT_WEIGHT_LEARNER,
        exp.run.tree.model_dump(),
        exp.env.aux_dims(),
        exp.env.dim,
        expert={k: {} for k in exp.run.expert},
    )


def _row(label: str, task: dict, rates: dict, cost: float, fine: float) -> dict:
    return {
        "policy": label,
        "success": rates.get("success"),
        "collision": rates.get("collision"),
        "lyapunov": rates.get("lyapunov_monotone_fraction"),
        "lyapunov_fine": fine,
        "cost": cost,
        **{k: task[k]["mean"] for k in TASK if k in task},
    }


def monotone_on_a_finer_step(exp, policy, starts, dt: float) -> float:
    """The fraction of the test rollouts whose V_r never rises when integrated on the step ``dt``: tells an
    integration error of the experiment's step (on stiff learned dynamics) from a policy that breaks Theorem 2."""
    ev = exp.run.eval
    with torch.no_grad():
        ro = exp.env.with_step(dt).rollout(policy, *starts, horizon=exp.horizon, record_every=exp.fine_interval)
    return float(lyapunov_monotone(ro.V, ev.lyapunov_rtol, ev.lyapunov_atol).double().mean())


def rows(run_dir: Path, cfg, fine_dt: float) -> list[dict]:
    """Expert, unit weights and every snapshot of the optimised tree on the test starts."""
    exp = start(cfg, run_dir, progress=False)
    splits = collect(exp)
    fitted = fit(exp, splits, require_trained=True)["rmp"]
    model = fitted.model.to(torch.float64)
    metrics = json.loads((run_dir / "metrics.json").read_text())
    cost = RolloutCost(exp.env, exp.run.train)
    starts = splits.test.initial_states()

    def task_cost(policy) -> float:
        with torch.no_grad():
            return cost(policy, *starts, backward=False)["total"]

    fine = lambda policy: monotone_on_a_finer_step(exp, policy, starts, fine_dt)
    out = [
        _row(
            "expert",
            metrics["expert"]["task"],
            metrics["expert"],
            task_cost(lambda q, qd, a: exp.expert(q, qd, a).qdd),
            fine(exp.expert),
        )
    ]
    unit = unit_weights(exp)
    met, onl = evaluate_model(exp, unit, splits, "unit weights")
    out.append(
        _row(
            "unit weights (RMPflow)",
            summarize(exp.env.task_metrics(onl.rollout)),
            met,
            task_cost(unit),
            fine(unit.policy),
        )
    )
    for it, state in sorted(fitted.result.snapshots.items()):
        s = metrics["learners"]["rmp"]["snapshots"][str(it)]
        snap = load_snapshot(model, state)
        label = f"APG @ {it}" + (" (learner-0)" if it == 0 else "")
        out.append(_row(label, s["task"], s, task_cost(snap), fine(snap.policy)))
        out[-1]["leaves"] = s.get("learned_leaf_parameters")
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, default=Path("outputs/apg_rows"))
    ap.add_argument("--table-only", action="store_true", help="run nothing new: the table of <out>/run")
    ap.add_argument(
        "--fine-dt",
        type=float,
        default=0.002,
        help="the finer RK4 step on which every policy's V_r is checked again (s)",
    )
    ap.add_argument(
        "overrides",
        nargs="*",
        help=f"Hydra overrides: the whole run where they name its experiment, else added to {' '.join(DEFAULT_RUN)}",
    )
    a = ap.parse_args(argv)
    t0 = time.time()
    names_its_run = any(o.startswith("experiment=") for o in a.overrides)
    overrides = a.overrides if names_its_run else [*DEFAULT_RUN, *a.overrides]
    cfg = config(overrides)
    if not a.table_only:
        run_experiment(cfg, a.out / "run")
    rs = rows(a.out / "run", cfg, a.fine_dt)
    run = json.loads((a.out / "run" / "metrics.json").read_text())
    md = (
        f"# {cfg.name}: the tree optimised through the simulator vs the expert and unit weights "
        f"({time.time() - t0:.0f} s)\n\n" + table(rs, cfg.env.dt, a.fine_dt)
    )
    command = "python tools/apg_rows.py " + shlex.join([f"--fine-dt={a.fine_dt}", *overrides])
    atomic_write_json(
        a.out / "metrics.json",
        {
            "command": command,
            "experiment": cfg.name,
            "seed": run["seed"],
            "timing": {"total_s": run["timing"]["total_s"]},
            "dt": cfg.env.dt,
            "fine_dt": a.fine_dt,
            "rows": rs,
        },
    )
    (a.out / "table.md").write_text(md)
    print(md)
    return 0


if __name__ == "__main__":
    sys.exit(main())
