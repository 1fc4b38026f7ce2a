"""``RMPFUSION_DEBUG=1`` turns the one-line answers to mistakes back into full tracebacks."""
from __future__ import annotations

import os
import subprocess
import sys


def _validate(*args: str, **env: str) -> subprocess.CompletedProcess:
    full = {k: v for k, v in os.environ.items() if k not in ("RMPFUSION_DEBUG", "HYDRA_FULL_ERROR")}
    full.update(WANDB_MODE="disabled", **env)
    return subprocess.run([sys.executable, "-m", "rmpfusion.cli.validate", *args], capture_output=True, text=True,
                          env=full, cwd="/", timeout=300)


def test_a_mistake_is_one_line_and_the_debug_switch_shows_the_traceback():
    plain = _validate("experimnt=2d1level")
    assert plain.returncode == 2 and "Traceback" not in plain.stderr
    assert plain.stderr.startswith("error: 'experimnt' is neither a config group nor a key of the config; did you mean")
    debug = _validate("experimnt=2d1level", RMPFUSION_DEBUG="1")
    assert debug.returncode != 0 and "Traceback (most recent call last)" in debug.stderr
    assert "CommandLineError" in debug.stderr and "check_command_line" in debug.stderr
