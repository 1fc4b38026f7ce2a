"""``rmpfusion-export CKPT``: a trained learner as one file that needs only torch to run.

The checkpoint carries the run's config, so the learner is rebuilt from it alone (as ``rmpfusion-evaluate-
checkpoint`` does) and exported with ``torch.export``: a program fixed to the tree's structure and weights,
taking ``(q, q̇, aux entries...)`` for any batch size and returning q̈ (and M, f with ``--with-rmp``). The file is
checked against the learner before the command ends (every output to 1e-10) and carries its inputs' order and
sizes (``rmpfusion.json`` inside it). ``--aoti`` also writes an AOTInductor package (compiled code, for a
control loop in Python or C++; docs/tutorials/deployment.md).

    rmpfusion-export outputs/franka/<time>/checkpoints/rmp/final.pt            # -> rmp-final.pt2 beside it
    python -c "import torch; p = torch.export.load('rmp-final.pt2').module(); print(p(q, qd, *aux))"
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import torch

from ..files import atomic_path
from ..learn.checkpoints import CheckpointError, load_checkpoint
from ..learn.export import METADATA, export_learner, metadata, metadata_text
from ..pipeline.experiment import prepare
from ..pipeline.fit import learners
from ..pipeline.progress import Progress
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
    a = ap.parse_args(argv)
    try:
        with user_errors_exit():
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
