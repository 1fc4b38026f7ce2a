"""``rmpfusion-view <run directory | config overrides>``: a robot, its scene and its rollouts in 3D, as one HTML page.

    rmpfusion-view outputs/franka/<time>          # a trained run: the expert and every learner snapshot
    rmpfusion-view experiment=franka              # a config: the expert and the same tree with unit weights
    rmpfusion-view --config-dir my_configs experiment=reach robot=my_arm   # a robot file of your own

For a run directory, the environment and the learners are rebuilt from the run's checkpoints (which carry the
resolved config), each snapshot training kept is loaded into its learner, and every policy is rolled out from
one start of the test split's distribution (drawn from the test split's seed). For a config, the expert and the
weightless tree (every weight 1: RMPflow) are rolled out the same way. The page (``plots/viewer.py``) opens with
no network; an existing file is never replaced unless ``--force`` says so.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import torch

from ..assembly.errors import ConfigError
from ..envs.demonstrations import DatasetError
from ..envs.manipulator import Manipulator
from ..learn.checkpoints import CheckpointError, latest_checkpoint, load_checkpoint
from ..learn.loop import load_snapshot
from ..pipeline.collect import SPLIT_SEED_OFFSET
from ..pipeline.compose import compose_config
from ..pipeline.config import DataConfig, RunConfig, upgrade_run_config
from ..pipeline.construct import build_unit_weights
from ..pipeline.experiment import Experiment, prepare
from ..pipeline.fit import learners
from ..pipeline.progress import Progress
from ..pipeline.validate import parse_run_config, resolve_and_validate
from ..plots.viewer import PolicyTrack, ViewerInput, viewer_figure, write_viewer
from ..registry import RegistryError
from ._common import one_line
from .rundir import RESOLVED


class ViewError(Exception):
    """Input the viewer cannot draw: said in one line, with what to do instead."""


# ------------------------------------------------------------------------------------------------ the inputs
def _run_config_of_directory(run_dir: Path) -> tuple[RunConfig, dict[str, Path]]:
    """The config a run's checkpoints carry, and each learner's newest checkpoint (the one holding its snapshots)."""
    if not run_dir.is_dir():
        raise ViewError(
            f"{run_dir} is not a directory; give a run directory (outputs/<experiment>/<time>) or config "
            "overrides such as experiment=franka"
        )
    ckroot = run_dir / "checkpoints"
    if not ckroot.is_dir():
        what = "a run directory that has not trained yet" if (run_dir / RESOLVED).is_file() else "not a run directory"
        raise ViewError(
            f"{run_dir} is {what}: it has no checkpoints/ (a run directory holds checkpoints/<learner>/"
            "ckpt-*.pt after rmpfusion-run or rmpfusion-train); to see the expert alone, give the "
            "run's overrides instead (e.g. experiment=franka)"
        )
    newest = {d.name: ck for d in sorted(ckroot.iterdir()) if (ck := latest_checkpoint(d)) is not None}
    if not newest:
        raise ViewError(f"{ckroot} holds no checkpoint (ckpt-<iteration>.pt); train the run first")
    state = load_checkpoint(next(iter(newest.values())))
    if not state.get("config"):
        raise ViewError(f"{next(iter(newest.values()))} carries no run config; view the run by its overrides instead")
    run = parse_run_config(upgrade_run_config(state["config"]))
    missing = [n for n in run.learners if n not in newest]
    if missing:
        raise ViewError(
            f"{ckroot} has no checkpoints for learners {missing} of the run's config; train them first "
            f"(rmpfusion-train with the run's overrides and hydra.run.dir={run_dir})"
        )
    return run, newest


def _run_config_of_overrides(overrides: list[str], config_dir: Path | None = None) -> RunConfig:
    """The config Hydra composes from ``overrides`` over conf/ (and ``config_dir``, a robot file of the user's own:
    ``robot=my_arm`` from ``<config_dir>/robot/my_arm.yaml``), validated as every command validates it."""
    from hydra.errors import HydraException
    from omegaconf.errors import OmegaConfBaseException

    if config_dir is not None and not config_dir.is_dir():
        raise ViewError(f"--config-dir {config_dir} is not a folder; give the folder your configs are in")
    try:
        cfg = compose_config(overrides, config_dir)
    except (HydraException, OmegaConfBaseException) as e:
        raise ViewError(f"the overrides {' '.join(overrides)} do not compose: {one_line(e)}") from None
    return resolve_and_validate(cfg)


def _check_manipulator(run: RunConfig) -> None:
    if run.env.type != "manipulator":
        raise ViewError(
            f"the viewer draws robots: experiment '{run.name}' runs the '{run.env.type}' environment; "
            "its figures are the run's figures/ (trajectories over the obstacles)"
        )


def _record_interval(run: RunConfig) -> float:
    """Seconds between the recorded points of a rollout: the demonstrations' ``data.interval``. Recorded
    demonstrations (``data.source: recorded``) have no such spacing and no expert to roll out, so such a run is
    refused in words."""
    if not isinstance(run.data, DataConfig):
        raise ViewError(
            f"experiment '{run.name}' learns from recorded demonstrations (data.source=recorded), which have no "
            "expert to roll out; its figures are the run's figures/"
        )
    return run.data.interval


# ------------------------------------------------------------------------------------------------ the rollouts
def _test_start(exp: Experiment):
    """One start of the test split's distribution: the test environments' scene, drawn from the test seed."""
    gen = torch.Generator().manual_seed(exp.run.seed + SPLIT_SEED_OFFSET["test"])
    envs = exp.env.sample_envs(1, gen, split="test")
    return exp.env.sample_initial_states(envs, 1, gen)


def _roll(exp: Experiment, policy, start, label: str) -> tuple[PolicyTrack, torch.Tensor]:
    q0, qd0, aux0 = start
    exp.say.say(f"view: rolling out {label}")
    ro = exp.env.rollout(policy, q0, qd0, aux0, horizon=exp.horizon, record_every=_record_interval(exp.run))
    return PolicyTrack(label, ro.q[:, 0]), ro.times


def _learner_policies(exp: Experiment, checkpoints: dict[str, Path]) -> list[tuple[str, torch.nn.Module]]:
    """Every learner at every snapshot its newest checkpoint holds, then trained (``final.pt``) when training finished
    at an iteration no snapshot has."""
    built, out = learners(exp), []
    for name, model in built.items():
        state = load_checkpoint(checkpoints[name], model)
        many = len(built) > 1
        for it, weights in sorted(state.get("snapshots", {}).items()):
            out.append((f"{name} @ {int(it)}" if many else f"learner @ {int(it)}", load_snapshot(model, weights)))
        final = checkpoints[name].parent / "final.pt"
        done = {int(i) for i in state.get("snapshots", {})}
        if final.is_file() and int(exp.run.train.iterations) not in done:
            model.load_state_dict(load_checkpoint(final, model)["model"])  # checked to fit the learner first
            out.append(
                (f"{name} @ {exp.run.train.iterations}" if many else f"learner @ {exp.run.train.iterations}", model)
            )
    return [(label, m.to(torch.float64).eval()) for label, m in out]


def _viewing(run: RunConfig, horizon: float | None) -> RunConfig:
    """``run`` as the viewer rolls it out: on the CPU, uncompiled (a few rollouts never repay torch.compile's
    minutes), for ``horizon`` seconds (default the run's evaluation horizon) rounded to whole records."""
    interval = _record_interval(run)
    ev: dict[str, bool | float] = {"compile": False}
    if horizon is not None:
        if not horizon > 0:
            raise ViewError(f"--horizon {horizon}: give a positive number of seconds")
        ev["horizon"] = max(1, round(horizon / interval)) * interval
    return run.model_copy(update={"device": "cpu", "eval": run.eval.model_copy(update=ev)})


def view_input(run: RunConfig, run_dir: Path | None, checkpoints: dict[str, Path] | None, say: Progress) -> ViewerInput:
    """What the page draws: the environment rebuilt from ``run``, its policies rolled out from one test start."""
    _check_manipulator(run)
    exp = prepare(run, run_dir or Path("."), say)
    start = _test_start(exp)
    policies: list[tuple[str, torch.nn.Module]] = [("expert", exp.expert)]
    if checkpoints is None:
        policies.append(("unit weights", build_unit_weights(run, exp.env.aux_dims())))
    else:
        policies += _learner_policies(exp, checkpoints)
    tracks, times = [], None
    for label, policy in policies:
        track, times = _roll(exp, policy, start, label)
        tracks.append(track)
    assert times is not None  # the expert is always rolled out
    # the environment's parameters, not the config's: a laid-out task (env.reach_layout) places and sizes the
    # obstacles from the arm's kinematics when the environment is built, and the rollouts ran in that scene
    assert isinstance(exp.env, Manipulator)  # _check_manipulator found the 'manipulator' environment
    params = exp.env.params
    scene = params.test_scene or params.scene
    aux0 = {k: v[0] for k, v in start[2].items()}
    source = run_dir if run_dir is not None else "config"
    return ViewerInput(
        robot=params.robot,
        scene=scene,
        aux=aux0,
        times=times,
        tracks=tracks,
        title=f"{run.name} ({source}): {params.robot.name}, one test start",
    )


# ------------------------------------------------------------------------------------------------ the command
def _parse(argv) -> argparse.Namespace:
    ap = argparse.ArgumentParser(
        prog="rmpfusion-view", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("target", nargs="+", help="a run directory, or Hydra overrides (key=value ...)")
    ap.add_argument(
        "--out",
        type=Path,
        default=None,
        help="the HTML file (default: <run directory>/viewer.html, or viewer-<experiment>.html here)",
    )
    ap.add_argument(
        "--config-dir",
        type=Path,
        default=None,
        help="a folder of configs added to rmpfusion's (your robot files), as the other commands' --config-dir",
    )
    ap.add_argument("--force", action="store_true", help="replace the output file if it exists")
    ap.add_argument("--frames", type=int, default=40, help="at most this many time-slider frames (default 40)")
    ap.add_argument(
        "--horizon",
        type=float,
        default=None,
        help="seconds each rollout lasts (default: the run's evaluation horizon, eval.horizon)",
    )
    return ap.parse_args(argv)


def _refuse_existing(out: Path | None, force: bool) -> None:
    if out is not None and out.exists() and not force:
        raise ViewError(f"{out} exists; nothing was written (pass --force to replace it, or --out another file)")


def view(
    target: list[str],
    out: Path | None = None,
    force: bool = False,
    frames: int = 40,
    horizon: float | None = None,
    progress: bool = True,
    config_dir: Path | None = None,
) -> Path:
    """Write the page for ``target`` (a run directory, or overrides); returns its path."""
    say = Progress(progress)
    _refuse_existing(out, force)
    is_directory = len(target) == 1 and "=" not in target[0]
    if not is_directory and (odd := [t for t in target if "=" not in t]):
        raise ViewError(f"{' '.join(odd)}: give one run directory, or config overrides written key=value")
    if is_directory:
        if config_dir is not None:
            raise ViewError("--config-dir is for config overrides: a run directory carries its resolved config")
        run_dir = Path(target[0])
        run, checkpoints = _run_config_of_directory(run_dir)
        out = out or run_dir / "viewer.html"
    else:
        run_dir, checkpoints = None, None
        run = _run_config_of_overrides(target, config_dir)
        out = out or Path(f"viewer-{run.name}.html")
    _refuse_existing(out, force)
    if frames < 2:
        raise ViewError(f"--frames {frames}: a time slider needs at least 2 frames")
    _check_manipulator(run)
    run = _viewing(run, horizon)
    torch.set_num_threads(1)
    path = write_viewer(viewer_figure(view_input(run, run_dir, checkpoints, say), max_frames=frames), out)
    say.say(f"wrote {path} ({path.stat().st_size / 1e6:.1f} MB, opens with no network)")
    return path


def main(argv=None) -> int:
    a = _parse(argv)
    try:
        view(a.target, a.out, a.force, a.frames, a.horizon, config_dir=a.config_dir)
    except (ViewError, CheckpointError, DatasetError, ConfigError, RegistryError) as e:
        print(f"error: {one_line(e) if not isinstance(e, ConfigError) else e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
