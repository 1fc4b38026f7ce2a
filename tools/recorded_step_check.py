#!/usr/bin/env python
"""Re-evaluate a finished recorded-demonstrations run's trained learner on finer integration steps, without
training it again.

When a run warns that V_r rose on some rollouts from rest (Theorem 2 forbids it in continuous time), this tells the
two causes apart: integration error shrinks as the step does (about fourfold per halving on a smooth rollout), a
wrong term in the tree does not. Each row is the same learner, the same held-out demonstrations and the same starts
at rest, integrated on the run's step divided by a factor:

    python tools/recorded_step_check.py <run dir> --divide 1 2      # the run's own step, then half of it

The first row (factor 1) reproduces the run's own metrics.json. Nothing is written to the run directory.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from rmpfusion.evaluate.lyapunov import max_relative_increase
from rmpfusion.pipeline.finished import finished_run
from rmpfusion.pipeline.recorded import evaluate_policy, evaluation_batch

#: a rise of V_r between records larger than this fraction of V_r's size fails the monotone check (its rtol)
RISE = 1e-6


def with_step_divided(config: dict, factor: float) -> dict:
    """The run config with its integration step divided by ``factor`` (the key depends on the environment)."""
    env = dict(config["env"])
    if "control_rate" in env:
        env["control_rate"] = env["control_rate"] * factor
    else:
        env["dt"] = env["dt"] / factor
    return {**config, "env": env}


def check(run_dir: Path, factor: float, learner: str = "rmp") -> dict:
    """The final ``learner`` of the run in ``run_dir`` evaluated on the run's step divided by ``factor``."""
    # the split datasets on the new grid go into the scratch directory, not into the run
    with finished_run(run_dir, learner, lambda config: with_step_divided(config, factor)) as f:
        exp, model = f.exp, f.model
        batch = evaluation_batch(exp, f.demos, f.every)
        res, ro = evaluate_policy(exp, f"{learner} at dt/{factor:g}", model.policy, batch, model.tree)
    rise = max_relative_increase(ro.V[:, batch.grid])
    failing = rise[rise > RISE]
    return {
        "dt": exp.env.dt,
        "monotone": res["convergence"]["lyapunov_monotone_fraction"],
        "worst_rise": float(rise.max()),
        "median_failing_rise": float(failing.median()) if failing.numel() else 0.0,
        "converged": res["convergence"]["converged"],
        "test_dtw": res["reproduction_test"]["dtw"],
    }


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("run_dir", type=Path, help="a finished run of recorded demonstrations")
    ap.add_argument("--divide", type=float, nargs="+", default=[1.0, 2.0], help="factors to divide the step by")
    ap.add_argument("--learner", default="rmp")
    a = ap.parse_args(argv)
    if not (a.run_dir / "checkpoints" / a.learner / "final.pt").is_file():
        print(f"{a.run_dir}: no checkpoints/{a.learner}/final.pt; give a finished run's directory", file=sys.stderr)
        return 1
    print("| step (s) | V_r monotone | worst rise (of V_r) | median rise where it rose | converged | test DTW |")
    print("|---|---|---|---|---|---|")
    for factor in a.divide:
        r = check(a.run_dir, factor, a.learner)
        print(
            f"| {r['dt']:g} | {r['monotone']:.0%} | {r['worst_rise']:.3g} | {r['median_failing_rise']:.3g} | "
            f"{r['converged']:.0%} | {r['test_dtw']:.4g} |"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
