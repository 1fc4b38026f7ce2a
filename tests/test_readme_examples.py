"""The configuration guide's examples run as written: README.md's if merged there, else docs/config-guide.md."""
from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SECTIONS = ("Writing a tree in YAML", "Overriding and sweeping", "Adding an RMP as a plugin", "Validating configs")


def _guide() -> str:
    readme = ROOT / "README.md"
    if readme.is_file() and all(s in readme.read_text() for s in SECTIONS):
        return readme.read_text()
    return (ROOT / "docs" / "config-guide.md").read_text()


def _blocks(lang: str) -> list[str]:
    return re.findall(rf"```{lang}\n(.*?)```", _guide(), flags=re.S)


EXAMPLES = {lang: _blocks(lang) for lang in ("yaml", "python", "bash", "toml")}


def test_guide_has_all_sections():
    text = _guide()
    assert all(f"## {s}" in text for s in SECTIONS)


@pytest.mark.parametrize("i", range(len(EXAMPLES["python"])))
def test_python_examples_run(i):
    exec(compile(EXAMPLES["python"][i], f"guide-python-{i}", "exec"),
         {"EXAMPLES": EXAMPLES, "CONF_DIR": str(ROOT / "conf"), "__name__": "guide"})


def _validate_commands() -> list[str]:
    cmds = [ln.split("#")[0].strip() for b in EXAMPLES["bash"] for ln in b.splitlines()]
    return [c for c in cmds if c.startswith("rmpfusion-validate")]


@pytest.mark.parametrize("cmd", _validate_commands())
def test_validate_commands_behave_as_documented(cmd, tmp_path):
    """Commands whose options come from the example plugin are run only when it is installed."""
    args = shlex.split(cmd)[1:]
    if any("spring" in a for a in args):
        pytest.skip("uses the example plugin; tests/test_plugins.py runs it installed")
    env = {**os.environ, "WANDB_MODE": "disabled"}
    r = subprocess.run([sys.executable, "-m", "rmpfusion.cli.validate", *args, f"hydra.run.dir={tmp_path}"],
                       capture_output=True, text=True, env=env, cwd="/", timeout=300)
    if "rfb" in cmd:  # the documented failing example
        assert r.returncode == 2 and "did you mean 'gain'" in r.stderr and "did you mean 'rbf'" in r.stderr
        assert "did you mean 'goal'" in r.stderr
    else:
        assert r.returncode == 0, r.stderr


def test_documented_sweep_and_run_overrides_compose():
    """rmpfusion-run commands in the guide compose (running them is tests/test_configs.py's sweep test)."""
    from hydra import compose, initialize_config_dir

    cmds = [ln.split("#")[0].strip() for b in EXAMPLES["bash"] for ln in b.splitlines()]
    runs = [shlex.split(c)[1:] for c in cmds if c.startswith("rmpfusion-run")]
    assert runs
    def one_point(a: str) -> str:  # a multirun sweep `key=a,b,c` composes as its first point
        key, _, value = a.partition("=")
        return f"{key}={value.split(',')[0]}" if "," in value and value[:1] not in "[{(" and "(" not in value else a

    for args in runs:
        multirun = "-m" in args or "--multirun" in args
        over = [one_point(a) if multirun else a for a in args
                if a not in ("-m", "--multirun") and "spring" not in a and "glob(" not in a]
        with initialize_config_dir(config_dir=str(ROOT / "conf"), version_base="1.3"):
            compose("config", overrides=over, return_hydra_config=True)


def test_toml_entry_point_matches_example_plugin():
    plugin = (ROOT / "tests" / "plugin_example" / "pyproject.toml").read_text()
    assert EXAMPLES["toml"][0].strip() in plugin
