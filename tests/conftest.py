"""Shared test helpers: float64 everywhere, finite differences, wandb never online, composed configs and the
example plugin installed."""

import functools
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from rmpfusion.pipeline.compose import compose_config

os.environ.setdefault("WANDB_MODE", "disabled")
os.environ.setdefault("MPLBACKEND", "Agg")

torch.set_default_dtype(torch.float64)
# small batched linear algebra is dominated by thread hand-off on a 2-core machine
torch.set_num_threads(1)


ROOT = Path(__file__).resolve().parents[1]
CONF = ROOT / "conf"
PLUGIN_EXAMPLE = ROOT / "tests" / "plugin_example"
#: The pages a user reads: README.md first, then every hand-written page of docs/ (the registry reference is
#: generated when the site is built, docs/_build is the built site). Their code blocks run and their results tables
#: are checked against results/ wherever a section lives.
DOC_PAGES = [
    ROOT / "README.md",
    *sorted(
        p
        for p in (ROOT / "docs").rglob("*.md")
        if not p.relative_to(ROOT / "docs").parts[0] in ("reference", "_build", "_ext")
    ),
]


def page_name(page: Path) -> str:
    """A page as messages name it: its path from the repository root."""
    return str(page.relative_to(ROOT))


def section_of(heading: str) -> tuple[Path, str]:
    """(page, text) of the section a heading line (e.g. ``# When things go wrong``) starts, on whichever page
    holds it: its text runs to the next heading of the same or a higher level (lines in code blocks are not
    headings)."""
    level = len(heading) - len(heading.lstrip("#"))
    for page in DOC_PAGES:
        lines = page.read_text(encoding="utf-8").splitlines(keepends=True)
        if heading + "\n" not in lines:
            continue
        start, fenced = lines.index(heading + "\n") + 1, False
        for end in range(start, len(lines)):
            fenced ^= lines[end].startswith("```")
            hashes = len(lines[end]) - len(lines[end].lstrip("#"))
            if not fenced and 0 < hashes <= level and lines[end][hashes : hashes + 1] == " ":
                return page, "".join(lines[start:end])
        return page, "".join(lines[start:])
    raise AssertionError(f"no page of the documentation has the heading {heading!r}")


#: the smallest run: tiny data and training, a fast evaluation, no wandb
TINY = ["data=tiny", "train=tiny", "eval=fast", "logger=disabled"]


def compose_cfg(overrides=(), hydra_cfg: bool = False):
    """conf/config.yaml composed with ``overrides`` as the entry points compose it (neither resolved nor validated);
    ``hydra_cfg`` includes the ``hydra`` node."""
    return compose_config(list(overrides), conf=CONF, hydra_config=hydra_cfg)


@pytest.fixture(scope="session")
def plugin_site(tmp_path_factory) -> Path:
    """``pip install tests/plugin_example`` into a private target (a copy of the source, so the repo and the shared
    virtualenv stay as they are); the commands that use the plugin get this directory on PYTHONPATH."""
    root = tmp_path_factory.mktemp("plugin")
    shutil.copytree(PLUGIN_EXAMPLE, root / "src")
    site = pip_install_into(root / "src", root / "site")
    assert (site / "hydra_plugins" / "rmpfusion_spring" / "searchpath.py").is_file()
    return site


def pip_install_into(src: Path, site: Path) -> Path:
    """``pip install src`` into the private folder ``site`` (no dependencies, no build isolation: nothing
    downloaded), for a test to put on PYTHONPATH; returns ``site``."""
    cmd = [sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--no-build-isolation", "--target", str(site)]
    subprocess.run([*cmd, str(src)], check=True, capture_output=True, timeout=300)
    return site


def fd_jacobian(fn, x: torch.Tensor, eps: float = 1e-6) -> torch.Tensor:
    """Central-difference per-sample Jacobian (B, n, m) of a batched fn: (B, m) -> (B, n)."""
    cols = []
    for k in range(x.shape[1]):
        e = torch.zeros_like(x)
        e[:, k] = eps
        cols.append((fn(x + e) - fn(x - e)) / (2 * eps))
    return torch.stack(cols, dim=-1)


def fd_directional(fn, x: torch.Tensor, v: torch.Tensor, eps: float = 1e-6) -> torch.Tensor:
    return (fn(x + eps * v) - fn(x - eps * v)) / (2 * eps)


@pytest.fixture
def gen():
    return torch.Generator().manual_seed(1234)


def rk4_rollout(tree, q, qd, aux, dt: float, steps: int):
    """Closed-loop RK4 of q̈ = tree(q, q̇, aux(t)), independent of the environments' integrators.

    ``aux`` is a mapping held fixed, or a function of time returning one (a moving goal), evaluated at each RK4
    stage's time. Returns the records at t = 0, dt, …, steps·dt: ``t``, ``q``, ``qd`` (steps + 1, B, d), ``V`` and
    ``dissipation`` q̇ᵀB_r q̇ (steps + 1, B).
    """
    aux_at = aux if callable(aux) else (lambda t: aux)
    acc = lambda t, q_, qd_: tree(q_, qd_, aux_at(t)).qdd
    rec = {"t": [], "q": [], "qd": [], "V": [], "dissipation": []}
    with torch.no_grad():
        for k in range(steps + 1):
            t = k * dt
            o = tree(q, qd, aux_at(t))
            for name, value in (
                ("t", torch.tensor(t)),
                ("q", q),
                ("qd", qd),
                ("V", o.V),
                ("dissipation", torch.einsum("bi,bij,bj->b", qd, o.B, qd)),
            ):
                rec[name].append(value)
            if k == steps:
                break
            k1v = o.qdd
            k2x, k2v = qd + 0.5 * dt * k1v, acc(t + 0.5 * dt, q + 0.5 * dt * qd, qd + 0.5 * dt * k1v)
            k3x, k3v = qd + 0.5 * dt * k2v, acc(t + 0.5 * dt, q + 0.5 * dt * k2x, qd + 0.5 * dt * k2v)
            k4x, k4v = qd + dt * k3v, acc(t + dt, q + dt * k3x, qd + dt * k3v)
            q = q + dt / 6 * (qd + 2 * k2x + 2 * k3x + k4x)
            qd = qd + dt / 6 * (k1v + 2 * k2v + 2 * k3v + k4v)
    return {k: torch.stack(v) for k, v in rec.items()}


def assert_lyapunov_non_increasing(rec, rtol: float = 1e-9):
    """Theorem 2 on a rollout's records: V_r never increases (beyond rtol of its scale, for the integration error)
    and does decrease."""
    V = rec["V"]
    dV = V[1:] - V[:-1]
    assert (dV <= rtol * (1 + V[:-1].abs())).all(), f"V_r increased by up to {float(dV.max()):.3e}"
    assert (V[-1] < V[0]).all()


def assert_energy_identity(tree, q, qd, aux, eps: float = 1e-6, rtol: float = 1e-5):
    """Theorem 2's identity dV_r/dt = −q̇ᵀB_r q̇ at the states (q, q̇), with aux held fixed: dV_r/dt by a central
    difference in time along (q̇, q̈), relative to the scale of V_r's rate."""
    with torch.no_grad():
        o = tree(q, qd, aux)
        rate = (tree(q + eps * qd, qd + eps * o.qdd, aux).V - tree(q - eps * qd, qd - eps * o.qdd, aux).V) / (2 * eps)
    expect = -torch.einsum("bi,bij,bj->b", qd, o.B, qd)
    torch.testing.assert_close(rate, expect, rtol=rtol, atol=rtol * float(expect.abs().max() + 1e-3))


@functools.cache
def mujoco_renders() -> str | None:
    """Why MuJoCo cannot render offscreen here (None when it can): it needs the mujoco package and an OpenGL
    platform, EGL by default (Debian's libegl1; .ci/run installs it), in a process of its own so that a missing
    library is a message, not a crash."""
    code = (
        "import rmpfusion.sims, mujoco\n"
        "m = mujoco.MjModel.from_xml_string('<mujoco><worldbody><geom size=\".1\"/></worldbody></mujoco>')\n"
        "mujoco.Renderer(m, 8, 8).render()\n"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    if r.returncode == 0:
        return None
    last = (r.stderr.strip().splitlines() or ["no message"])[-1]
    return f"MuJoCo cannot render offscreen on this machine (MUJOCO_GL=egl needs libegl1): {last}"


def needs_mujoco_rendering():
    """Skip, saying why, where MuJoCo cannot render offscreen."""
    reason = mujoco_renders()
    if reason is not None:
        pytest.skip(reason)
