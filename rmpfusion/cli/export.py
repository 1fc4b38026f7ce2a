"""``rmpfusion-export CKPT``: a trained learner as one file that needs only torch to run.

The checkpoint carries the run's config, so the learner is rebuilt from it alone (as ``rmpfusion-evaluate-
checkpoint`` does) and exported with ``torch.export``: a program fixed to the tree's structure and weights,
taking ``(q, q̇, aux entries...)`` for any batch size and returning q̈ (and M, f with ``--with-rmp``). The file is
checked against the learner before the command ends (every output to 1e-10) and carries its inputs' order and
sizes (``rmpfusion.json`` inside it). ``--aoti`` also writes an AOTInductor package (compiled code, for a
control loop in Python or C++; docs/tutorials/deployment.md).

    rmpfusion-export outputs/franka/<time>/checkpoints/rmp/final.pt            # -> rmp-final.pt2 beside it
    python -c "import torch; p = torch.export.load('rmp-final.pt2').module(); print(p(q, qd, *aux))"

``--set SHAPE:N`` (repeatable; ``SHAPE:N:per-control-point`` for N members of each control point's own,
``SHAPE:N:nearest=K`` for each control point's K nearest of N, selected inside the program) exports a
learner trained among a scene's fixed obstacles as a controller for a world that changes at run time: its tree's
obstacle edges give way to run-time obstacle sets under the same shared weights
(``envs/manipulator_tree.py::with_obstacle_sets``), and the program takes the goal and every set's tensors and mask
(``rmpfusion.scenes.World.set_aux``; names and shapes in ``rmpfusion.json``), for one state at a time.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import torch
from pydantic import ValidationError

from ..envs.protocol import JointSpace
from ..files import atomic_path
from ..learn.checkpoints import CheckpointError, load_checkpoint
from ..learn.export import METADATA, export_learner, export_with_sets, metadata, metadata_text
from ..pipeline.construct import learner_over_sets
from ..pipeline.experiment import prepare
from ..pipeline.fit import learners
from ..pipeline.progress import Progress
from ..robots.robot import build_robot
from ..scenes import ObstacleSet, with_slots
from ..scenes.aux import PARKED
from ..scenes.sets import sets_given
from ._common import user_errors_exit
from .from_checkpoint import _load, _not_a_checkpoint

#: How closely the exported file must reproduce the learner (float64), checked before the command ends.
TOLERANCE = 1e-10


class ExportError(RuntimeError):
    """The export cannot be written as asked (existing file, learner without a tree for --with-rmp, a mismatch)."""


def _example(exp, n: int = 4):
    """A few states of the run's environment (its own sampling, the training split's distribution)."""
    g = torch.Generator().manual_seed(exp.run.seed)
    envs = exp.env.sample_envs(1, g, split="train")
    return exp.env.sample_initial_states(envs, n, g)


@torch.no_grad()
def _check(run_file, learner, q, qd, aux, names, with_rmp: bool) -> float:
    """The largest difference between the written program and the learner on the example states."""
    out = run_file(q, qd, *(aux[n].contiguous() for n in names))
    expect: tuple[torch.Tensor, ...]
    if with_rmp:
        ref = learner.tree(q, qd, aux)
        expect = (ref.qdd, ref.M, ref.f)
    else:
        expect = (learner(q, qd, aux),)
    got = out if isinstance(out, (tuple, list)) else (out,)
    return max(float((a - b).abs().max()) for a, b in zip(got, expect))


def parse_set(text: str) -> ObstacleSet:
    """``SHAPE:N``, ``SHAPE:N:per-control-point`` or ``SHAPE:N:nearest=K`` as an obstacle set; a malformed one is a
    ValueError saying how."""
    parts = text.split(":")
    how = parts[2] if len(parts) == 3 else ""
    nearest = how.removeprefix("nearest=")
    if (
        len(parts) not in (2, 3)
        or not parts[1].isdigit()
        or (len(parts) == 3 and how != "per-control-point" and not (how.startswith("nearest=") and nearest.isdigit()))
    ):
        raise ValueError(
            f"--set {text}: write SHAPE:N, SHAPE:N:per-control-point or SHAPE:N:nearest=K, e.g. --set sphere:32"
        )
    try:
        return ObstacleSet.model_validate(
            {
                "shape": parts[0],
                "n_max": int(parts[1]),
                "per_control_point": how == "per-control-point",
                "nearest": int(nearest) if how.startswith("nearest=") else None,
            }
        )
    except ValidationError as e:
        reasons = "; ".join(f"{'.'.join(map(str, err['loc']))}: {err['msg']}" for err in e.errors())
        raise ValueError(f"--set {text}: {reasons}") from None


def _set_inputs(read: list[ObstacleSet], goal: torch.Tensor) -> dict[str, torch.Tensor]:
    """The goal and every set's tensors and mask for one state: members present every other slot, placed 0.3 m
    beyond the goal and apart, the rest of each member's fields at the parked obstacle's values."""
    inputs = {"goal": goal[:1]}
    for s in read:
        for f, k in s.fields().items():
            value = torch.tensor(PARKED[f], dtype=torch.float64).expand(1, s.n_max, k).clone()
            if f == "center":
                value = goal[:1, None, :] + torch.tensor([0.3, 0.0, 0.3]) + 0.05 * torch.arange(s.n_max)[None, :, None]
            inputs[f"{s.prefix}_{f}"] = value.to(torch.float64)
        inputs[f"{s.prefix}_mask"] = (torch.arange(s.n_max) % 2 == 0).to(torch.float64)[None]
    return inputs


def export_with_run_time_sets(
    path: Path, sets: list[ObstacleSet], out: Path | None = None, force: bool = False
) -> Path:
    """Write the learner in checkpoint ``path`` as a program over run-time obstacle ``sets`` (see the module
    docstring), checked against the eager tree before the command ends."""
    if (what := _not_a_checkpoint(path)) is not None:
        raise CheckpointError(what)
    state, run, name = _load(path)
    out = out or path.parent / f"{name}-{path.stem}-sets.pt2"
    if out.exists() and not force:
        raise ExportError(f"{out} exists; choose another --out or pass --force to replace it")
    torch.set_num_threads(1)
    run = run.model_copy(update={"device": "cpu"})
    exp = prepare(run, path.parents[2] if len(path.parents) > 2 else path.parent, Progress(False))
    trained = learners(exp)[name]
    load_checkpoint(path, trained)
    trained.load_state_dict(state["model"])
    if trained.tree is None:
        raise ExportError("--set needs a learner whose policy is an RMP tree (its obstacle edges take the sets)")
    learner, _ = learner_over_sets(run, name, trained, sets)
    tree = learner.tree
    assert tree is not None  # a tree learner, as the trained one
    q, qd, aux = _example(exp, n=1)
    if not isinstance(exp.env, JointSpace):
        raise ExportError("--set needs an environment of a robot's joints (its control points read the sets)")
    robot = build_robot(exp.env.robot_description)
    given = sets_given(sets, len(robot.params.control_points))  # what the program takes
    centres = robot.sphere_centres if any(s.nearest for s in sets) else None
    inputs = _set_inputs(given, aux["goal"].to(torch.float64))
    program = export_with_sets(tree, given, q, qd, inputs, centres)
    meta = metadata(
        {"goal": 3}, ["goal"], exp.env.dim, torch.float64, False, learner=name, checkpoint=str(path),
        iteration=int(state.get("iteration", -1)), experiment=run.name,
    )  # fmt: skip
    meta["inputs"] = [f"q (1, {exp.env.dim})", f"qd (1, {exp.env.dim})"] + [
        f"{n} {tuple(t.shape)}" for n, t in inputs.items()
    ]
    meta["sets"] = [s.model_dump() for s in sets]
    with atomic_path(out, suffix=".pt2") as tmp:
        torch.export.save(program, tmp, extra_files={METADATA: metadata_text(meta)})
        loaded = torch.export.load(tmp).module()
        with torch.no_grad():
            got = loaded(q, qd, *inputs.values())
            want = tree(q, qd, with_slots(given, inputs, None if centres is None else centres(q))).qdd
        err = float((got - want).abs().max())
        if not err <= TOLERANCE:
            raise ExportError(
                f"the exported program differs from the learner by {err:.3g} (more than {TOLERANCE:g}); nothing was written"
            )
    return out


def export_checkpoint(
    path: Path, out: Path | None = None, with_rmp: bool = False, aoti: bool = False, force: bool = False
) -> list[Path]:
    """Write the exported program (and the AOTInductor package) of the learner in checkpoint ``path``."""
    if (what := _not_a_checkpoint(path)) is not None:
        raise CheckpointError(what)
    state, run, name = _load(path)
    out = out or path.parent / f"{name}-{path.stem}.pt2"
    targets = [out] + ([out.with_name(out.stem + "-aoti.pt2")] if aoti else [])
    existing = [str(t) for t in targets if t.exists()]
    if existing and not force:
        raise ExportError(f"{', '.join(existing)} exists; choose another --out or pass --force to replace it")
    torch.set_num_threads(1)
    run = run.model_copy(update={"device": "cpu"})  # traced on the CPU; a loaded program moves with .to(device)
    exp = prepare(run, path.parents[2] if len(path.parents) > 2 else path.parent, Progress(False))
    learner = learners(exp)[name]
    load_checkpoint(path, learner)  # the weights must fit this learner
    learner.load_state_dict(state["model"])
    learner.to(torch.float64)
    q, qd, aux = _example(exp)
    names = sorted(exp.env.aux_dims())
    meta = metadata(
        exp.env.aux_dims(),
        names,
        exp.env.dim,
        torch.float64,
        with_rmp,
        learner=name,
        iteration=int(state.get("iteration", -1)),
        checkpoint=str(path),
        experiment=run.name,
    )
    program = export_learner(learner, q, qd, aux, names, with_rmp=with_rmp)
    with atomic_path(out, suffix=".pt2") as tmp:  # torch.export wants its files to end in .pt2
        torch.export.save(program, tmp, extra_files={METADATA: metadata_text(meta)})
        _verify("exported program", torch.export.load(tmp).module(), learner, q, qd, aux, names, with_rmp)
    if aoti:
        with atomic_path(targets[1], suffix=".pt2") as tmp:
            torch._inductor.aoti_compile_and_package(
                program,
                package_path=str(tmp),
                inductor_configs={"aot_inductor.metadata": {METADATA: metadata_text(meta)}},
            )
            _verify(
                "AOTInductor package", torch._inductor.aoti_load_package(str(tmp)), learner, q, qd, aux, names, with_rmp
            )
    return targets


def _verify(what: str, program, learner, q, qd, aux, names, with_rmp) -> None:
    err = _check(program, learner, q, qd, aux, names, with_rmp)
    if not err <= TOLERANCE:
        raise ExportError(
            f"the {what} differs from the learner by {err:.3g} (more than {TOLERANCE:g}) on the example "
            "states; nothing was written"
        )


def main(argv=None) -> int | str | None:
    ap = argparse.ArgumentParser(
        prog="rmpfusion-export", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("checkpoint", type=Path, help="checkpoints/<learner>/final.pt or ckpt-*.pt of a run")
    ap.add_argument(
        "--out",
        type=Path,
        default=None,
        help="the file to write (default <learner>-<checkpoint>.pt2 beside the checkpoint)",
    )
    ap.add_argument("--with-rmp", action="store_true", help="also return the root's M and f (tree learners)")
    ap.add_argument(
        "--aoti",
        action="store_true",
        help="also write an AOTInductor package (<out>-aoti.pt2); needs a C++ compiler, takes minutes",
    )
    ap.add_argument("--force", action="store_true", help="replace files that exist")
    ap.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="SHAPE:N[:per-control-point|:nearest=K]",
        help="export for run-time obstacle sets instead of the scene's fixed obstacles (repeatable)",
    )
    a = ap.parse_args(argv)
    try:
        with user_errors_exit():
            if a.set:
                if a.with_rmp or a.aoti:
                    raise ExportError("--set exports q-ddot for one state at a time: leave out --with-rmp and --aoti")
                sets = [parse_set(t) for t in a.set]
                written = [export_with_run_time_sets(a.checkpoint, sets, a.out, force=a.force)]
            else:
                written = export_checkpoint(a.checkpoint, a.out, with_rmp=a.with_rmp, aoti=a.aoti, force=a.force)
    except (ExportError, ValueError) as e:  # what this command refuses to write (a learner it cannot export)
        print(f"error: {e}", file=sys.stderr)
        return 2
    except SystemExit as e:  # a user error, printed; the status is returned (the console script exits with it)
        return e.code
    for p in written:
        print(f"wrote {p}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
