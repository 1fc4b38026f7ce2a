"""``rmpfusion-run`` and the stage commands ``rmpfusion-collect`` / ``-train`` / ``-evaluate``.

All are the same Hydra app over conf/: compose, validate (nothing runs on an invalid config), then hand
the RunConfig to the experiment pipeline with the stages the command stands for. Stages share the run
directory: collect writes the datasets, train reads them and writes checkpoints, evaluate reads the
checkpoints; point a later stage at an earlier run with ``hydra.run.dir=outputs/...``.

``rmpfusion-run`` returns the run's objective (lower is better) so the Optuna sweeper can minimise it.
"""

from __future__ import annotations

from omegaconf import DictConfig

from ..pipeline.collect import collect as collect_stage
from ..pipeline.fit import fit
from ..pipeline.run import run_experiment, start
from ._common import Job, hydra_app, job, user_errors_exit

#: torch intra-op threads per job: the batches are small, extra threads only contend (see pipeline/run.py)
THREADS = 1


def _objective(result) -> float | None:
    """The scalar a sweeper minimises: the pipeline's ``objective`` if it reports one, else the first
    learner's final test loss."""
    if not isinstance(result, dict):
        return None
    if isinstance(result.get("objective"), (int, float)):
        return float(result["objective"])
    for res in (result.get("learners") or {}).values():
        for key in ("test_loss", "batch_loss", "final_train_loss"):
            if isinstance(res.get(key), (int, float)):
                return float(res[key])
    return None


def _experiment(j: Job, require_trained: bool = False) -> dict:
    with user_errors_exit():
        result = run_experiment(
            j.run, j.dir, progress=True, log=j.logger.log, threads=THREADS, require_trained=require_trained
        )
    for name, res in (result.get("learners") or {}).items():
        if res.get("resumed_from") is not None:
            print(f"learner {name}: resumed from the checkpoint at iteration {res['resumed_from']}")
    j.logger.finish(result)
    return result


def result_line(run_dir, result: dict) -> str:
    """The run's outcome in one line, printed after everything else (the logger's summary included)."""
    parts = []
    for name, res in (result.get("learners") or {}).items():
        found = {
            **res,
            "test_dtw": (res.get("reproduction_test") or {}).get("dtw"),
            "converged": (res.get("convergence") or {}).get("converged"),
        }
        shown = ", ".join(
            f"{k}={found[k]:.4g}"
            for k in ("online_loss", "batch_loss", "success", "collision", "test_dtw", "converged")
            if isinstance(found.get(k), (int, float))
        )
        flag = " DIVERGED" if res.get("diverged") else ""
        parts.append(f"learner {name}{flag}: {shown or 'no metrics'}")
    return f"result: {'; '.join(parts) or 'no learners'} ({run_dir / 'metrics.json'})"


def _finished(j_dir, result: dict) -> float | None:
    print(result_line(j_dir, result))
    return _objective(result)


@hydra_app
def main(cfg: DictConfig) -> float | None:
    """The whole experiment: demonstrations, training, evaluation, figures, metrics.json.

    Rerun with the same overrides and ``hydra.run.dir`` to resume a killed run: data is reused and training
    continues from the last checkpoint."""
    with job(cfg, THREADS) as j:
        result = _experiment(j)
    return _finished(j.dir, result)


@hydra_app
def collect(cfg: DictConfig) -> None:
    """Stage 1: the expert's demonstrations, written (checksummed) into the run directory."""
    with job(cfg, THREADS, log=False) as j, user_errors_exit():
        splits = collect_stage(start(j.run, j.dir))
        for split, i in splits.info.items():
            print(
                f"{split}: {i['points']} points in {i['path']}{' (reused)' if i.get('reused') else ''} "
                f"sha256 {i['sha256']}"
            )


@hydra_app
def train(cfg: DictConfig) -> None:
    """Stage 2: train every learner on the run directory's demonstrations (collected first if absent);
    checkpoints go to checkpoints/<learner>/, and a rerun resumes from them (also after SIGKILL; SIGTERM and
    Ctrl-C write a checkpoint before stopping)."""
    with job(cfg, THREADS) as j, user_errors_exit():
        exp = start(j.run, j.dir, log=j.logger.log)
        fitted = fit(exp, collect_stage(exp))
        summary: dict = {}
        for name, f in fitted.items():
            if f.result.resumed_from is not None:
                print(
                    f"learner {name}: resumed from iteration {f.result.resumed_from} ({j.dir / 'checkpoints' / name})"
                )
            last = f.result.curve[-1][1] if f.result.curve else float("nan")
            print(
                f"learner {name}: {j.run.train.iterations} iterations ({j.run.train.method}), final train "
                f"{f.result.measure} {last:.4g}"
            )
            summary[name] = {"final_train_loss": last, "resumed_from": f.result.resumed_from}
        j.logger.finish({"learners": summary})


@hydra_app
def evaluate(cfg: DictConfig) -> float | None:
    """Stage 3: evaluate trained learners (rollouts, Lyapunov monitor, figures, metrics.json).

    Needs the checkpoints rmpfusion-train left in the same run directory; nothing is retrained.
    """
    with job(cfg, THREADS) as j:
        result = _experiment(j, require_trained=True)
    return _finished(j.dir, result)


if __name__ == "__main__":
    main()
