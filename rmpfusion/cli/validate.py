"""``rmpfusion-validate``: compose, validate and build a config without running anything.

Usage: ``rmpfusion-validate experiment=2d2level`` (any overrides; ``-m`` checks a whole sweep).
Exits 0 and prints a summary with the tree drawn as text, or exits 2 listing every problem.
"""

from __future__ import annotations

from omegaconf import DictConfig

from ..assembly.premises import check_premises
from ..assembly.spec import weight_label
from ..envs.protocol import JointSpace, LearnsFromRecordings
from ..evaluate.weights import learned_edges
from ..pipeline.construct import build_all
from ..pipeline.obstacle_entries import find_entries, summary_line
from ..pipeline.validate import resolve_and_validate
from ..recordings.source import ignored_line, on_grid_for, read_recordings, source_files
from ._common import discard_unclaimed, hydra_app, hydra_run_dir, user_errors_exit


def _cut(d, env) -> str:
    """What cutting at rests made of the files: how many demonstrations (read again: they are small)."""
    joints = env.robot_description.joints if isinstance(env, JointSpace) else None
    return f", cut at every rest of {d.cut_at_rest:g} s or more: {len(read_recordings(d, joints))} demonstrations"


def _read_lines(run, env) -> list[str]:
    """What reading the recordings found besides the demonstrations (read again: they are small): the columns left
    out, and the recordings that enter an obstacle of the run's world (validation refused them already unless
    ``data.obstacle_entries`` lets them through)."""
    d = run.data
    robot = env.robot_description if isinstance(env, JointSpace) else None
    recordings = read_recordings(d, robot.joints if robot is not None else None)
    lines = [f"data: {line}"] if (line := ignored_line(recordings)) is not None else []
    states = on_grid_for(recordings, d, env.dt, env.dim, run.env.type, robot, env.aux_dims())
    if isinstance(env, LearnsFromRecordings):
        lines.append(f"obstacle entries: {summary_line(find_entries(env, states), d.obstacle_entries)}")
    return lines


def summary(run, env, expert, learners) -> str:
    aux = ", ".join(f"{k}({v})" for k, v in env.aux_dims().items()) or "none"
    lines = [
        f"experiment: {run.name}   seed={run.seed} device={run.device}",
        f"env: {run.env.type}   aux: {aux}",
        "tree (expert weights on the edges):",
        *("  " + ln for ln in expert.describe().splitlines()),
    ]
    if run.expert:
        lines.append("expert weights: " + ", ".join(f"{n}={weight_label(w)}" for n, w in run.expert.items()))
    lines.append(f"premises (tree): {check_premises(expert).line()}")
    for name, model in learners.items():
        extra = f", learns the weights of edges {learned_edges(model.tree)}" if model.tree is not None else ""
        lines.append(f"learner {name}: {run.learners[name].type}, {model.num_parameters()} parameters{extra}")
        if model.tree is not None:
            lines.append(f"premises ({name}): {check_premises(model.tree).line()}")
    d, t = run.data, run.train
    if d.source == "recorded":
        what = f"LASA shape {d.shape}" if d.format == "lasa" else ", ".join(d.files)
        if d.format != "lasa" and len(read := source_files(d)) != len(d.files):
            what += f": {len(read)} {'bags' if d.format == 'rosbag' else 'files'}"  # a pattern named them
        data_lines = [
            (
                f"data: recorded demonstrations ({d.format}: {what}"
                + (_cut(d, env) if getattr(d, "cut_at_rest", None) is not None else "")
                + f"), split {d.split}, derivatives "
                f"{d.derivatives}"
                + (
                    f" (Savitzky-Golay window {d.window}, order {d.polyorder})"
                    if d.derivatives == "filter"
                    else " (the files' own; data.window and data.polyorder are not used)"
                )
                + (
                    f"; aux per demonstration from the files: {', '.join(from_files)}"
                    + (
                        ""
                        if d.aux_to_policy
                        else " (where obstacles stood in evaluation; the policy is told the scene's)"
                    )
                    if (from_files := d.aux_from_files)
                    else ""
                )
            ),
            (
                f"eval: rollouts from the held-out demonstrations' starts and {d.starts} starts at rest, "
                f"{d.horizon_factor:g} times the longest demonstration (the starts at rest on to "
                f"{max(d.horizon_factor, d.convergence_horizon_factor):g} times); {_compiled_or_eager(run.eval.compile)}; "
                f"figures {'on' if run.eval.figures else 'off'} (eval.unit_weights is for expert data: the tree with "
                "every weight 1 is always the reference here)"
            ),
        ]
        data_lines += _read_lines(run, env)
    else:
        data_lines = [
            (
                f"data: {d.train_envs} envs x {d.train_trajectories} trajectories x {d.points} points (test "
                f"{d.test_envs} x {d.test_trajectories}, validation {d.val_envs} x {d.val_trajectories}), every "
                f"{d.interval}s"
            )
        ]
    lines += [
        *data_lines,
        f"train: {t.method}, {t.describe()}",
        f"logger: wandb {run.logger.mode}",
        "OK: the configuration is valid and builds; nothing was run.",
    ]
    return "\n".join(lines)


def _compiled_or_eager(compile_: bool | str) -> str:
    if compile_ == "auto":
        return "each tree compiled where its rollouts repay it (eval.compile=auto)"
    return "trees compiled" if compile_ else "trees eager"


@hydra_app
def main(cfg: DictConfig) -> None:
    """Nothing runs, so nothing stays: the directory Hydra made for the job is removed (``discard_unclaimed``)."""
    try:
        with user_errors_exit():
            run = resolve_and_validate(cfg)
            env, expert, learners = build_all(run)
        print(summary(run, env, expert, learners))
        print(
            f"run directory: {hydra_run_dir()} (where rmpfusion-run with these overrides writes; nothing is kept "
            "by rmpfusion-validate)"
        )
    finally:
        discard_unclaimed(hydra_run_dir())


if __name__ == "__main__":
    main()
