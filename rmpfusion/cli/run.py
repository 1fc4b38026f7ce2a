"""``rmpfusion-run`` and the stage commands ``rmpfusion-collect`` / ``-train`` / ``-evaluate``.

All are the same Hydra app over conf/: compose, validate (nothing runs on an invalid config), then hand
the RunConfig to the experiment pipeline with the stages the command stands for. Stages share the run
directory: collect writes the datasets, train reads them and writes checkpoints, evaluate reads the
checkpoints; point a later stage at an earlier run with ``hydra.run.dir=outputs/...``.

``rmpfusion-run`` returns the run's objective (lower is better) so the Optuna sweeper can minimise it.
"""
from __future__ import annotations

import sys
from pathlib import Path

import hydra
from omegaconf import DictConfig

from ._common import CONF_DIR, Job, config_errors_exit, job

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


def _collect(run, run_dir: Path, say):
    from ..build.tree import build_tree
    from ..pipeline import run as pipeline
    from ..pipeline.validate import expert_spec

    env = pipeline.make_env(run)
    expert = build_tree(expert_spec(run), aux_dims=env.aux_dims())
    data = pipeline.load_splits(run, env, expert, run_dir, say)
    return env, expert, {s: ds for s, (ds, _) in data.items()}, {s: info for s, (_, info) in data.items()}


def _experiment(j: Job) -> float | None:
    from ..pipeline.run import run_experiment

    with config_errors_exit():
        result = run_experiment(j.run, j.dir, progress=True, log=j.logger.log, threads=THREADS)
    for name, res in (result.get("learners") or {}).items():
        if res.get("resumed_from") is not None:
            print(f"learner {name}: resumed from the checkpoint at iteration {res['resumed_from']}")
    j.logger.finish(result)
    return _objective(result)


@hydra.main(version_base="1.3", config_path=CONF_DIR, config_name="config")
def main(cfg: DictConfig) -> float | None:
    """The whole experiment: demonstrations, training, evaluation, figures, metrics.json.

    Rerun with the same overrides and ``hydra.run.dir`` to resume a killed run: data is reused and training
    continues from the last checkpoint."""
    with job(cfg, THREADS) as j:
        return _experiment(j)


@hydra.main(version_base="1.3", config_path=CONF_DIR, config_name="config")
def collect(cfg: DictConfig) -> None:
    """Stage 1: the expert's demonstrations, written (checksummed) into the run directory."""
    from ..pipeline.run import Progress

    with job(cfg, THREADS, log=False) as j:
        *_, info = _collect(j.run, j.dir, Progress(True))
        for split, i in info.items():
            print(f"{split}: {i['points']} points in {i['path']}{' (reused)' if i.get('reused') else ''} "
                  f"sha256 {i['sha256']}")


@hydra.main(version_base="1.3", config_path=CONF_DIR, config_name="config")
def train(cfg: DictConfig) -> None:
    """Stage 2: train every learner on the run directory's demonstrations (collected first if absent);
    checkpoints go to checkpoints/<learner>/, and a rerun resumes from them (also after SIGKILL; SIGTERM and
    Ctrl-C write a checkpoint before stopping)."""
    import torch

    from ..pipeline import run as pipeline
    from ..learn.learners import build_learner, build_order
    from ..learn.train import train as train_model

    with job(cfg, THREADS) as j:
        run, run_dir, log = j.run, j.dir, j.logger.log
        say = pipeline.Progress(True)
        env, expert, data, _ = _collect(run, run_dir, say)
        blocks = {n: b.model_dump() for n, b in run.learners.items()}
        built: dict = {}
        for name in build_order(blocks):  # the pipeline's seeds, so rmpfusion-evaluate resumes the same runs
            with torch.random.fork_rng():
                torch.manual_seed(pipeline._learner_seed(run.seed, name))
                built[name] = build_learner(blocks[name], run.tree, env.aux_dims(), expert.dim, expert=run.expert,
                                            built=built, where=f"learners.{name}")
        summary: dict = {}
        for name in run.learners:
            ckdir = run_dir / "checkpoints" / name
            tr = train_model(built[name], data["train"], run.train, seed=pipeline._learner_seed(run.seed, name) + 1,
                             test_data=data["test"], val_data=data.get("val"), checkpoint_dir=ckdir,
                             run_config=run.model_dump(), progress=say.bar(f"train {name}"),
                             log=(lambda m, _n=name: log({f"{_n}/{k}": v for k, v in m.items()})) if log else None)
            if tr.resumed_from is not None:
                print(f"learner {name}: resumed from iteration {tr.resumed_from} ({ckdir})")
            last = tr.curve[-1][1] if tr.curve else float("nan")
            print(f"learner {name}: {run.train.iterations} iterations, final train loss {last:.4g}")
            summary[name] = {"final_train_loss": last, "resumed_from": tr.resumed_from}
        j.logger.finish({"learners": summary})


@hydra.main(version_base="1.3", config_path=CONF_DIR, config_name="config")
def evaluate(cfg: DictConfig) -> float | None:
    """Stage 3: evaluate trained learners (rollouts, Lyapunov monitor, figures, metrics.json).

    Needs the checkpoints rmpfusion-train left in the same run directory; nothing is retrained.
    """
    from ..learn.train import latest_checkpoint

    with job(cfg, THREADS) as j:
        missing = []
        for name in j.run.learners:
            ck = latest_checkpoint(j.dir / "checkpoints" / name)
            if ck is None or int(torch_load_iteration(ck)) < j.run.train.iterations:
                missing.append(name)
        if missing:
            print(f"error: no fully trained checkpoints for {missing} in {j.dir / 'checkpoints'}; run rmpfusion-train "
                  f"with the same overrides and hydra.run.dir={j.dir} first", file=sys.stderr)
            sys.exit(1)
        return _experiment(j)


def torch_load_iteration(path: Path) -> int:
    import torch

    return int(torch.load(path, map_location="cpu", weights_only=True)["iteration"])


if __name__ == "__main__":
    main()
