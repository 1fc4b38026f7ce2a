"""The command line before a run: the debug switch, and which job of a sweep the preflight composes."""

from __future__ import annotations

import os
import subprocess
import sys


def _validate(*args: str, **env: str) -> subprocess.CompletedProcess:
    full = {k: v for k, v in os.environ.items() if k not in ("RMPFUSION_DEBUG", "HYDRA_FULL_ERROR")}
    full.update(WANDB_MODE="disabled", **env)
    return subprocess.run(
        [sys.executable, "-m", "rmpfusion.cli.validate", *args],
        capture_output=True,
        text=True,
        env=full,
        cwd="/",
        timeout=300,
    )


def test_a_mistake_is_one_line_and_the_debug_switch_shows_the_traceback():
    plain = _validate("experimnt=2d1level")
    assert plain.returncode == 2 and "Traceback" not in plain.stderr
    assert plain.stderr.startswith("error: 'experimnt' is neither a config group nor a key of the config; did you mean")
    debug = _validate("experimnt=2d1level", RMPFUSION_DEBUG="1")
    assert debug.returncode != 0 and "Traceback (most recent call last)" in debug.stderr
    assert "CommandLineError" in debug.stderr and "check_command_line" in debug.stderr


def test_every_kind_of_sweep_is_checked_on_its_first_job_or_left_to_its_sweeper():
    from pathlib import Path

    from rmpfusion.cli.preflight import _first_job

    conf = [Path(__file__).resolve().parents[1] / "conf"]
    assert _first_job(
        [
            "experiment=glob(2d*,exclude=2d1*)",
            "seed=1,2",
            "seed=range(3,5)",
            "train.lr=choice(1e-3,1e-2)",
            "train.lr=tag(log,interval(1e-4,1e-2))",
            "hydra.run.dir=/x",
            "hydra/launcher=joblib",
        ],
        conf,
    ) == ["experiment=2d2level", "seed=1", "seed=3", "train.lr=0.001"]


def test_a_misspelt_key_is_answered_with_the_keys_of_the_blocks_the_command_chose():
    """experiment=lasa chooses a recorded data block and recorded_arm an arm's env: a misspelt key of either is
    answered with that block's keys, not those of the default config's blocks."""
    data = _validate("experiment=lasa", "data.unit=mm")
    assert data.returncode == 2 and "did you mean 'data.units'" in data.stderr and "time_units" in data.stderr
    env = _validate("experiment=recorded_arm", "env.control_rat=100")
    assert env.returncode == 2 and "did you mean 'env.control_rate'" in env.stderr
