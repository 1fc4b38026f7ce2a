"""A non-editable install (a wheel) carries conf/ inside the package, and its commands find it from any
directory without RMPFUSION_CONF."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.slow
def test_a_wheel_install_finds_its_configs(tmp_path):
    subprocess.run(
        [
            sys.executable,
            "-m",
            "pip",
            "wheel",
            str(ROOT),
            "--no-deps",
            "--no-build-isolation",
            "-q",
            "-w",
            str(tmp_path / "wheel"),
        ],
        check=True,
        capture_output=True,
        timeout=600,
    )
    wheel = next((tmp_path / "wheel").glob("rmpfusion-*.whl"))
    site = tmp_path / "site"
    subprocess.run(
        [sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--target", str(site), str(wheel)],
        check=True,
        capture_output=True,
        timeout=600,
    )
    env = {k: v for k, v in os.environ.items() if k != "RMPFUSION_CONF"}
    env.update(PYTHONPATH=str(site), WANDB_MODE="disabled")
    code = "import rmpfusion, rmpfusion.cli as c; print(rmpfusion.__file__); print(c.CONF_DIR)"
    where = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env=env, cwd=tmp_path, timeout=300, check=True
    ).stdout.split()
    assert where == [str(site / "rmpfusion" / "__init__.py"), str(site / "rmpfusion" / "conf")]
    assert len(list((site / "rmpfusion" / "conf").glob("*/*.yaml"))) == len(list((ROOT / "conf").glob("*/*.yaml")))
    r = subprocess.run(
        [sys.executable, "-m", "rmpfusion.cli.validate", "experiment=2d2level", f"hydra.run.dir={tmp_path / 'run'}"],
        capture_output=True,
        text=True,
        env=env,
        cwd=tmp_path,
        timeout=300,
    )
    assert r.returncode == 0 and "OK:" in r.stdout, r.stderr[-2000:]
