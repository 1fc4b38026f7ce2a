"""``device`` is not silently ignored: until GPU support lands anything but ``cpu`` is a ConfigError saying so."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir
from pydantic import ValidationError

from rmpfusion.build.errors import ConfigError
from rmpfusion.pipeline.config import RunConfig
from rmpfusion.pipeline.validate import resolve_and_validate

CONF = Path(__file__).resolve().parents[1] / "conf"
MESSAGE = ("device: 'cuda' is not supported yet: rmpfusion runs on the CPU only (device=cpu); "
           "set device=cpu or leave the key out")


def compose_cfg(overrides=()):
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        return compose("config", overrides=list(overrides))


def test_device_cpu_is_accepted():
    assert resolve_and_validate(compose_cfg(["device=cpu"])).device == "cpu"


def test_other_devices_are_a_config_error_naming_key_value_and_fix():
    with pytest.raises(ConfigError) as err:
        resolve_and_validate(compose_cfg(["device=cuda"]))
    assert [str(i) for i in err.value.issues] == [MESSAGE]
    with pytest.raises(ConfigError) as err:
        resolve_and_validate(compose_cfg(["device=cuda:1"]))
    assert [str(i) for i in err.value.issues] == [MESSAGE.replace("'cuda'", "'cuda:1'")]


def test_device_is_reported_with_the_other_problems():
    with pytest.raises(ConfigError) as err:
        resolve_and_validate(compose_cfg(["device=mps", "expert.goal.type=rfb"]))
    paths = [i.path for i in err.value.issues]
    assert paths[0] == "device" and "expert.goal.type" in paths


def test_run_config_itself_only_takes_cpu():
    """The schema is the contract other entry points (checkpoints) validate against: it holds the same rule."""
    with pytest.raises(ValidationError):
        RunConfig.model_validate({"env": {"type": "particle2d"}, "tree": {}, "device": "cuda"})


def test_validate_cli_prints_the_message(tmp_path):
    env = {**os.environ, "WANDB_MODE": "disabled", "HYDRA_FULL_ERROR": "0"}
    r = subprocess.run([sys.executable, "-m", "rmpfusion.cli.validate", "device=cuda", f"hydra.run.dir={tmp_path}"],
                       capture_output=True, text=True, timeout=300, cwd=str(tmp_path), env=env)
    assert r.returncode == 2, r.stderr
    assert r.stderr.strip() == f"error: invalid configuration: 1 problem(s)\n  - {MESSAGE}"
