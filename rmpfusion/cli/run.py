"""``rmpfusion-run`` and the stage commands ``rmpfusion-collect`` / ``-train`` / ``-evaluate``.

All are the same Hydra app over conf/: compose, validate (nothing runs on an invalid config), then hand
the RunConfig to the experiment pipeline with the stages the command stands for. Stages share the run
directory: collect writes the datasets, train reads them and writes checkpoints, evaluate reads the
checkpoints; point a later stage at an earlier run with ``hydra.run.dir=outputs/...``.

``rmpfusion-run`` returns the run's objective (lower is better) so the Optuna sweeper can minimise it.
"""
from __future__ import annotations

import contextlib
import sys
from pathlib import Path

import hydra
from omegaconf import DictConfig

from ._common import CONF_DIR, config_errors_exit, hydra_run_dir, save_resolved


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


@contextlib.contextmanager
def _wandb_log(run, run_dir: Path):
    """One wandb run per job (so per sweep point), writing into the run directory; None when disabled."""
    if run.logger.mode == "disabled":
        yield None
        return
    import wandb

    lg = run.logger
    wb = wandb.init(project=lg.project, entity=lg.entity, tags=list(lg.tags), group=lg.group or run.name,
                    name=f"{run.name}-seed{run.seed}", mode=lg.mode, dir=str(run_dir),
                    config=run.model_dump(mode="json"), reinit=True)
    try:
        yield wb.log
    finally:
        wb.finish()


def _validated(cfg: DictConfig):
    from ..config.validate import resolve_and_validate

    with config_errors_exit():
        run = resolve_and_validate(cfg)
    run_dir = hydra_run_dir()
    save_resolved(run, run_dir)
    return run, run_dir


def _collect(run, run_dir: Path, say):
    from ..core.tree import build_tree
    from ..learn import pipeline
    from ..config.validate import expert_spec

    env = pipeline.make_env(run)
    expert = build_tree(expert_spec(run), aux_dims=env.aux_dims())
    train_ds, info_tr = pipeline.load_or_collect(run, env, expert, run_dir, "train", say)
    test_ds, info_te = pipeline.load_or_collect(run, env, expert, run_dir, "test", say)
    return env, expert, train_ds, test_ds, {"train": info_tr, "test": info_te}


@hydra.main(version_base="1.3", config_path=CONF_DIR, config_name="config")
def main(cfg: DictConfig) -> float | None:
    """The whole experiment: demonstrations, training, evaluation, figures, metrics.json."""
    from ..learn.pipeline import run_experiment

    run, run_dir = _validated(cfg)
    with _wandb_log(run, run_dir) as log, config_errors_exit():
        result = run_experiment(run, run_dir, progress=True, log=log)
    return _objective(result)


@hydra.main(version_base="1.3", config_path=CONF_DIR, config_name="config")
def collect(cfg: DictConfig) -> None:
    """Stage 1: the expert's demonstrations, written (checksummed) into the run directory."""
    from ..learn.pipeline import Progress

    run, run_dir = _validated(cfg)
    *_, info = _collect(run, run_dir, Progress(True))
    for split, i in info.items():
        print(f"{split}: {i['points']} points in {i['path']}{' (reused)' if i.get('reused') else ''}")


@hydra.main(version_base="1.3", config_path=CONF_DIR, config_name="config")
def train(cfg: DictConfig) -> None:
    """Stage 2: train every learner on the run directory's demonstrations (collected first if absent);
    checkpoints go to checkpoints/<learner>/, and a rerun resumes from them."""
    import torch

    from ..learn import pipeline
    from ..learn.learners import build_learner, build_order
    from ..learn.train import train as train_model

    run, run_dir = _validated(cfg)
    say = pipeline.Progress(True)
    env, expert, train_ds, test_ds, _ = _collect(run, run_dir, say)
    blocks = {n: b.model_dump() for n, b in run.learners.items()}
    built: dict = {}
    with _wandb_log(run, run_dir) as log:
        for name in build_order(blocks):  # the pipeline's seeds, so rmpfusion-evaluate resumes the same runs
            with torch.random.fork_rng():
                torch.manual_seed(pipeline._learner_seed(run.seed, name))
                built[name] = build_learner(blocks[name], run.tree, env.aux_dims(), expert.dim, expert=run.expert,
                                            built=built, where=f"learners.{name}")
        for name in run.learners:
            tr = train_model(built[name], train_ds, run.train, seed=pipeline._learner_seed(run.seed, name) + 1,
                             test_data=test_ds, checkpoint_dir=run_dir / "checkpoints" / name,
                             run_config=run.model_dump(), progress=say.bar(f"train {name}"),
                             log=(lambda m, _n=name: log({f"{_n}/{k}": v for k, v in m.items()})) if log else None)
            last = tr.curve[-1][1] if tr.curve else float("nan")
            print(f"learner {name}: {run.train.iterations} iterations, final train loss {last:.4g}")


@hydra.main(version_base="1.3", config_path=CONF_DIR, config_name="config")
def evaluate(cfg: DictConfig) -> float | None:
    """Stage 3: evaluate trained learners (rollouts, Lyapunov monitor, figures, metrics.json).

    Needs the checkpoints rmpfusion-train left in the same run directory; nothing is retrained.
    """
    from ..learn.pipeline import run_experiment
    from ..learn.train import latest_checkpoint

    run, run_dir = _validated(cfg)
    missing = []
    for name in run.learners:
        ck = latest_checkpoint(run_dir / "checkpoints" / name)
        if ck is None or int(torch_load_iteration(ck)) < run.train.iterations:
            missing.append(name)
    if missing:
        print(f"error: no fully trained checkpoints for {missing} in {run_dir / 'checkpoints'}; run rmpfusion-train "
              f"with the same overrides and hydra.run.dir={run_dir} first", file=sys.stderr)
        sys.exit(1)
    with _wandb_log(run, run_dir) as log, config_errors_exit():
        result = run_experiment(run, run_dir, progress=True, log=log)
    return _objective(result)


def torch_load_iteration(path: Path) -> int:
    import torch

    return int(torch.load(path, map_location="cpu", weights_only=True)["iteration"])


if __name__ == "__main__":
    main()
