"""The example plugin (tests/plugin_example), pip-installed like a third-party package, extends rmpfusion
from outside: its RMP is found through the entry point, its YAML presets through Hydra's search path."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import TINY, pip_install_into, section_of  # and the plugin_site fixture: the example plugin pip-installed


def _cli(site: Path, *args, timeout=300):
    env = {
        **os.environ,
        "WANDB_MODE": "disabled",
        "PYTHONPATH": os.pathsep.join([str(site), os.environ.get("PYTHONPATH", "")]),
    }
    return subprocess.run(
        [sys.executable, "-m", *args], capture_output=True, text=True, timeout=timeout, cwd="/", env=env
    )


def test_without_plugin_the_name_is_unknown(tmp_path):
    env = {**os.environ, "WANDB_MODE": "disabled"}
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "rmpfusion.cli.validate",
            "tree.nodes.goal.rmp.type=spring",
            f"hydra.run.dir={tmp_path}",
        ],
        capture_output=True,
        text=True,
        env=env,
        cwd="/",
        timeout=300,
    )
    assert r.returncode == 2 and "unknown leaf RMP 'spring'" in r.stderr


@pytest.mark.slow
def test_plugin_preset_from_command_line_reaches_built_tree(plugin_site, tmp_path):
    r = _cli(
        plugin_site,
        "rmpfusion.cli.validate",
        "rmp@tree.nodes.goal.rmp=spring",
        "tree.nodes.goal.rmp.gain=7",
        f"hydra.run.dir={tmp_path}",
    )
    assert r.returncode == 0, r.stderr
    assert "goal (dim 2)  map=offset  weight=rbf  rmp=spring" in r.stdout


@pytest.mark.slow
def test_plugin_tree_file_trains_a_few_steps(plugin_site, tmp_path):
    """tree=2d1level_spring lives only in the plugin package; the whole pipeline runs on it."""
    r = _cli(plugin_site, "rmpfusion.cli.run", "tree=2d1level_spring", *TINY, f"hydra.run.dir={tmp_path}", timeout=600)
    assert r.returncode == 0, r.stderr[-3000:]
    import json

    m = json.loads((tmp_path / "metrics.json").read_text())
    assert m["learners"]["rmp"]["snapshots"].keys() == {"0", "3"}
    assert "spring" in (tmp_path / "config.resolved.yaml").read_text()


@pytest.mark.slow
def test_plugin_rmp_in_process(plugin_site, monkeypatch):
    """Loaded lazily on first lookup, from a spec given as a plain dict."""
    monkeypatch.syspath_prepend(str(plugin_site))
    import importlib

    from rmpfusion import registry

    monkeypatch.setattr(registry.PLUGINS, "loaded", False)
    importlib.invalidate_caches()
    import torch

    from rmpfusion import build_tree

    tree = build_tree(
        {
            "root": {"name": "q", "dim": 2},
            "nodes": {"s": {"parent": "q", "map": {"type": "identity"}, "rmp": {"type": "spring", "gain": 2.0}}},
        }
    )
    q = torch.tensor([[1.0, -2.0]], dtype=torch.float64)
    out = tree(q, torch.zeros_like(q))
    torch.testing.assert_close(out.qdd, -2.0 * q)


def _readme_leaf_recipe() -> str:
    """The plugin tutorial's leaf-RMP code, verbatim, without the line that only lets the page run it twice."""
    _, section = section_of("# Adding an RMP as a plugin")
    code = section[section.index("```python\n") + len("```python\n") :]
    code = code[: code.index("```")]
    assert "class MySpring(GDS)" in code and "def curvature" not in code  # curvature terms left to autodiff
    return "\n".join(line for line in code.splitlines() if not line.startswith("LEAF_RMPS.unregister"))


@pytest.fixture(scope="session")
def readme_plugin_site(tmp_path_factory) -> Path:
    """The README's recipe as a fresh package, declared through the entry point the README shows, pip-installed."""
    root = tmp_path_factory.mktemp("readme_plugin")
    pkg = root / "src" / "rmpfusion_myspring"
    pkg.mkdir(parents=True)
    (pkg / "__init__.py").write_text(_readme_leaf_recipe() + "\n")
    (root / "src" / "pyproject.toml").write_text(
        '[build-system]\nrequires = ["setuptools"]\nbuild-backend = "setuptools.build_meta"\n\n'
        '[project]\nname = "rmpfusion-myspring"\nversion = "0.1"\n\n'
        '[project.entry-points."rmpfusion.plugins"]\nmy_spring = "rmpfusion_myspring"\n\n'
        '[tool.setuptools]\npackages = ["rmpfusion_myspring"]\n'
    )
    return pip_install_into(root / "src", root / "site")


@pytest.mark.slow
def test_readme_leaf_recipe_runs_compiled_at_every_batch_size_like_eager(readme_plugin_site, tmp_path):
    """A leaf with autodiff curvature, in the default pipeline with compilation on (training and evaluation see
    several batch sizes): the run completes, says once per tree how it compiles, and equals the eager run."""
    leaf = ["~tree.nodes.goal.rmp", "+tree.nodes.goal.rmp.type=my_spring", "data=tiny", "train=tiny", "logger=disabled"]
    compiled = _cli(
        readme_plugin_site,
        "rmpfusion.cli.run",
        *leaf,
        "+train.compile=true",
        "eval.compile=true",
        f"hydra.run.dir={tmp_path / 'compiled'}",
        timeout=900,
    )
    assert compiled.returncode == 0, compiled.stderr[-3000:]
    assert "Traceback" not in compiled.stderr and "storage_offset" not in compiled.stderr
    assert "compiles once per batch size (static shapes), with the same numbers" in compiled.stderr
    eager = _cli(
        readme_plugin_site,
        "rmpfusion.cli.run",
        *leaf,
        "eval.compile=false",
        f"hydra.run.dir={tmp_path / 'eager'}",
        timeout=600,
    )
    assert eager.returncode == 0, eager.stderr[-3000:]
    import json

    from rmpfusion.studies.compare import compare

    runs = [json.loads((tmp_path / d / "metrics.json").read_text()) for d in ("compiled", "eager")]
    for m in runs:  # the compiled expert's demonstrations equal the eager one's to rounding, not bit for bit: their
        for split in m["data"].values():  # checksums differ, every number made from them agrees to 1e-9
            if isinstance(split, dict):
                split.pop("sha256", None)
    n, _worst, differ, _ = compare(*runs, rtol=1e-9)
    assert n > 20 and not differ, differ
