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


def evaluate_checkpoint(path: str | Path, out: str | Path | None = None, figures: bool = True,
                        progress: bool = True) -> dict:
    """Metrics of the learner in checkpoint ``path`` on its run's test set (see the module docstring)."""
    import torch

    from ..pipeline.config import RunConfig, upgrade_run_config
    from ..build.tree import build_tree
    from ..evaluate.metrics import evaluate_learner
    from ..files import atomic_write_json
    from ..pipeline import run as pipeline
    from ..learn.learners import build_learner, build_order
    from ..learn.train import CheckpointError, load_checkpoint

    path = Path(path)
    state = load_checkpoint(path)  # missing, damaged or tampered files raise, naming the file and the fix
    if not state.get("config"):
        raise CheckpointError(f"checkpoint file {path} carries no run config (it was written outside an experiment); "
                              "evaluate it with rmpfusion-evaluate and the run's overrides instead")
    cfg = RunConfig.model_validate(upgrade_run_config(state["config"]))  # renamed keys of older checkpoints
    name = path.parent.name
    if name not in cfg.learners:
        raise CheckpointError(f"checkpoint file {path} lies in checkpoints/{name}/ but its config has learners "
                              f"{sorted(cfg.learners)}; keep checkpoints in the directory training wrote them to")
    run_dir = path.parents[2] if len(path.parents) > 2 else path.parent
    out = Path(out) if out is not None else path.parent / f"eval-{int(state['iteration']):08d}"
    out.mkdir(parents=True, exist_ok=True)
    say = pipeline.Progress(progress)

    torch.set_num_threads(1)
    env = pipeline.make_env(cfg)
    aux_dims = env.aux_dims()
    expert = build_tree(pipeline.expert_spec(cfg), aux_dims=aux_dims)
    blocks = {n: b.model_dump() for n, b in cfg.learners.items()}
    built: dict[str, torch.nn.Module] = {}
    for n in build_order(blocks):  # the learners this one's size is matched to, then itself
        built[n] = build_learner(blocks[n], cfg.tree, aux_dims, expert.dim, expert=cfg.expert, built=built,
                                 where=f"learners.{n}")
        if n == name:
            break
    model = built[name]
    load_checkpoint(path, model)  # the weights must fit this learner
    model.load_state_dict(state["model"])
    model.to(torch.float64)

    test_ds, test_info = pipeline.load_or_collect(cfg, env, expert, run_dir, "test", say)
    d, ev = cfg.data, cfg.eval
    horizon = ev.horizon if ev.horizon is not None else d.points * d.interval
    fine = pipeline._fine_record(env, d.interval)
    say.say(f"eval: {name} at iteration {int(state['iteration'])} from {path}")
    metrics, online = evaluate_learner(model, expert, env, test_ds, horizon, d.interval, ev.lyapunov_rtol,
                                       ev.lyapunov_atol, fine, say.bar(f"eval {name}"))
    result = {"checkpoint": str(path), "learner": name, "iteration": int(state["iteration"]),
              "test_data": test_info, "metrics": pipeline._clean(metrics), "figures": []}
    if figures:
        per_env = min(d.test_trajectories, len(test_ds.initial_states()[0]))
        result["figures"] = [str(p) for p in _figures(env, test_ds, online.rollout, out, name, per_env)]
    atomic_write_json(out / "metrics.json", result)
    say.say(f"wrote {out / 'metrics.json'}: " + ", ".join(f"{k}={v:.4g}" for k, v in metrics.items()
                                                           if isinstance(v, float)))
    return result


def _figures(env, test_ds, ro, out: Path, name: str, per_env: int) -> list[Path]:
    """Trajectories and V_r(t) in test environment 0 for 2D environments; a render of the first rollout's start
    and end for environments that render (the Franka Panda)."""
    import numpy as np

    from ..plots import plot_lyapunov, plot_trajectories
    from ..plots.figures import save_figure

    q0, qd0, aux0 = test_ds.initial_states()
    paths: list[Path] = []
    if ro.V is not None:
        paths.append(plot_lyapunov(out / f"lyapunov_{name}.png", ro.times, ro.V, title=f"{name}: $V_r(t)$"))
    if q0.shape[-1] == 2:
        idx = slice(0, per_env)  # test environment 0 (initial states are environment-major)
        aux_plot = {k: v[:1] for k, v in aux0.items()}
        paths.append(plot_trajectories(out / f"trajectories_{name}.png", aux_plot, None, {name: ro.q[:, idx]},
                                       q0[idx], qd0[idx], title=f"{name} from its checkpoint, test environment 0"))
    elif callable(getattr(env, "render", None)):
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        aux1 = {k: v[:1] for k, v in aux0.items()}
        frames = [env.render(ro.q[0, 0], aux1), env.render(ro.q[-1, 0].nan_to_num(), aux1)]
        fig, axes = plt.subplots(1, 2, figsize=(8, 3.2))
        for ax, img, title in zip(axes, frames, ("start", "end")):
            ax.imshow(np.asarray(img))
            ax.set_title(f"{name}: {title}")
            ax.axis("off")
        paths.append(save_figure(fig, out / f"render_{name}.png"))
    return paths


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="rmpfusion-evaluate-checkpoint", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("checkpoint", type=Path, help="a checkpoint written by training: checkpoints/<learner>/ckpt-*.pt")
    ap.add_argument("--out", type=Path, default=None, help="where metrics.json and figures go")
    ap.add_argument("--no-figures", action="store_true")
    a = ap.parse_args(argv)
    from ..learn.demonstrations import DatasetError
    from ..learn.train import CheckpointError

    try:
        evaluate_checkpoint(a.checkpoint, a.out, figures=not a.no_figures)
    except (CheckpointError, DatasetError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
