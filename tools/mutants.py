"""Does the test suite catch the bugs it is meant to catch? Apply one-line mutants, run the tests that should fail.

Each mutant below is a plausible one-line slip in rmpfusion (a monitor that checks any record instead of every
record, a certificate that accepts a zero weight, a loss normalised by the wrong count, ...). For each one this
tool copies the repository's tracked files into a scratch directory (the working tree is never edited), applies
the mutant there, runs the tests listed for it with pytest, and reports the mutant KILLED (some test failed) or
SURVIVED (every test passed: the suite would let the bug through). A mutant whose original line is no longer in
its file is reported STALE: the code moved, and the list below needs updating.

    python tools/mutants.py                     # every mutant, against every test listed for it
    python tools/mutants.py --fast              # only the tests written to catch each mutant (seconds each)
    python tools/mutants.py --only lyapunov_any certificate_zero_weight
    python tools/mutants.py --tests-from main   # the same mutants against another commit's tests/ (e.g. to check
                                                # that a new test is what kills a mutant)
    python tools/mutants.py --list

The exit status is 0 when every mutant run was killed, 1 otherwise. ``tests/test_mutants.py`` (slow) runs
``--fast`` and asserts that.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


@dataclass(frozen=True)
class Mutant:
    """A one-line change to ``path``: ``before`` (exactly once in the file) becomes ``after``."""

    name: str
    path: str
    before: str
    after: str
    what: str
    catchers: tuple[str, ...]  # the tests written to catch it (pytest node ids or files)
    related: tuple[str, ...] = ()  # other tests of the same code, run too unless --fast


RECOMPUTED = "tests/test_recomputed_numbers.py"

MUTANTS: tuple[Mutant, ...] = (
    Mutant(
        "lyapunov_any",
        "rmpfusion/evaluate/lyapunov.py",
        "    return ok.all(0)\n",
        "    return ok.any(0)\n",
        "the Lyapunov monitor accepts a trajectory when any record (not every record) is non-increasing",
        (
            f"{RECOMPUTED}::test_lyapunov_monitor_fails_a_trajectory_that_rises_at_one_record_among_many",
            f"{RECOMPUTED}::test_lyapunov_monitor_agrees_with_a_direct_comparison_on_random_series",
        ),
        (
            "tests/test_particle2d.py::test_lyapunov_monotone_rule",
            "tests/test_particle2d.py::test_tree_rollout_is_safe_stable_and_reaches",
            "tests/test_franka.py::test_tiny_franka_experiment_end_to_end",
        ),
    ),
    Mutant(
        "certificate_zero_weight",
        "rmpfusion/evaluate/certificate.py",
        "(w_all > 0).all(1)",
        "(w_all >= 0).all(1)",
        "the certificate accepts w >= 0 instead of w > 0",
        (f"{RECOMPUTED}::test_certificate_rejects_a_weight_that_is_exactly_zero",),
        ("tests/test_certificate.py",),
    ),
    Mutant(
        "dataset_loss_per_sample",
        "rmpfusion/learn/objectives.py",
        "    return total / (n * data.qdd.shape[1])\n",
        "    return total / n\n",
        "dataset_loss divides the summed squared error by the number of samples n instead of n·d",
        (
            f"{RECOMPUTED}::test_dataset_loss_is_the_mean_squared_error_over_every_entry",
            f"{RECOMPUTED}::test_the_minibatch_loss_and_the_dataset_loss_are_the_same_quantity",
        ),
        ("tests/test_learning.py",),
    ),
    Mutant(
        "training_loss_summed",
        "rmpfusion/learn/objectives.py",
        "        return F.mse_loss(pred, target)\n",
        '        return F.mse_loss(pred, target, reduction="sum")\n',
        "the training loss is summed over the minibatch instead of averaged",
        (
            f"{RECOMPUTED}::test_training_loss_is_the_minibatch_mean_and_minibatches_reach_every_sample",
            f"{RECOMPUTED}::test_the_minibatch_loss_and_the_dataset_loss_are_the_same_quantity",
        ),
        ("tests/test_learning.py",),
    ),
    Mutant(
        "timeout_distance_second_to_last",
        "rmpfusion/envs/manipulator/metrics.py",
        '"timeout_goal_distance": ro.goal_distance[-1]',
        '"timeout_goal_distance": ro.goal_distance[-2]',
        "the time-out goal distance is read from the second-to-last record",
        (f"{RECOMPUTED}::test_time_out_goal_distance_is_the_last_record_recomputed_from_the_kinematics",),
        (
            "tests/test_franka.py::test_ratios_to_the_expert_are_per_trajectory",
            "tests/test_franka.py::test_tiny_franka_experiment_end_to_end",
        ),
    ),
    Mutant(
        "minibatch_skips_last_sample",
        "rmpfusion/learn/methods/bc.py",
        "idx = torch.randint(N, ",
        "idx = torch.randint(N - 1, ",
        "behavior cloning's minibatches never draw the last training sample",
        (f"{RECOMPUTED}::test_training_loss_is_the_minibatch_mean_and_minibatches_reach_every_sample",),
        ("tests/test_learning.py",),
    ),
)


def scratch_copy(dest: Path, tests_from: str | None) -> None:
    """The repository's tracked and untracked-but-not-ignored files under ``dest``; with ``tests_from``, tests/ as
    that commit has it."""
    files = (
        subprocess.run(
            ["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
            cwd=ROOT,
            check=True,
            capture_output=True,
        )
        .stdout.decode()
        .split("\0")
    )
    for rel in filter(None, files):
        src = ROOT / rel
        if src.is_file():
            (dest / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, dest / rel)
    if tests_from:
        shutil.rmtree(dest / "tests")
        archive = subprocess.run(["git", "archive", tests_from, "tests"], cwd=ROOT, check=True, capture_output=True)
        subprocess.run(["tar", "-x", "-C", str(dest)], input=archive.stdout, check=True)


def present(selection: str, root: Path) -> bool:
    """Whether a pytest node id or file exists in the copy (another commit's tests may lack it)."""
    path, _, func = selection.partition("::")
    file = root / path
    return file.is_file() and (not func or f"def {func.split('[')[0]}(" in file.read_text(encoding="utf-8"))


def run_tests(root: Path, selections: list[str], timeout: float) -> tuple[bool, str]:
    """(passed, last lines of pytest's output) for ``selections`` run in ``root`` (slow tests included when named)."""
    env = {**os.environ, "PYTHONPATH": str(root), "PYTHONDONTWRITEBYTECODE": "1"}
    cmd = [sys.executable, "-m", "pytest", "-q", "-x", "-p", "no:cacheprovider", *selections]
    try:
        done = subprocess.run(cmd, cwd=root, env=env, capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return False, f"timed out after {timeout:.0f} s"
    tail = "\n".join((done.stdout + done.stderr).strip().splitlines()[-3:])
    return done.returncode == 0, tail


def apply(root: Path, m: Mutant) -> str | None:
    """Apply ``m`` in the copy under ``root``; the original text to restore, or None when the mutant is stale."""
    file = root / m.path
    text = file.read_text(encoding="utf-8")
    if text.count(m.before) != 1:
        return None
    file.write_text(text.replace(m.before, m.after), encoding="utf-8")
    return text


def check(root: Path, m: Mutant, fast: bool, timeout: float) -> dict:
    """Run ``m``'s tests on the mutated copy: {"verdict": KILLED | SURVIVED | STALE | NO TESTS, ...}."""
    selections = [s for s in (m.catchers if fast else m.catchers + m.related) if present(s, root)]
    original = apply(root, m)
    if original is None:
        return {"verdict": "STALE", "tests": selections, "detail": f"{m.before.strip()!r} is not once in {m.path}"}
    try:
        if not selections:
            return {"verdict": "NO TESTS", "tests": [], "detail": "none of its tests exist in this copy"}
        t0 = time.perf_counter()
        passed, tail = run_tests(root, selections, timeout)
        return {
            "verdict": "SURVIVED" if passed else "KILLED",
            "tests": selections,
            "detail": tail,
            "seconds": time.perf_counter() - t0,
        }
    finally:
        (root / m.path).write_text(original, encoding="utf-8")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--only", nargs="+", metavar="NAME", help="these mutants only (see --list)")
    ap.add_argument("--fast", action="store_true", help="only the tests written to catch each mutant")
    ap.add_argument("--tests-from", metavar="REF", help="run another commit's tests/ (e.g. main) against the mutants")
    ap.add_argument("--timeout", type=float, default=900.0, help="seconds per mutant's test run (default 900)")
    ap.add_argument("--list", action="store_true", help="list the mutants and their tests, run nothing")
    args = ap.parse_args(argv)
    names = {m.name for m in MUTANTS}
    unknown = sorted(set(args.only or ()) - names)
    if unknown:
        ap.error(f"unknown mutant(s) {unknown}; the mutants are: {', '.join(sorted(names))}")
    chosen = [m for m in MUTANTS if not args.only or m.name in args.only]
    if args.list:
        for m in chosen:
            print(f"{m.name}: {m.what}\n  {m.path}: {m.before.strip()!r} -> {m.after.strip()!r}")
            for s in m.catchers + m.related:
                print(f"  {'catcher' if s in m.catchers else 'related'}: {s}")
        return 0
    with tempfile.TemporaryDirectory(prefix="rmpfusion-mutants-") as tmp:
        root = Path(tmp)
        scratch_copy(root, args.tests_from)
        results = {}
        for m in chosen:
            r = results[m.name] = check(root, m, args.fast, args.timeout)
            took = f" ({r['seconds']:.0f} s)" if "seconds" in r else ""
            print(
                f"{r['verdict']:9s} {m.name}{took}: {m.what}\n          tests: {' '.join(r['tests']) or '-'}\n"
                f"          {r['detail'].replace(chr(10), chr(10) + ' ' * 10)}",
                flush=True,
            )
    killed = sum(r["verdict"] == "KILLED" for r in results.values())
    print(
        f"{killed} of {len(results)} mutants killed"
        + (f" by the tests of {args.tests_from}" if args.tests_from else "")
    )
    return 0 if killed == len(results) else 1


if __name__ == "__main__":
    sys.exit(main())
