"""Every code block of the documentation (README.md and the hand-written pages of docs/) runs as written, in a fresh
process from the repository root.

* ``python`` blocks: ``python -c <block>`` with the repository root as working directory; nothing is injected, so
  a block that needs a name or a file must say where it comes from.
* ``bash`` blocks: every command line (comments stripped) runs with ``bash -c`` from the repository root, with the
  virtualenv's console scripts on PATH. Two things are appended to the command as written, never changed in it:
  every Hydra command gets its own output directory under pytest's tmp_path (``hydra.run.dir=`` /
  ``hydra.sweep.dir=``, so nothing is written to outputs/), and a command that runs the pipeline gets the
  overrides that make it tiny (``TINY``): the same code end to end on a few points and steps. Lines of one block
  that share a ``hydra.run.dir=`` (the resume example) run in order in one test. Validation commands and the
  documented smoke run are cheap; everything else (whole experiments, sweeps, the plugin installed) is marked
  ``slow`` (``make test-all`` runs them).
* Blocks that are not commands are checked against what they show: a YAML block is a file of conf/ or is used
  verbatim by a Python block, a TOML block is part of the example plugin's pyproject.toml, the shell output of the
  failing validation is what that command prints; the run-directory listing and the source layout are prose.

Nothing is skipped silently: a command that must not run is listed in ``EXCLUDED`` with the reason, every block is
accounted for (``test_every_block_is_accounted_for``), and an exclusion that no longer matches a page fails.
"""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest
import yaml
from conftest import DOC_PAGES, PLUGIN_EXAMPLE, ROOT, compose_cfg, page_name
from conftest import TINY as TINY_RUN  # and the plugin_site fixture: ``pip install tests/plugin_example``

from rmpfusion.assembly import build_tree
from rmpfusion.core import RMPTree

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    tomllib = pytest.importorskip("tomli")


@dataclass(frozen=True)
class Block:
    lang: str
    text: str
    line: int  # of the opening fence, 1-based
    page: str = "README.md"  # from the repository root

    @property
    def first(self) -> str:
        return self.text.splitlines()[0] if self.text.strip() else ""

    @property
    def where(self) -> str:
        return f"{self.page} line {self.line}"


def page_blocks(page: Path) -> list[Block]:
    """The fenced blocks of one page; a MyST directive (```{toctree}, ```{include}) is the site's, not code."""
    blocks, lines = [], page.read_text(encoding="utf-8").splitlines(keepends=True)
    i = 0
    while i < len(lines):
        m = re.match(r"^```(\{[\w-]+\}|\w*)", lines[i])
        if not m:
            i += 1
            continue
        j = i + 1
        while not lines[j].startswith("```"):
            j += 1
        if not m.group(1).startswith("{"):
            blocks.append(Block(m.group(1), "".join(lines[i + 1 : j]), i + 1, page_name(page)))
        i = j + 1
    return blocks


BLOCKS = [b for page in DOC_PAGES for b in page_blocks(page)]

#: Commands of bash blocks that are not run, and why (matched against the command without its comment).
EXCLUDED = {
    "make demo": "the full paper-size experiment (minutes; make may also install into .venv); the command it runs, "
    "rmpfusion-run experiment=2d1level, is the first line of the next block, run here at tiny sizes",
    "make test": "runs the test suite this file is part of",
    "rmpfusion-run -m 'experiment=glob(*)' data=tiny train=tiny eval=fast logger=disabled": "the same sweep as "
    "tests/test_configs.py::test_sweep_all_experiments_tiny (slow), which runs it and checks that every experiment "
    "wrote its metrics (minutes: run once, not twice)",
    "rmpfusion-run experiment=recorded_arm": "about 30 minutes; tests/test_recorded_arm.py runs it end to end at "
    "tiny sizes (slow)",
    "python tools/arm_recordings.py": "about 7 minutes (inverse kinematics and a clearance check of every plan); "
    "tests/test_recorded_arm.py runs it for one demonstration and compares it with the shipped file (slow)",
    "python tools/rosbag_recordings.py --out bags": "writes bags/ where "
    "it runs and refuses a second time (nothing is overwritten); tests/test_rosbag.py runs the tool into a temporary "
    "directory and reads its bags back",
    "rmpfusion-run experiment=recorded_arm data.format=rosbag data.demo_column=null 'data.files=[\"bags/demo*\"]'": (
        "reads the bags the line before writes; tests/test_rosbag.py validates this run's config on them and checks "
        "they land on the step grid as the CSV that experiment=recorded_arm (tested end to end) reads"
    ),
    "rmpfusion-run experiment=recorded_arm data.files=[my_demos.csv] 'data.aux_columns={obstacle1_center: [ox, oy, oz]}'": (
        "my_demos.csv stands for a user's file; tests/test_recorded_aux.py validates this config on such a file and "
        "checks that each demonstration's obstacle reaches training and evaluation"
    ),
    "rmpfusion-run -m experiment=2d2level sweep=seeds launcher=submitit_slurm hydra.launcher.partition=gpu": "needs a SLURM cluster (the submitit_local lines run the same launcher plugin on this machine)",
    "python tools/summarize_sweep.py outputs/multirun/<time>": "<time> stands for a sweep's directory; tests/test_runs.py runs summarize_sweep.py on a real sweep",
    "rmpfusion-view outputs/franka/<time>": "<time> stands for a Franka run's directory; tests/test_viewer.py views a real run's directory",
    "rmpfusion-export outputs/franka/<time>/checkpoints/rmp/final.pt --aoti": "<time> stands for a Franka run's directory; tests/test_export.py runs rmpfusion-export (and --aoti) on a real "
    "run's checkpoint",
}

#: Blocks that are not commands: first line -> what it is.
NOT_COMMANDS = {
    "config.resolved.yaml   the validated config that ran (.hydra/ holds Hydra's unresolved copy and the overrides)": "the files of a run directory (prose in a table)",
    "error: invalid configuration: 3 problem(s)": "the output of the failing rmpfusion-validate above it "
    "(compared with what that command prints)",
    "rmpfusion/core/      RMP-algebra*: pushforward, pullback*, resolve; GDS, TaskMap, WeightFunction bases; RMPTree": "the source layout",
    "#include <torch/csrc/inductor/aoti_package/model_package_loader.h>": "C++ for libtorch, which this machine does not build; the package it loads is checked from Python by "
    "tests/test_export.py",
}

#: Background pages whose unlabelled blocks are formulas and folder listings, never commands (every labelled block
#: on them is checked like any other).
FORMULA_PAGES = {"docs/math.md", "docs/architecture.md"}

#: Commands that fail on purpose, with their exit status.
FAILS = {"rmpfusion-validate expert.goal.type=rfb +tree.nodes.goal.rmp.gian=2 tree.nodes.goal.map.origin=gaol": 2}

#: Appended to every command that runs the pipeline (rmpfusion-run, rmpfusion-study run): tiny data, 3 training
#: steps, evaluation without figures or torch.compile, no wandb. The documented commands stay as written before them.
TINY = [*TINY_RUN, "eval.compile=false"]
#: Appended to a study's runs: TINY, and the sizes a run's own overrides set (Hydra applies every key override after
#: every group choice, so a run's train.iterations=20000 would outlast train=tiny).
TINY_STUDY = [
    *TINY,
    "train.iterations=3",
    "train.snapshots=[0,3]",
    "train.checkpoint_every=3",
    "train.log_every=1",
    "data.train_trajectories=2",
]
#: Appended to commands on recorded demonstrations (experiment=lasa): 3 training steps, 4 starts, rollouts as long
#: as the longest demonstration, no figures (the data are the dataset's own: there is nothing to make tiny).
TINY_RECORDED = [
    "logger=disabled",
    "train.iterations=3",
    "train.snapshots=[0,3]",
    "data.starts=4",
    "data.horizon_factor=1.0",
    "data.convergence_horizon_factor=2.0",
    "eval.figures=false",
]
#: The tools that compare training methods choose the method themselves: tiny splits and evaluation only.
TINY_EVAL = [
    "data.test_envs=1",
    "data.test_trajectories=2",
    "data.val_envs=1",
    "data.val_trajectories=2",
    "data.points=3",
    "data.interval=0.1",
    "eval=fast",
    "eval.compile=false",
]


def strip_comment(line: str) -> str:
    """The command without a trailing shell comment (a ``#`` after whitespace, outside quotes)."""
    quote = None
    for k, ch in enumerate(line):
        if quote:
            quote = None if ch == quote else quote
        elif ch in "'\"":
            quote = ch
        elif ch == "#" and (k == 0 or line[k - 1].isspace()):
            return line[:k].strip()
    return line.strip()


def commands(block: Block) -> list[str]:
    return [c for c in (strip_comment(ln) for ln in block.text.splitlines()) if c]


@dataclass(frozen=True)
class Unit:
    """Commands of one bash block that run together, in order (those sharing a hydra.run.dir)."""

    block: Block
    cmds: tuple[str, ...]

    @property
    def id(self) -> str:
        return f"{self.block.page}:L{self.block.line}:{self.cmds[0][:60]}"

    @property
    def needs_plugin(self) -> bool:  # the commands after "pip install tests/plugin_example" use its presets
        return any("spring" in c for c in self.cmds)

    @property
    def cheap(self) -> bool:
        def one(c: str) -> bool:
            if self.needs_plugin:
                return False
            if c.startswith(
                (
                    "rmpfusion-validate",
                    "rmpfusion-fit-spheres",
                    "python tools/tracking_demo.py",
                    "rmpfusion-view",
                    "rmpfusion-study table",
                    "rmpfusion-study list",
                )
            ):
                return True  # the tracking demo runs 0.1 s of its rollouts here (appended)
            return c.startswith("rmpfusion-run ") and " -m " not in c and "data=tiny train=tiny" in c  # the smoke run

        return all(one(c) for c in self.cmds)


def units() -> list[Unit]:
    out = []
    for b in BLOCKS:
        if b.lang != "bash":
            continue
        groups: dict[str, list[str]] = {}
        for c in commands(b):
            if c in EXCLUDED:
                continue
            m = re.search(r"hydra\.run\.dir=(\S+)", c)
            groups.setdefault(m.group(1) if m else c, []).append(c)
        out += [Unit(b, tuple(cs)) for cs in groups.values()]
    return out


UNITS = units()
PYTHON = [b for b in BLOCKS if b.lang == "python"]


def _env(**extra) -> dict:
    env = {
        **os.environ,
        "WANDB_MODE": "disabled",
        "MPLBACKEND": "Agg",
        "HYDRA_FULL_ERROR": "1",
        "PATH": os.pathsep.join([str(Path(sys.executable).parent), os.environ.get("PATH", "")]),
    }
    env.update(extra)
    return env


def appended(cmd: str, out: Path) -> list[str]:
    """What the test adds after the documented command (see the module docstring)."""
    if cmd.startswith("rmpfusion-validate"):
        return [f"hydra.run.dir={out}"]
    if cmd.startswith("python tools/tracking_demo.py"):
        return ["--seconds", "0.1"]  # every robot and leaf, 10 integration steps
    if cmd.startswith("rmpfusion-view"):
        return ["--horizon", "0.1", "--out", str(out / "viewer.html")]  # a tenth of a second of each rollout
    if cmd.startswith("rmpfusion-fit-spheres"):
        return []  # writes where the page says: under outputs/, which git ignores
    if cmd.startswith("python tools/apg_rows.py"):
        return [
            "--out",
            str(out),
            "data=tiny",
            *TINY_EVAL,
            "train.compile=false",
            "train.iterations=2",
            "train.snapshots=[0,2]",
            "train.horizon=0.5",
            "train.truncation=0.5",
            "train.batch_size=2",
            "train.log_every=1",
            "train.checkpoint_every=1",
        ]
    if cmd.startswith("python tools/sim_agreement.py"):
        return ["--samples", "1"]  # one configuration and state per robot
    if cmd.startswith(("rmpfusion-study table", "rmpfusion-study list")):
        return []  # reads results/ and the pages only
    if cmd.startswith("rmpfusion-study run"):  # the study's runs at tiny sizes, below pytest's tmp_path
        return ["--out", str(out), *(TINY_RECORDED if " lasa" in cmd else TINY_STUDY)]
    if cmd.startswith("rmpfusion-run"):
        extra = list(TINY_RECORDED if "experiment=lasa" in cmd else TINY)
        if " -m " in f" {cmd} ":
            extra.append(f"hydra.sweep.dir={out}")
            if "sweep=optuna_lr" in cmd:
                extra.append("hydra.sweeper.n_trials=2")  # the preset's 20 trials, two of them
        else:
            extra.append(f"hydra.run.dir={out}")
        return extra
    raise AssertionError(f"documented command {cmd!r} is neither run by this test nor listed in EXCLUDED")


def _following_text_block(block: Block) -> Block:
    k = BLOCKS.index(block)
    return BLOCKS[k + 1]


def _check_documented_output(out: str, block: Block) -> None:
    """Every line of the shown output, with ``...`` standing for elided text, appears in what the command printed."""
    for line in block.text.splitlines():
        pos = 0
        for piece in (p.strip() for p in line.split("...")):
            k = out.find(piece, pos)
            assert k >= 0, f"{block.where}: {line!r}: {piece!r} is not in what the command printed:\n{out}"
            pos = k + len(piece)


# ------------------------------------------------------------------------------------------------- python blocks
@pytest.mark.parametrize("block", PYTHON, ids=[f"{b.page}:L{b.line}" for b in PYTHON])
def test_python_block_runs_in_a_fresh_process(block):
    r = subprocess.run(
        [sys.executable, "-c", block.text], cwd=ROOT, capture_output=True, text=True, env=_env(), timeout=600
    )
    assert r.returncode == 0, f"{block.where}:\n{r.stdout[-2000:]}\n{r.stderr[-4000:]}"


# --------------------------------------------------------------------------------------------------- bash blocks
def _run_unit(unit: Unit, tmp_path: Path, request) -> None:
    env = _env()
    if unit.needs_plugin:
        site = request.getfixturevalue("plugin_site")
        env["PYTHONPATH"] = os.pathsep.join([str(site), os.environ.get("PYTHONPATH", "")])
    out = tmp_path / "out"
    for cmd in unit.cmds:
        line = " ".join([cmd, *(shlex.quote(a) for a in appended(cmd, out))])
        r = subprocess.run(["bash", "-c", line], cwd=ROOT, capture_output=True, text=True, env=env, timeout=1800)
        want = FAILS.get(cmd, 0)
        assert r.returncode == want, (
            f"{unit.block.where}: `{line}` exited {r.returncode}, expected "
            f"{want}\n{r.stdout[-2000:]}\n{r.stderr[-4000:]}"
        )
        if cmd in FAILS:
            assert "Traceback" not in r.stderr
            _check_documented_output(r.stderr, _following_text_block(unit.block))


CHEAP = [u for u in UNITS if u.cheap]
SLOW = [u for u in UNITS if not u.cheap]


@pytest.mark.parametrize("unit", CHEAP, ids=[u.id for u in CHEAP])
def test_bash_command_runs(unit, tmp_path, request):
    _run_unit(unit, tmp_path, request)


@pytest.mark.slow
@pytest.mark.parametrize("unit", SLOW, ids=[u.id for u in SLOW])
def test_bash_command_runs_tiny(unit, tmp_path, request):
    _run_unit(unit, tmp_path, request)


def test_every_run_command_composes():
    """The fast suite's check of the slow commands: each rmpfusion-run line (a sweep at its first point) composes
    with Hydra; the plugin's need the plugin, 'glob(*)' is expanded by the sweeper (both run in the slow tests)."""
    runs = [shlex.split(c)[1:] for u in UNITS for c in u.cmds if c.startswith("rmpfusion-run")]
    assert len(runs) >= 10
    for u in UNITS:  # a folder given by --config-dir is made by the same block's command before it (the robot fit)
        for c in u.cmds:
            made = [shlex.split(m) for m in commands(u.block) if m.startswith("rmpfusion-fit-spheres")]
            if "--config-dir" in c and not (ROOT / shlex.split(c)[shlex.split(c).index("--config-dir") + 1]).exists():
                assert made, f"{u.block.where}: {c!r} reads a --config-dir that no command before it writes"
                subprocess.run(made[0], cwd=ROOT, check=True, capture_output=True, env=_env(), timeout=600)

    def one_point(a: str) -> str:
        key, _, value = a.partition("=")
        return f"{key}={value.split(',')[0]}" if "," in value and value[:1] not in "[{(" and "(" not in value else a

    for args in runs:
        multirun = "-m" in args
        if "--config-dir" in args:  # what Hydra's --config-dir does: the folder joins the search path
            k = args.index("--config-dir")
            args = [*args[:k], *args[k + 2 :], f"hydra.searchpath=[file://{ROOT / args[k + 1]}]"]
        over = [one_point(a) if multirun else a for a in args if a != "-m" and "spring" not in a and "glob(" not in a]
        compose_cfg(over, hydra_cfg=True)


# ------------------------------------------------------------------------------------------ blocks that are data
def _subset(part, whole, where: str) -> None:
    if isinstance(part, dict):
        assert isinstance(whole, dict), where
        for k, v in part.items():
            assert k in whole, f"{where}.{k} is not in {PLUGIN_EXAMPLE / 'pyproject.toml'}"
            _subset(v, whole[k], f"{where}.{k}")
    else:
        assert part == whole, f"{where}: the page shows {part!r}, the plugin has {whole!r}"


def test_toml_blocks_are_the_example_plugins_settings():
    """The pyproject settings the plugin tutorial shows are those of the plugin that tests/test_plugins.py installs."""
    plugin = tomllib.loads((PLUGIN_EXAMPLE / "pyproject.toml").read_text())
    tomls = [b for b in BLOCKS if b.lang == "toml"]
    assert len(tomls) >= 2
    for b in tomls:
        _subset(tomllib.loads(b.text), plugin, b.where)


def test_yaml_blocks_are_conf_files_or_used_by_a_python_block_or_trees_that_build():
    confs = {p: p.read_text() for p in (ROOT / "conf").rglob("*.yaml")}
    for b in (b for b in BLOCKS if b.lang == "yaml"):
        files = [p for p, text in confs.items() if text == b.text]
        users = [p for p in PYTHON if b.text in p.text]
        if files or users:
            continue
        spec = yaml.safe_load(b.text)  # a tree shown as an example of the schema: it must build as shown
        assert isinstance(spec, dict) and "nodes" in spec, (
            f"{b.where}: a YAML block that is neither a file of conf/, nor used verbatim by a Python block (which "
            "runs it), nor a tree spec"
        )
        assert isinstance(build_tree(spec), RMPTree), b.where


def test_the_search_path_plugin_shown_is_the_example_plugins_file():
    path = PLUGIN_EXAMPLE / "hydra_plugins" / "rmpfusion_spring" / "searchpath.py"
    assert any(b.text == path.read_text() for b in PYTHON), f"the plugin tutorial shows a different {path.name}"
    assert not (
        PLUGIN_EXAMPLE / "hydra_plugins" / "__init__.py"
    ).exists()  # the namespace package the tutorial describes


def test_every_block_is_accounted_for():
    """Every block is run, checked, or named here as not a command; every exclusion still matches a page."""
    for b in BLOCKS:
        assert b.lang in ("python", "bash", "yaml", "toml", "text", "cpp", ""), f"{b.where}: unknown block {b.lang!r}"
        if b.lang in ("text", "cpp", "") and b.page not in FORMULA_PAGES:
            assert b.first in NOT_COMMANDS, (
                f"{b.where}: a {b.lang or 'plain'} block that is not "
                f"listed in NOT_COMMANDS; if it is a command, make it a bash block"
            )
    cmds = [c for b in BLOCKS if b.lang == "bash" for c in commands(b)]
    assert set(EXCLUDED) <= set(cmds), f"stale exclusions: {set(EXCLUDED) - set(cmds)}"
    assert set(FAILS) <= set(cmds)
    assert {b.first for b in BLOCKS if b.lang in ("text", "cpp", "") and b.page not in FORMULA_PAGES} == set(
        NOT_COMMANDS
    )
    run = {c for u in UNITS for c in u.cmds}
    assert set(cmds) == run | set(EXCLUDED)
    for c in run:
        appended(c, Path("/tmp/x"))  # every command that runs has a rule for its output directory
