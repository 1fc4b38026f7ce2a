"""Runs people can trust: real processes are killed (SIGKILL, SIGTERM, and SIGKILL in the middle of a
checkpoint write) and rerun with the same command in the same run directory; they must end at exactly the
weights of an uninterrupted run. A 2-job submitit_local multirun must leave two complete run directories with one
offline wandb run each, and tools/summarize_sweep.py must summarise it. Same seed, same data and losses.

Every training process here runs the real ``rmpfusion-train`` app on tiny sizes; the uninterrupted reference
runs in the background while the first kill test runs.
"""

from __future__ import annotations

import json
import os
import platform
import re
import shutil
import signal
import statistics
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch
import yaml

from rmpfusion.learn.checkpoints import latest_checkpoint

REPO = Path(__file__).resolve().parents[1]
ITERS = 60
TRAIN = [
    "data=tiny",
    "train=tiny",
    "eval=fast",
    "logger=disabled",
    "weights@learners.rmp.weights=mlp_small",
    f"train.iterations={ITERS}",
    "train.checkpoint_every=10",
    "train.log_every=20",
    f"train.snapshots=[0,{ITERS}]",
]
FINAL = f"ckpt-{ITERS:08d}.pt"


def _env(**extra) -> dict:
    env = {
        **os.environ,
        "WANDB_MODE": "disabled",
        "HYDRA_FULL_ERROR": "1",
        "PYTHONUNBUFFERED": "1",
        "OMP_NUM_THREADS": "1",
        "MPLBACKEND": "Agg",
    }
    env.update(extra)
    return env


def _app(stage: str) -> list[str]:
    """The installed console script (``rmpfusion-train`` ...) when it sits beside this interpreter."""
    script = Path(sys.executable).with_name(f"rmpfusion-{stage}")
    if script.is_file():
        return [str(script)]
    return [sys.executable, "-c", f"from rmpfusion.cli.run import {stage}; {stage}()"]


class Proc:
    """A real process with its stdout/stderr in files (no pipe can fill up and block it)."""

    def __init__(self, cmd: list[str], logs: Path, env: dict | None = None):
        logs.mkdir(parents=True, exist_ok=True)
        self.out_path, self.err_path = logs / "stdout.txt", logs / "stderr.txt"
        # the child writes to them until it ends: closed in wait(), not at the end of a with block
        self._out, self._err = open(self.out_path, "w"), open(self.err_path, "w")  # noqa: SIM115
        self.p = subprocess.Popen(cmd, stdout=self._out, stderr=self._err, env=env or _env(), cwd=str(logs))

    @property
    def pid(self) -> int:
        return self.p.pid

    def wait(self, timeout: float = 300) -> int:
        rc = self.p.wait(timeout=timeout)
        self._out.close()
        self._err.close()
        return rc

    @property
    def stdout(self) -> str:
        return self.out_path.read_text()

    @property
    def stderr(self) -> str:
        return self.err_path.read_text()

    def wait_until(self, cond, what: str, timeout: float = 180) -> None:
        end = time.monotonic() + timeout
        while not cond():
            if self.p.poll() is not None:
                pytest.fail(
                    f"process ended (status {self.p.returncode}) before {what}:\n{self.stdout[-2000:]}\n"
                    f"{self.stderr[-3000:]}"
                )
            if time.monotonic() > end:
                self.p.kill()
                pytest.fail(f"timed out waiting for {what}:\n{self.stdout[-2000:]}\n{self.stderr[-3000:]}")
            time.sleep(0.005)


def train_proc(run_dir: Path, logs: Path, *extra: str, prefix: list[str] | None = None) -> Proc:
    return Proc((prefix or _app("train")) + TRAIN + list(extra) + [f"hydra.run.dir={run_dir}"], logs)


def _done(proc: Proc, timeout: float = 300) -> Proc:
    rc = proc.wait(timeout)
    assert rc == 0, f"status {rc}\n{proc.stdout[-2000:]}\n{proc.stderr[-4000:]}"
    return proc


def _ckpt(path: Path) -> dict:
    return torch.load(path, map_location="cpu", weights_only=True)


def _assert_same_weights(run_dir: Path, reference: dict) -> None:
    state = _ckpt(run_dir / "checkpoints" / "rmp" / FINAL)
    assert state["iteration"] == ITERS
    assert state["model"].keys() == reference["model"].keys()
    for k, v in reference["model"].items():
        assert torch.equal(state["model"][k], v), f"{k} differs from the uninterrupted run"
    assert state["curve"] == reference["curve"]  # the same loss at every one of the ITERS steps


# --------------------------------------------------------------------------------------------- fixtures
@pytest.fixture(scope="module")
def outdir(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("runs")


SWEEP = [
    "-m",
    "launcher=submitit_local",
    "seed=0,1",
    "data=tiny",
    "train=tiny",
    "eval=fast",
    "eval.figures=true",
    "logger=offline",
    "hydra.launcher.timeout_min=10",
]
#: the sweep's job directories: <job number>_<name>_<the job's overrides> (conf/config.yaml hydra.sweep.subdir;
#: no experiment= so the name is "default"; launcher, logger and hydra.* overrides are left out of the name; the
#: sweeper writes each job's booleans as True/False)
JOBS = [f"{n}_default_data=tiny,eval.figures=True,eval=fast,seed={n},train=tiny" for n in (0, 1)]


@pytest.fixture(scope="module")
def background(outdir) -> dict[str, Proc]:
    """The long independent processes, started together at the first test that needs one of them (they overlap
    with the kill tests, which mostly wait on one process at a time): the uninterrupted reference training, and
    ``rmpfusion-run -m launcher=submitit_local seed=0,1`` with offline wandb and figures (two submitit jobs)."""
    home = outdir / "wandb-home"  # wandb's own settings and caches stay out of $HOME
    wandb_env = _env(
        WANDB_MODE="offline",
        WANDB_CONFIG_DIR=str(home / "config"),
        WANDB_CACHE_DIR=str(home / "cache"),
        WANDB_DATA_DIR=str(home / "data"),
    )
    procs = {
        "reference": train_proc(outdir / "uninterrupted", outdir / "logs-uninterrupted"),
        "sweep": Proc(
            [sys.executable, "-m", "rmpfusion.cli.run", *SWEEP, f"hydra.sweep.dir={outdir / 'sweep'}"],
            outdir / "logs-sweep",
            env=wandb_env,
        ),
    }
    yield procs
    for proc in procs.values():
        if proc.p.poll() is None:
            proc.p.kill()
            proc.wait()


@pytest.fixture(scope="module")
def reference(outdir, background) -> dict:
    _done(background["reference"])
    state = _ckpt(outdir / "uninterrupted" / "checkpoints" / "rmp" / FINAL)
    first = dict(state["snapshots"][0])
    assert any(not torch.equal(first[k], v) for k, v in state["model"].items()), "training changed nothing"
    return state


# ------------------------------------------------------------------------------------- kill and resume
@pytest.mark.slow
def test_sigkill_mid_training_then_rerun_ends_at_the_uninterrupted_weights(background, tmp_path, request):
    run_dir = tmp_path / "run"
    ck = run_dir / "checkpoints" / "rmp"
    first = train_proc(run_dir, tmp_path / "logs1")
    first.wait_until(lambda: latest_checkpoint(ck) is not None, "the first checkpoint")
    os.kill(first.pid, signal.SIGKILL)
    assert first.wait() == -signal.SIGKILL
    killed_at = _ckpt(latest_checkpoint(ck))["iteration"]
    assert 0 < killed_at < ITERS and not (ck / FINAL).exists(), "the kill did not land mid-training"

    again = _done(train_proc(run_dir, tmp_path / "logs2"))  # the same command, the same directory
    assert f"learner rmp: resumed from iteration {killed_at}" in again.stdout
    assert "data: reusing train set" in again.stdout  # the killed run's demonstrations, not new ones
    _assert_same_weights(run_dir, request.getfixturevalue("reference"))
    # the checkpoint alone rebuilds the run: it embeds the resolved config
    from rmpfusion.pipeline.config import RunConfig

    cfg = RunConfig.model_validate(_ckpt(ck / FINAL)["config"])
    assert cfg.train.iterations == ITERS and cfg.learners["rmp"].type == "rmp"


@pytest.mark.slow
def test_sigterm_writes_a_checkpoint_at_once_and_the_rerun_resumes_from_it(outdir, reference, tmp_path):
    """SLURM preemption / ``kill``: the step in progress finishes, a checkpoint is written, the process exits
    143. Periodic checkpoints are off here (checkpoint_every > iterations), so the only checkpoint on disk is
    the one the signal caused. Output is not a terminal: progress comes as plain lines with rate and ETA."""
    run_dir = tmp_path / "run"
    ck = run_dir / "checkpoints" / "rmp"
    proc = train_proc(run_dir, tmp_path / "logs1", "train.checkpoint_every=100000")
    proc.wait_until(lambda: "train rmp [" in proc.stdout, "training to start")
    proc.p.send_signal(signal.SIGTERM)
    assert proc.wait() == 128 + signal.SIGTERM, proc.stderr[-3000:]
    m = re.search(rf"SIGTERM received; checkpoint at iteration (\d+)/{ITERS} written to (\S+);", proc.stderr)
    assert m, proc.stderr[-3000:]
    at = int(m.group(1))
    assert 0 < at < ITERS
    assert [p.name for p in ck.glob("ckpt-*.pt")] == [f"ckpt-{at:08d}.pt"] == [Path(m.group(2)).name]
    assert _ckpt(ck / f"ckpt-{at:08d}.pt")["iteration"] == at
    assert re.search(rf"train rmp \[[#.]+\] \d+/{ITERS} +\d+% +[\d.]+/s +elapsed \d\d:\d\d +eta ", proc.stdout)
    assert "\r" not in proc.stdout  # no terminal redraws in a log file

    again = _done(train_proc(run_dir, tmp_path / "logs2", "train.checkpoint_every=100000"))
    assert f"learner rmp: resumed from iteration {at}" in again.stdout
    _assert_same_weights(run_dir, reference)
    log = (run_dir / "console.log").read_text()  # both invocations' output, kept in the run directory
    assert log.count("==== ") == 2 and "SIGTERM received" in log and f"resumed from iteration {at}" in log


@pytest.mark.slow
def test_ctrl_c_writes_a_checkpoint_and_says_how_to_resume_without_a_traceback(tmp_path):
    """Ctrl-C (SIGINT): the step in progress finishes, a checkpoint is written, and the command ends in two
    lines (what was saved, how to resume) with the shell's status for an interrupt, 130: no traceback."""
    run_dir = tmp_path / "run"
    long = 100_000  # iterations: on a busy machine the run of ITERS could end before the signal arrives
    proc = train_proc(
        run_dir,
        tmp_path / "logs",
        f"train.iterations={long}",
        f"train.snapshots=[0,{long}]",
        "train.checkpoint_every=1000000",
    )
    proc.wait_until(lambda: "train rmp [" in proc.stdout, "training to start")
    proc.p.send_signal(signal.SIGINT)
    assert proc.wait() == 130, proc.stderr[-3000:]
    assert "Traceback" not in proc.stderr and "KeyboardInterrupt" not in proc.stderr, proc.stderr[-3000:]
    m = re.search(rf"SIGINT received; checkpoint at iteration (\d+)/{long} written to (\S+);", proc.stderr)
    assert m and Path(m.group(2)).is_file(), proc.stderr[-3000:]
    assert (
        f"interrupted (Ctrl-C): what was finished is kept in {run_dir} (datasets, the last checkpoint); rerun "
        f"the same command with hydra.run.dir={run_dir} to resume"
    ) in proc.stderr


def test_signals_during_training_in_process_checkpoint_then_defer_to_the_installed_handler(tmp_path):
    """Under a job manager that handles SIGTERM itself (submitit keeps the job alive until its requeue), the
    signal still writes a checkpoint at once, the manager's handler runs, and training goes on; Ctrl-C with
    Python's default handler checkpoints, then raises KeyboardInterrupt. Handlers are restored afterwards."""
    from rmpfusion.assembly.tree import build_tree
    from rmpfusion.envs import Particle2D, collect
    from rmpfusion.learn import train
    from rmpfusion.learn.config import TrainConfig

    env = Particle2D(n_obstacles=1, dt=0.05)
    expert = build_tree(
        {
            "root": {"name": "q", "dim": 2},
            "nodes": {
                "goal": {"parent": "q", "map": {"type": "offset", "origin": "goal"}, "rmp": {"type": "goal_attractor"}}
            },
        },
        aux_dims=env.aux_dims(),
    )
    data = collect(env, expert, 1, 2, 3, 0.25, torch.Generator().manual_seed(0))

    class Linear(torch.nn.Module):
        def __init__(self):
            super().__init__()
            self.lin = torch.nn.Linear(4, 2)

        def forward(self, q, qd, aux):
            return self.lin(torch.cat([q, qd], -1))

    def model():
        torch.manual_seed(0)
        return Linear()

    cfg = TrainConfig(iterations=12, batch_size=4, snapshots=[12], checkpoint_every=1000, log_every=1000)

    def signal_at(step, signum):
        return lambda done, total: os.kill(os.getpid(), signum) if done == step else None

    calls: list[int] = []

    def manager(signum, frame):
        calls.append(signum)

    before = signal.signal(signal.SIGTERM, manager)
    try:
        res = train(model(), data, cfg, seed=0, checkpoint_dir=tmp_path / "a", progress=signal_at(5, signal.SIGTERM))
        assert calls == [signal.SIGTERM] and signal.getsignal(signal.SIGTERM) is manager
    finally:
        signal.signal(signal.SIGTERM, before)
    assert res.curve[-1][0] == 12
    assert sorted(p.name for p in (tmp_path / "a").glob("ckpt-*.pt")) == ["ckpt-00000005.pt", "ckpt-00000012.pt"]

    # Python's own Ctrl-C handler, whatever this process inherited (background jobs and CI start with SIGINT ignored)
    inherited = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        with pytest.raises(KeyboardInterrupt):
            train(model(), data, cfg, seed=0, checkpoint_dir=tmp_path / "b", progress=signal_at(4, signal.SIGINT))
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    finally:
        signal.signal(signal.SIGINT, inherited)
    assert [p.name for p in (tmp_path / "b").glob("ckpt-*.pt")] == ["ckpt-00000004.pt"]
    resumed = train(model(), data, cfg, seed=0, checkpoint_dir=tmp_path / "b")
    assert resumed.resumed_from == 4 and resumed.curve == res.curve  # the interrupted run ends as the other one


SLOW_WRITE = '''
import os, pathlib, sys, time
target, marker = os.environ["RMPFUSION_TEST_SLOW_NAME"], os.environ["RMPFUSION_TEST_MARKER"]
real = pathlib.Path.write_bytes

def write_bytes(self, data):
    """A disk that stalls half-way through one checkpoint: half the bytes reach the file, then nothing."""
    if self.name.startswith("." + target + ".tmp"):
        with open(self, "wb") as fh:
            fh.write(data[: len(data) // 2])
            fh.flush()
            os.fsync(fh.fileno())
        pathlib.Path(marker).write_text(f"{self}\\n{len(data)}")
        time.sleep(600)
    return real(self, data)

pathlib.Path.write_bytes = write_bytes
from rmpfusion.cli.run import train
sys.argv[0] = "rmpfusion-train"
train()
'''


@pytest.mark.slow
def test_sigkill_during_a_checkpoint_write_leaves_no_half_written_checkpoint(outdir, reference, tmp_path):
    """The second checkpoint's bytes stall half-way (a hook in the child's file writes); SIGKILL then. The
    first checkpoint stays complete, no ckpt file is half-written, and the rerun ignores and removes the
    temporary, resumes from the complete checkpoint and ends at the uninterrupted weights."""
    run_dir = tmp_path / "run"
    ck = run_dir / "checkpoints" / "rmp"
    marker = tmp_path / "stalled"
    hooked = Proc(
        [sys.executable, "-c", SLOW_WRITE] + TRAIN + [f"hydra.run.dir={run_dir}"],
        tmp_path / "logs1",
        env=_env(RMPFUSION_TEST_SLOW_NAME="ckpt-00000020.pt", RMPFUSION_TEST_MARKER=str(marker)),
    )
    hooked.wait_until(
        marker.exists, "the stalled write of ckpt-00000020.pt (does the atomic writer still use Path.write_bytes?)"
    )
    time.sleep(0.05)  # the marker is written after the bytes: the file is as a crash would leave it
    os.kill(hooked.pid, signal.SIGKILL)
    assert hooked.wait() == -signal.SIGKILL
    tmp_file, full_size = marker.read_text().split("\n")
    tmp_file = Path(tmp_file)

    # what a crash leaves: the previous checkpoint whole, the new one only as a (half-written) temporary
    assert sorted(p.name for p in ck.glob("ckpt-*.pt")) == ["ckpt-00000010.pt"]
    assert _ckpt(ck / "ckpt-00000010.pt")["iteration"] == 10  # loads completely
    assert tmp_file.parent == ck and tmp_file.exists() and 0 < tmp_file.stat().st_size < int(full_size)
    with pytest.raises(Exception):  # noqa: B017  (torch's error for a cut-off file differs between versions)
        torch.load(tmp_file, map_location="cpu", weights_only=True)  # it really is half a file
    assert latest_checkpoint(ck).name == "ckpt-00000010.pt"  # never a candidate for resuming

    again = _done(train_proc(run_dir, tmp_path / "logs2"))
    assert "learner rmp: resumed from iteration 10" in again.stdout
    assert f"removed {tmp_file}" in again.stdout
    assert not tmp_file.exists() and not list(ck.glob(".*tmp*")), list(ck.iterdir())
    _assert_same_weights(run_dir, reference)


DAGGER_ITERS = 300
DAGGER = [
    "data=tiny",
    "train=dagger",
    "eval=fast",
    "logger=disabled",
    "weights@learners.rmp.weights=mlp_small",
    f"train.iterations={DAGGER_ITERS}",
    "train.checkpoint_every=10",
    "train.log_every=50",
    f"train.snapshots=[0,{DAGGER_ITERS}]",
    "train.compile=false",
    "train.batch_size=16",
    "train.rounds=2",
    "train.initial_trajectories=2",
    "train.trajectories_per_round=3",
]


@pytest.mark.slow
def test_dagger_killed_after_a_round_resumes_to_the_weights_and_data_of_an_uninterrupted_run(tmp_path):
    """DAgger's state is more than the weights: the data aggregated from the learner's rollouts so far. SIGKILL
    after round 1 (iteration 100) and before round 2 (200); the rerun resumes from the last checkpoint, keeps
    round 1's data, aggregates round 2 and ends at the weights, losses and expert queries of an uninterrupted run."""
    ref_dir, run_dir = tmp_path / "uninterrupted", tmp_path / "run"
    reference = Proc(_app("train") + DAGGER + [f"hydra.run.dir={ref_dir}"], tmp_path / "logs-ref")
    ck = run_dir / "checkpoints" / "rmp"

    def past_round_one() -> bool:
        last = latest_checkpoint(ck)
        return last is not None and int(last.stem.split("-")[1]) >= 110

    first = Proc(_app("train") + DAGGER + [f"hydra.run.dir={run_dir}"], tmp_path / "logs1")
    first.wait_until(past_round_one, "a checkpoint after DAgger's first round")
    os.kill(first.pid, signal.SIGKILL)
    assert first.wait() == -signal.SIGKILL
    killed = _ckpt(latest_checkpoint(ck))
    assert 100 < killed["iteration"] < 200, "the kill did not land between the rounds"
    assert [r["round"] for r in killed["method_state"]["rounds"]] == [0, 1]
    again = _done(Proc(_app("train") + DAGGER + [f"hydra.run.dir={run_dir}"], tmp_path / "logs2"))
    assert f"learner rmp: resumed from iteration {killed['iteration']}" in again.stdout
    assert "dagger round 2/2 at iteration 200" in again.stdout and "dagger round 1/2" not in again.stdout
    _done(reference)
    final = f"ckpt-{DAGGER_ITERS:08d}.pt"
    ref, got = _ckpt(ref_dir / "checkpoints" / "rmp" / final), _ckpt(ck / final)
    for k, v in ref["model"].items():
        assert torch.equal(got["model"][k], v), f"{k} differs from the uninterrupted run"
    assert got["curve"] == ref["curve"] and got["val_curve"] == ref["val_curve"]
    assert got["method_state"]["rounds"] == ref["method_state"]["rounds"]
    for k, v in ref["method_state"]["data"].items():
        assert torch.equal(got["method_state"]["data"][k], v), k


# ------------------------------------------------------------------------------------- one run per dir
@pytest.mark.slow
def test_rerun_with_another_config_is_refused_and_changes_nothing(outdir, reference):
    run_dir = outdir / "uninterrupted"
    watched = [run_dir / ".hydra" / n for n in ("config.yaml", "overrides.yaml", "hydra.yaml")]
    watched += [
        run_dir / "config.resolved.yaml",
        run_dir / "versions.json",
        *sorted((run_dir / "checkpoints").rglob("*.pt")),
    ]
    before = {p: p.read_bytes() for p in watched}
    proc = train_proc(run_dir, outdir / "logs-conflict", "train.lr=0.01")
    assert proc.wait() == 2, proc.stderr[-3000:]
    err = proc.stderr
    assert "already holds a run with a different configuration" in err and str(run_dir / "config.resolved.yaml") in err
    assert "train.lr: 0.001 (saved) vs 0.01 (now)" in err and "hydra.run.dir=" in err
    assert "Traceback" not in err
    assert {p: p.read_bytes() for p in watched} == before  # Hydra's .hydra/ files were put back too
    assert sorted((run_dir / "checkpoints").rglob("*.pt")) == sorted(p for p in watched if p.suffix == ".pt")


def test_a_busy_run_directory_is_refused(tmp_path):
    """Two processes never share a run directory: the kernel lock is held for the job, released by any exit
    (the SIGKILL tests above restart in the directory of a killed holder)."""
    from rmpfusion.cli.rundir import LOCK, RunDirError, exclusive

    probe = (
        "import fcntl, os, sys\nfd = os.open(sys.argv[1], os.O_RDWR)\ntry:\n"
        "    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB); print('acquired')\n"
        "except BlockingIOError: print('busy:', os.pread(fd, 100, 0).decode().strip())"
    )
    with exclusive(tmp_path):
        r = subprocess.run(
            [sys.executable, "-c", probe, str(tmp_path / LOCK)], capture_output=True, text=True, timeout=60
        )
        assert r.stdout.strip().startswith(f"busy: pid {os.getpid()} on "), r.stdout + r.stderr
        busy = rf"{re.escape(str(tmp_path))} is in use by pid {os.getpid()} on "
        with pytest.raises(RunDirError, match=busy), exclusive(tmp_path):  # what a second job in the directory is told
            pytest.fail("a second holder got the lock")
    r = subprocess.run([sys.executable, "-c", probe, str(tmp_path / LOCK)], capture_output=True, text=True, timeout=60)
    assert r.stdout.strip() == "acquired", r.stdout + r.stderr


def test_run_log_holds_the_jobs_lines_and_how_it_ended(tmp_path):
    """Hydra's log of the job (``<job name>.log``: run.log for the rmpfusion-run app, whose stages share it) holds
    every line the job printed, time-stamped in Hydra's format (stdout INFO, stderr WARNING), and how the job
    ended; the console shows each line once."""
    run_dir = tmp_path / "run"
    args = ["data=tiny", "logger=disabled", f"hydra.run.dir={run_dir}"]
    r = subprocess.run(_app("collect") + args, capture_output=True, text=True, timeout=300, env=_env(), cwd=tmp_path)
    assert r.returncode == 0, r.stderr[-3000:]
    lines = (run_dir / "run.log").read_text().splitlines()
    stamp = r"^\[\d{4}-\d\d-\d\d \d\d:\d\d:\d\d,\d{3}\]\[rmpfusion\]\[(INFO|WARNING|ERROR)\] - "
    assert lines and all(re.match(stamp, ln) for ln in lines), lines[:5]
    assert re.search(r"\[INFO\] - job started in .*run \(pid \d+\): ", lines[0]), lines[0]
    for printed in ("data: collecting train set", "collect train [", "train: 12 points in"):
        # as often as on the console, which shows it once (Hydra's console handler does not print it again)
        assert sum(printed in ln for ln in lines) == r.stdout.count(printed) == (3 if "[" in printed else 1), printed
    assert lines[-1].endswith("[INFO] - job finished")
    assert len([ln for ln in lines if "[INFO] - " in ln]) - 2 == len(r.stdout.strip().splitlines())

    r = subprocess.run(_app("evaluate") + args, capture_output=True, text=True, timeout=300, env=_env(), cwd=tmp_path)
    assert r.returncode == 1 and "no fully trained checkpoints" in r.stderr
    lines = (run_dir / "run.log").read_text().splitlines()
    assert any("[WARNING] - error: no fully trained checkpoints" in ln for ln in lines)
    assert (
        lines[-1].endswith("[ERROR] - job stopped with exit status 1") and sum("job started" in ln for ln in lines) == 2
    )


# ---------------------------------------------------------------------------------------------- sweeps
@pytest.fixture(scope="module")
def sweep(outdir, background) -> Path:
    _done(background["sweep"], timeout=600)
    return outdir / "sweep"


@pytest.mark.slow
def test_submitit_local_multirun_two_complete_runs_and_two_offline_wandb_runs(sweep):
    jobs = sorted(p for p in sweep.iterdir() if p.is_dir() and not p.name.startswith("."))
    assert [j.name for j in jobs] == JOBS  # the directories say what each job ran
    assert len(list(sweep.glob(".submitit/*/*_result.pkl"))) == 2  # really two submitit jobs
    for seed, job in enumerate(jobs):
        metrics = json.loads((job / "metrics.json").read_text())
        assert metrics["seed"] == seed
        assert yaml.safe_load((job / "config.resolved.yaml").read_text())["seed"] == seed
        for split in ("train", "test"):
            assert Path(metrics["data"][split]["path"]).parent == job / "data"
            assert Path(metrics["data"][split]["path"]).is_file()
        assert (job / "checkpoints" / "rmp" / "final.pt").is_file()
        figures = sorted(Path(f) for f in metrics["figures"])
        assert len(figures) >= 4 and all(f.parent == job / "figures" and f.is_file() for f in figures)
        assert (job / "console.log").is_file() and "done in" in (job / "console.log").read_text()
        assert json.loads((job / "versions.json").read_text())["packages"]["torch"] == torch.__version__
        # exactly one wandb run per job, offline, in the job's own directory, with every figure as an image
        runs = list((job / "wandb").glob("offline-run-*"))
        assert len(runs) == 1 and not list((job / "wandb").glob("run-*")), list((job / "wandb").iterdir())
        images = list((runs[0] / "files" / "media" / "images").rglob("*.png"))
        assert sorted(re.sub(r"_\d+_[0-9a-f]+$", "", p.stem) for p in images) == sorted(f.stem for f in figures)
        # config (with the versions), training curves and final metrics are in the run's log (protobuf records)
        record = next(runs[0].glob("run-*.wandb")).read_bytes()
        for needle in ("versions", torch.__version__, "rmp/train_loss", "rmp/batch_loss", "figures/lyapunov_rmp"):
            assert needle.encode() in record, needle
    ids = {(j / "wandb" / "run_id").read_text() for j in jobs}
    assert len(ids) == 2


@pytest.mark.slow
def test_package_versions_are_recorded(sweep):
    from importlib.metadata import version

    import hydra
    import numpy
    import omegaconf
    import pydantic
    import wandb

    rec = json.loads((sweep / JOBS[0] / "versions.json").read_text())
    assert rec["python"] == platform.python_version()
    want = {
        "torch": torch.__version__,
        "numpy": numpy.__version__,
        "hydra-core": hydra.__version__,
        "omegaconf": omegaconf.__version__,
        "pydantic": pydantic.VERSION,
        "wandb": wandb.__version__,
        "pybullet": version("pybullet"),
        "rmpfusion": version("rmpfusion"),
    }
    assert {k: rec["packages"][k] for k in want} == want
    assert rec["torch_threads"] == 1 and rec["cpu_count"] == os.cpu_count() and rec["platform"]
    import rmpfusion

    source = Path(rmpfusion.__file__).resolve().parents[1]
    if (source / ".git").exists():  # a source checkout: its commit, read without running git
        assert re.fullmatch(r"[0-9a-f]{40}", rec["git"]["commit"] or ""), rec["git"]
        assert rec["git"]["repo"] == str(source)


@pytest.mark.slow
def test_same_seed_same_dataset_and_losses_in_another_process_and_directory(sweep, tmp_path):
    """Job 0's exact overrides, rerun here in-process in a fresh directory: byte-identical datasets (checksums),
    identical losses and weights. Seed 1 differs, so the equality is not vacuous."""
    from rmpfusion.pipeline.compose import compose_run
    from rmpfusion.pipeline.run import run_experiment

    job0, job1 = sweep / JOBS[0], sweep / JOBS[1]
    overrides = yaml.safe_load((job0 / ".hydra" / "overrides.yaml").read_text())
    run = compose_run(overrides + ["eval.figures=false"])
    # the jobs ran in fresh interpreters (default dtype float32), this one under tests/conftest.py (float64):
    # the same numbers prove that nothing depends on torch's global default dtype
    assert torch.get_default_dtype() == torch.float64
    mine = run_experiment(run, tmp_path / "again", progress=False)
    theirs = json.loads((job0 / "metrics.json").read_text())
    other = json.loads((job1 / "metrics.json").read_text())
    for split in ("train", "test"):
        assert mine["data"][split]["sha256"] == theirs["data"][split]["sha256"] != other["data"][split]["sha256"]
    a, b = mine["learners"]["rmp"], theirs["learners"]["rmp"]
    for key in ("final_train_loss", "batch_loss", "online_loss"):
        assert a[key] == b[key], key
    assert a["final_train_loss"] != other["learners"]["rmp"]["final_train_loss"]
    w0 = _ckpt(job0 / "checkpoints" / "rmp" / "final.pt")["model"]
    w1 = _ckpt(tmp_path / "again" / "checkpoints" / "rmp" / "final.pt")["model"]
    assert all(torch.equal(w0[k], w1[k]) for k in w0)


def _summarize(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, str(REPO / "tools" / "summarize_sweep.py"), *args],
        capture_output=True,
        text=True,
        timeout=120,
        env=_env(),
    )


@pytest.mark.slow
def test_summarize_sweep_table_and_figure(sweep, tmp_path):
    r = _summarize(str(sweep), "--out", str(tmp_path / "report"))
    assert r.returncode == 0, r.stderr
    out = tmp_path / "report"
    assert (out / "summary.png").stat().st_size > 1000 and (out / "summary.md").read_text() in r.stdout
    rows = json.loads((out / "summary.json").read_text())["rows"]
    rmp = next(row for row in rows if row["learner"] == "rmp")
    assert rmp["setting"] == "(all jobs)" and sorted(rmp["seeds"]) == ["0", "1"]
    losses = [json.loads((sweep / j / "metrics.json").read_text())["learners"]["rmp"]["batch_loss"] for j in JOBS]
    assert rmp["batch_loss"]["n"] == 2
    assert rmp["batch_loss"]["mean"] == pytest.approx(statistics.fmean(losses), rel=1e-12)
    assert rmp["batch_loss"]["std"] == pytest.approx(statistics.stdev(losses), rel=1e-12)
    line = next(ln for ln in (out / "summary.md").read_text().splitlines() if ln.startswith("| (all jobs) | rmp |"))
    assert f"{statistics.fmean(losses):.4g} ± {statistics.stdev(losses):.4g}" in line


@pytest.mark.slow
def test_summarize_sweep_groups_by_setting_and_reports_unfinished_jobs(sweep, tmp_path):
    """Jobs of two settings x two seeds (the real job's metrics with other numbers), one job unfinished."""
    base = json.loads((sweep / JOBS[0] / "metrics.json").read_text())
    d = tmp_path / "lr_sweep"
    losses = {("0.001", 0): 1.0, ("0.001", 1): 3.0, ("0.01", 0): 10.0, ("0.01", 1): 20.0}
    for n, ((lr, seed), loss) in enumerate(losses.items()):
        job = d / f"{n}_2d1level"
        (job / ".hydra").mkdir(parents=True)
        (job / ".hydra" / "overrides.yaml").write_text(yaml.safe_dump([f"train.lr={lr}", f"seed={seed}", "data=tiny"]))
        m = json.loads(json.dumps(base))
        m["seed"], m["learners"]["rmp"]["batch_loss"], m["learners"]["rmp"]["val_loss"] = seed, loss, loss / 2
        (job / "metrics.json").write_text(json.dumps(m))
    late = d / "4_2d1level" / ".hydra"
    late.mkdir(parents=True)
    late.joinpath("overrides.yaml").write_text(yaml.safe_dump(["train.lr=0.1", "seed=0", "data=tiny"]))
    r = _summarize(str(d))
    assert r.returncode == 0, r.stderr
    assert "4_2d1level" in r.stderr and "no metrics.json" in r.stderr
    rows = {(row["setting"], row["learner"]): row for row in json.loads((d / "summary.json").read_text())["rows"]}
    assert rows[("train.lr=0.001", "rmp")]["batch_loss"] == {"n": 2, "mean": 2.0, "std": pytest.approx(2**0.5)}
    assert rows[("train.lr=0.01", "rmp")]["batch_loss"] == {"n": 2, "mean": 15.0, "std": pytest.approx(50**0.5)}
    assert rows[("train.lr=0.01", "rmp")]["val_loss"] == {"n": 2, "mean": 7.5, "std": pytest.approx(12.5**0.5)}
    assert "| train.lr=0.01 | rmp | 2 | 0, 1 | 7.5 ± 3.536 | 15 ± 7.071 |" in (d / "summary.md").read_text()

    shutil.rmtree(d)
    late.mkdir(parents=True)
    late.joinpath("overrides.yaml").write_text(yaml.safe_dump(["seed=0"]))
    r = _summarize(str(d))
    assert r.returncode == 1 and "no finished job" in r.stderr and "4_2d1level" in r.stderr
    assert not (d / "summary.md").exists()
