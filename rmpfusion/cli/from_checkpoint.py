"""``rmpfusion-evaluate-checkpoint CKPT``: evaluate (and render) a trained learner from its checkpoint alone.

A training checkpoint carries the run's resolved config next to the weights, so nothing else is needed: the
environment, the expert and the learner are rebuilt from it, the test set is read from the run directory's
cache (or collected again, reproducibly, from the seed), and the learner is rolled out on it. Writes
``metrics.json`` and figures (trajectories and V_r(t) for the 2D particle, renders for environments that can
render) into ``--out`` (default: ``eval-<iteration>/`` beside the checkpoint).

    rmpfusion-evaluate-checkpoint outputs/2d1level/<time>/checkpoints/rmp/ckpt-00020000.pt
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import torch

from ..envs.demonstrations import FORMAT as DATASET_FORMAT
from ..envs.protocol import PlanarWorkspace, Renders
from ..files import atomic_write_json, torch_file_format
from ..learn.checkpoints import CHECKPOINT_FORMAT, CHECKPOINT_NAME, CheckpointError, latest_checkpoint, load_checkpoint
from ..pipeline.collect import collect
from ..pipeline.config import RunConfig, upgrade_run_config
from ..pipeline.evaluation import evaluate_model
from ..pipeline.experiment import clean, prepare
from ..pipeline.fit import learners
from ..pipeline.progress import Progress
from ..pipeline.validate import device_problem, parse_run_config
from ..plots import plot_lyapunov, plot_trajectories
from ..plots.figures import save_figure, subplots
from ._common import user_errors_exit

_KINDS = {
    ".json": "a JSON file",
    ".yaml": "a YAML file",
    ".yml": "a YAML file",
    ".png": "an image",
    ".gif": "an animation",
    ".log": "a log file",
    ".md": "a text file",
    ".txt": "a text file",
}


def _checkpoints_below(directory: Path) -> list[Path]:
    """The newest checkpoint of each learner below a run directory, a checkpoints/ directory or a learner's."""
    inside = sorted(directory.glob("*")) if directory.name == "checkpoints" else []
    learners = [directory, *sorted(directory.glob("checkpoints/*")), *inside]
    return list(dict.fromkeys(ck for d in learners if d.is_dir() and (ck := latest_checkpoint(d)) is not None))


def _not_a_checkpoint(path: Path) -> str | None:
    """What ``path`` is when it is not a checkpoint file (said instead of a checkpoint error, whose advice is
    for damaged checkpoints only); None for a checkpoint, damaged or not."""
    if path.is_dir():
        found = _checkpoints_below(path)
        hint = (
            f"; its checkpoints: {', '.join(str(p) for p in found)}"
            if found
            else "; a checkpoint is checkpoints/<learner>/ckpt-<iteration>.pt in a run directory"
        )
        return f"{path} is a directory, not a checkpoint file{hint}"
    if not path.exists() or CHECKPOINT_NAME.match(path.name) or path.name == "final.pt":
        return None  # a missing or damaged checkpoint gets the checkpoint's own message
    if path.suffix in _KINDS:
        return (
            f"{path} is {_KINDS[path.suffix]}, not a checkpoint; a checkpoint is "
            "checkpoints/<learner>/ckpt-<iteration>.pt in a run directory"
        )
    tag = torch_file_format(path)
    if tag == CHECKPOINT_FORMAT:
        return None
    if tag == DATASET_FORMAT:
        return f"{path} is a dataset (demonstrations of a run's data/), not a checkpoint; nothing was changed"
    return (
        f"{path} is not a checkpoint written by rmpfusion ({tag or 'not a torch file it can read'}); nothing "
        "was changed"
    )


def _load(path: Path) -> tuple[dict, RunConfig, str]:
    """The checkpoint's state, its run's validated config and the learner it belongs to."""
    state = load_checkpoint(path)  # missing, damaged or tampered files raise, naming the file and the fix
    if not state.get("config"):
        raise CheckpointError(
            f"checkpoint file {path} carries no run config (it was written outside an experiment); "
            "evaluate it with rmpfusion-evaluate and the run's overrides instead"
        )
    run = parse_run_config(upgrade_run_config(state["config"]))  # renamed keys of older checkpoints
    name = path.parent.name
    if name not in run.learners:
        raise CheckpointError(
            f"checkpoint file {path} lies in checkpoints/{name}/ but its config has learners "
            f"{sorted(run.learners)}; keep checkpoints in the directory training wrote them to"
        )
    return state, run, name


def evaluate_checkpoint(
    path: str | Path, out: str | Path | None = None, figures: bool = True, progress: bool = True
) -> dict:
    """Metrics of the learner in checkpoint ``path`` on its run's test set (see the module docstring)."""
    path = Path(path)
    if (what := _not_a_checkpoint(path)) is not None:
        raise CheckpointError(what)
    state, run, name = _load(path)
    run_dir = path.parents[2] if len(path.parents) > 2 else path.parent
    out = Path(out) if out is not None else path.parent / f"eval-{int(state['iteration']):08d}"
    out.mkdir(parents=True, exist_ok=True)
    torch.set_num_threads(1)
    if (missing := device_problem(run.device)) is not None:
        print(
            f"rmpfusion: the run computed on {run.device}, which is not available here; evaluating on the CPU "
            f"({missing})",
            file=sys.stderr,
        )
        run = run.model_copy(update={"device": "cpu"})
    exp = prepare(run, run_dir, Progress(progress))
    model = learners(exp)[name]
    load_checkpoint(path, model)  # the weights must fit this learner
    model.load_state_dict(state["model"])
    model.to(torch.float64)
    splits = collect(exp, ("test",))
    exp.say.say(f"eval: {name} at iteration {int(state['iteration'])} from {path}")
    metrics, online = evaluate_model(exp, model, splits, f"eval {name}")
    result = {
        "checkpoint": str(path),
        "learner": name,
        "iteration": int(state["iteration"]),
        "test_data": splits.info["test"],
        "metrics": clean(metrics),
        "figures": [],
    }
    if figures:
        result["figures"] = [str(p) for p in _figures(exp, splits.test, online.rollout, out, name)]
    atomic_write_json(out / "metrics.json", result)
    exp.say.say(
        f"wrote {out / 'metrics.json'}: "
        + ", ".join(f"{k}={v:.4g}" for k, v in metrics.items() if isinstance(v, float))
    )
    return result


def _figures(exp, test_ds, ro, out: Path, name: str) -> list[Path]:
    """Trajectories and V_r(t) in test environment 0 for planar environments; a render of the first rollout's
    start and end for environments that render (a manipulator)."""
    _, _, aux0 = test_ds.initial_states()
    paths: list[Path] = []
    if ro.V is not None:
        paths.append(plot_lyapunov(out / f"lyapunov_{name}.png", ro.times, ro.V, title=f"{name}: $V_r(t)$"))
    if isinstance(exp.env, PlanarWorkspace):
        idx, q0_env, qd0_env, aux_plot = exp.environment_0(test_ds)
        paths.append(
            plot_trajectories(
                out / f"trajectories_{name}.png",
                aux_plot,
                None,
                {name: ro.q[:, idx]},
                q0_env,
                qd0_env,
                title=f"{name} from its checkpoint, test environment 0",
            )
        )
    elif isinstance(exp.env, Renders):
        aux1 = {k: v[:1] for k, v in aux0.items()}
        w, h = 320, 240  # a small two-frame summary, not the run's figure size
        frames = [exp.env.render(ro.q[0, 0], aux1, w, h, 0), exp.env.render(ro.q[-1, 0].nan_to_num(), aux1, w, h, 0)]
        fig, axes = subplots(1, 2, figsize=(8, 3.2))
        for ax, img, title in zip(axes, frames, ("start", "end")):
            ax.imshow(np.asarray(img))
            ax.set_title(f"{name}: {title}")
            ax.axis("off")
        paths.append(save_figure(fig, out / f"render_{name}.png"))
    return paths


def main(argv=None) -> int | str | None:
    ap = argparse.ArgumentParser(
        prog="rmpfusion-evaluate-checkpoint", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument(
        "checkpoint",
        type=Path,
        help="a checkpoint written by training: checkpoints/<learner>/ckpt-*.pt "
        "or the trained learner's checkpoints/<learner>/final.pt",
    )
    ap.add_argument("--out", type=Path, default=None, help="where metrics.json and figures go")
    ap.add_argument("--no-figures", action="store_true")
    a = ap.parse_args(argv)
    try:
        with user_errors_exit():
            evaluate_checkpoint(a.checkpoint, a.out, figures=not a.no_figures)
    except SystemExit as e:  # the message is printed; the status is returned (the console script exits with it)
        return e.code
    return 0


if __name__ == "__main__":
    sys.exit(main())
