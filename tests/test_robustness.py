"""Robustness: one table of bad inputs and faults, each with how it is triggered, what must happen,
and the message a user actually sees. Every row runs as a test; ``PYTHONPATH=. python tests/test_robustness.py`` runs them
all and prints the table as markdown (docs/troubleshooting.md, "When things go wrong", is that output).

Rows marked ``known gap`` are strict xfails: they document behaviour that is still wrong (and who can fix it);
they fail loudly once it is fixed, so the mark is removed with the fix.
"""

from __future__ import annotations

import math
import re
import sys
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import pytest
import torch
from conftest import section_of
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from torch import nn

import rmpfusion
from rmpfusion.core.algebra import NodeRMP, SingularInertiaWarning, resolve
from rmpfusion.core.gds import LeafRMP
from rmpfusion.core.taskmap import TaskMap
from rmpfusion.core.tree import NumericalError
from rmpfusion.envs.demonstrations import Dataset, DatasetError, load_dataset, save_dataset
from rmpfusion.evaluate.certificate import certify
from rmpfusion.learn.checkpoints import CheckpointError, latest_checkpoint, load_checkpoint
from rmpfusion.learn.train import train
from rmpfusion.registry import LEAF_RMPS, TASK_MAPS, Params

ROOT = Path(__file__).resolve().parent.parent
F64 = torch.float64


# ------------------------------------------------------------------------------------------------ the table
@dataclass(frozen=True)
class Row:
    id: str
    fault: str  # the bad input or fault
    trigger: str  # how the test provokes it
    expect: str  # what must happen
    shows: str  # the message a user sees, as a template (see ``shows_pattern``); the test full-matches it
    run: Callable  # run(tmp_path, monkeypatch) -> the message a user sees (asserting the expectation on the way)
    gap: str | None = None  # known gap: why it is still wrong and where the fix belongs (strict xfail)
    needs: tuple[str, ...] = field(default_factory=tuple)  # importable modules the row needs


ROWS: list[Row] = []


def row(
    id: str, fault: str, trigger: str, expect: str, *, shows: str, gap: str | None = None, needs: tuple[str, ...] = ()
):
    def deco(fn):
        ROWS.append(Row(id, fault, trigger, expect, shows, fn, gap, needs))
        return fn

    return deco


# A row's ``shows`` is the message verbatim (``<dir>`` is the run directory, as in the README), except for
# these placeholders for what legitimately varies: <num> a number as Python formats it (2.59, 1.1e+200, -3.5e-18,
# inf), <hex> a checksum prefix, <text> text that belongs to a library (torch's or pybullet's own error
# message), <a|b> one of the listed words. Everything else - what failed, which file/key/sample, what to do -
# must appear exactly.
_PLACEHOLDERS = {
    "<num>": r"[-+]?(?:\d+(?:\.\d*)?|\.\d+)(?:e[-+]?\d+)?|[-+]?inf|nan",
    "<hex>": r"[0-9a-f]+",
    "<text>": r".+?",
}


def shows_pattern(template: str) -> re.Pattern:
    """The regular expression a row's ``shows`` template stands for (matched against the whole message)."""
    out = []
    for part in re.split(r"(<num>|<hex>|<text>|<[^<>|]+(?:\|[^<>|]+)+>)", template):
        if part in _PLACEHOLDERS:
            out.append(f"(?:{_PLACEHOLDERS[part]})")
        elif part.startswith("<") and part.endswith(">") and "|" in part:
            out.append("(?:" + "|".join(re.escape(w) for w in part[1:-1].split("|")) + ")")
        else:
            out.append(re.escape(part))
    return re.compile("".join(out), re.DOTALL)


def check_shows(r: Row, msg: str) -> None:
    assert isinstance(msg, str), f"row {r.id} returned {msg!r}, not the message a user sees"
    assert shows_pattern(r.shows).fullmatch(msg), (
        f"row {r.id}: the user sees\n    {msg}\nbut the row promises\n    {r.shows}"
    )


def raised(exc_type, fn, *args, match: str | None = None, **kwargs) -> str:
    """Run ``fn`` expecting ``exc_type`` (message matching ``match``); return the message."""
    with pytest.raises(exc_type, match=match) as info:
        fn(*args, **kwargs)
    return str(info.value)


# ------------------------------------------------------------------------------------------------ test components
class _NanBeyond(LeafRMP):
    """A (deliberately broken) leaf: the GDS G = B = I, Φ = ½|y|², except that f is NaN wherever y[0] > limit."""

    class Params(Params):
        limit: float = 0.0

    def __init__(self, params, dim):
        super().__init__(dim)
        self.limit = params.limit

    def forward(self, y, yd):
        B, n = y.shape
        eye = torch.eye(n, dtype=y.dtype).expand(B, n, n)
        f = torch.where((y[:, :1] > self.limit), torch.full_like(y, float("nan")), -y - yd)
        K, Phi = 0.5 * (yd * yd).sum(-1), 0.5 * (y * y).sum(-1)
        return NodeRMP(f=f, M=eye, G=eye, B=eye, Phi=Phi, L=K - Phi, V=K + Phi)


class _Indefinite(LeafRMP):
    """A (deliberately broken) leaf whose inertia M = diag(1, −2, 1, ...) is indefinite."""

    class Params(Params):
        pass

    def __init__(self, params, dim):
        super().__init__(dim)

    def forward(self, y, yd):
        B, n = y.shape
        d = torch.ones(n, dtype=y.dtype)
        d[1 % n] = -2.0
        M = torch.diag(d).expand(B, n, n)
        K = 0.5 * (yd * yd).sum(-1)
        return NodeRMP(f=-y, M=M, G=M, B=torch.zeros_like(M), Phi=y.new_zeros(B), L=K, V=K)


class _NanMap(TaskMap):
    """A (deliberately broken) map: y = x, but NaN wherever x[0] > limit."""

    class Params(Params):
        limit: float = 0.0

    def __init__(self, params, in_dim, aux_dims=None):
        super().__init__(in_dim, aux_dims)
        self.limit, self.out_dim = params.limit, in_dim

    def forward(self, x, xd, aux=None):
        y = torch.where(x[:, :1] > self.limit, torch.full_like(x, float("nan")), x)
        J = torch.eye(self.in_dim, dtype=x.dtype).expand(x.shape[0], -1, -1)
        return y, xd, J, torch.zeros_like(x)


class _NegativeMetric(LeafRMP):
    """A (deliberately broken) plugin leaf whose metric is −I: an attractor that pushes away from its goal."""

    class Params(Params):
        pass

    def __init__(self, params, dim):
        super().__init__(dim)

    def forward(self, y, yd):
        B, n = y.shape
        G = -torch.eye(n, dtype=y.dtype).expand(B, n, n)
        K, Phi = -0.5 * (yd * yd).sum(-1), 0.5 * (y * y).sum(-1)
        return NodeRMP(
            f=-y - yd, M=G, G=G, B=torch.eye(n, dtype=y.dtype).expand(B, n, n), Phi=Phi, L=K - Phi, V=K + Phi
        )


class _WrongShape(LeafRMP):
    """A (deliberately broken) plugin leaf whose metric has one row and column too many."""

    class Params(Params):
        pass

    def __init__(self, params, dim):
        super().__init__(dim)

    def forward(self, y, yd):
        B, n = y.shape
        eye = torch.eye(n + 1, dtype=y.dtype).expand(B, n + 1, n + 1)
        K, Phi = 0.5 * (yd * yd).sum(-1), 0.5 * (y * y).sum(-1)
        return NodeRMP(f=-y - yd, M=eye, G=eye, B=eye, Phi=Phi, L=K - Phi, V=K + Phi)


_COMPONENTS = [
    (LEAF_RMPS, "test_nan_beyond", _NanBeyond),
    (LEAF_RMPS, "test_indefinite", _Indefinite),
    (TASK_MAPS, "test_nan_map", _NanMap),
    (LEAF_RMPS, "test_negative_metric", _NegativeMetric),
    (LEAF_RMPS, "test_wrong_shape", _WrongShape),
]


def register_components() -> None:
    for reg, name, obj in _COMPONENTS:
        reg.register(name)(obj)


def unregister_components() -> None:
    for reg, name, _ in _COMPONENTS:
        reg.unregister(name)


@pytest.fixture(scope="module", autouse=True)
def _components():
    register_components()
    yield
    unregister_components()


# ------------------------------------------------------------------------------------------------ a 2-D tree
AUX_DIMS = {"goal": 2, "obstacle_center": 2, "obstacle_radius": 1}


def tree_spec(**extra_nodes) -> dict:
    return {
        "root": {"name": "q", "dim": 2},
        "aux": AUX_DIMS,
        "nodes": {
            "goal": {
                "parent": "q",
                "map": {"type": "offset", "origin": "goal"},
                "weight": {"type": "mlp", "hidden": [8], "aux": ["goal", "obstacle_center"]},
                "rmp": {"type": "goal_attractor", "gain": 2.0},
            },
            "obstacle": {
                "parent": "q",
                "map": {"type": "sphere_distance", "center": "obstacle_center", "radius": "obstacle_radius"},
                "weight": {"type": "rbf", "low": 0.5, "high": 2.0, "center": "obstacle_center"},
                "rmp": {"type": "collision_avoidance", "alpha": 1e-2, "eta": 0.5},
            },
            "joint0_upper": {
                "parent": "q",
                "map": {"type": "joint_limit", "side": "upper", "limit": 4.0, "joints": 0},
                "rmp": {"type": "joint_limit"},
            },
            "joint0_lower": {
                "parent": "q",
                "map": {"type": "joint_limit", "side": "lower", "limit": -4.0, "joints": 0},
                "rmp": {"type": "joint_limit"},
            },
            "regulariser": {"parent": "q", "map": {"type": "identity"}, "rmp": {"type": "identity_metric"}},
            **extra_nodes,
        },
    }


def make_tree(dtype=F64, **extra_nodes):
    torch.manual_seed(0)
    return rmpfusion.build_tree(tree_spec(**extra_nodes), dtype=dtype)


def states(B: int = 4, seed: int = 0):
    """States outside the obstacle (centre (0, 0), radius 1) and inside the joint limits."""
    g = torch.Generator().manual_seed(seed)
    ang = 2 * math.pi * torch.rand(B, generator=g, dtype=F64)
    rad = 1.5 + 1.5 * torch.rand(B, generator=g, dtype=F64)
    q = torch.stack([rad * ang.cos(), rad * ang.sin()], -1)
    qd = torch.randn(B, 2, generator=g, dtype=F64)
    aux = {
        "goal": torch.tensor([[3.0, 0.5]], dtype=F64).expand(B, 2).clone(),
        "obstacle_center": torch.zeros(B, 2, dtype=F64),
        "obstacle_radius": torch.ones(B, 1, dtype=F64),
    }
    return q, qd, aux


def poke(t: torch.Tensor, value: float, sample: int = 1) -> torch.Tensor:
    t = t.clone()
    t[sample, 0] = value
    return t


# ------------------------------------------------------------------------------------------------ rows: tree inputs
def _bad_input(which: str, value: float):
    def run(tmp_path, monkeypatch):
        tree = make_tree()
        q, qd, aux = states()
        if which == "q":
            q = poke(q, value)
        elif which == "qd":
            qd = poke(qd, value)
        else:
            aux = {**aux, which: poke(aux[which], value)}
        label = which if which in ("q", "qd") else f"aux['{which}']"
        return raised(NumericalError, tree, q, qd, aux, match=rf"non-finite input {re.escape(label)} in sample 1;")

    return run


for _which, _value in [
    ("q", float("nan")),
    ("qd", float("inf")),
    ("goal", float("nan")),
    ("obstacle_center", float("-inf")),
    ("obstacle_radius", float("nan")),
]:
    _label = _which if _which in ("q", "qd") else f"aux['{_which}']"
    _shown = {"nan": "NaN", "inf": "+inf", "-inf": "-inf"}[str(_value)]
    row(
        f"input-{_which}",
        f"{_shown} in {_label}",
        f"tree(q, qd, aux) with sample 1's {_label} set to {_shown}",
        "NumericalError naming the input and the sample",
        shows=f"non-finite input {_label} in sample 1; check the state or aux state passed to the tree "
        "(a NaN here must not become a command)",
    )(_bad_input(_which, _value))


@row(
    "weight-nan",
    "a weight function producing NaN",
    "NaN in the first layer of node 'goal''s mlp weight",
    "NumericalError naming the node and the weight",
    shows="non-finite weight at node 'goal' (weight mlp) in samples 0, 1, 2, 3; inputs were finite "
    "(max |q| = <num>, max |qd| = <num>)",
)
def _weight_nan(tmp_path, monkeypatch):
    tree = make_tree()
    with torch.no_grad():
        tree.weights["goal"].fn.layers[0].weight[0, 0] = float("nan")
    q, qd, aux = states()
    return raised(NumericalError, tree, q, qd, aux, match=r"non-finite weight at node 'goal' \(weight mlp\)")


@row(
    "map-nan",
    "a task map producing NaN",
    "custom map that returns NaN where x₀ > 3.2, sample 1 at x₀ = 3.5",
    "NumericalError naming the node and the map",
    shows="non-finite y at node 'bad' (map test_nan_map) in sample 1; inputs were finite "
    "(max |q| = 3.5, max |qd| = <num>)",
)
def _map_nan(tmp_path, monkeypatch):
    tree = make_tree(
        bad={"parent": "q", "map": {"type": "test_nan_map", "limit": 3.2}, "rmp": {"type": "goal_attractor"}}
    )
    q, qd, aux = states()
    q = poke(q, 3.5)
    aux["obstacle_center"][1] = torch.tensor([-3.0, -3.0])  # keep sample 1 out of the obstacle
    err = pytest.raises(NumericalError, tree, q, qd, aux).value
    assert err.samples == [1] and err.where == "y at node 'bad'"
    assert re.search(r"non-finite y at node 'bad' \(map test_nan_map\) in sample 1", str(err))
    return str(err)


@row(
    "leaf-nan",
    "a leaf RMP producing NaN",
    "custom leaf whose f is NaN where y₀ > 3.2, sample 1 at y₀ = 3.5",
    "NumericalError naming the node and the leaf",
    shows="non-finite f in the RMP of node 'bad' (leaf test_nan_beyond) in sample 1; inputs were finite "
    "(max |q| = 3.5, max |qd| = <num>)",
)
def _leaf_nan(tmp_path, monkeypatch):
    tree = make_tree(bad={"parent": "q", "map": {"type": "identity"}, "rmp": {"type": "test_nan_beyond", "limit": 3.2}})
    q, qd, aux = states()
    q = poke(q, 3.5)
    return raised(
        NumericalError,
        tree,
        q,
        qd,
        aux,
        match=r"non-finite f in the RMP of node 'bad' \(leaf test_nan_beyond\) in sample 1",
    )


@row(
    "map-singular-point",
    "a state at a distance map's singular point",
    "q exactly at the obstacle's centre (|q − c| = 0, the gradient is undefined)",
    "NumericalError naming the node and the map",
    shows="non-finite <ydot|J> at node 'obstacle' (map sphere_distance) in sample 1; inputs were finite "
    "(max |q| = <num>, max |qd| = <num>)",
)
def _centre(tmp_path, monkeypatch):
    tree = make_tree()
    q, qd, aux = states()
    q[1] = aux["obstacle_center"][1]
    return raised(
        NumericalError,
        tree,
        q,
        qd,
        aux,
        match=r"non-finite (ydot|J) at node 'obstacle' \(map sphere_distance\) in sample 1;",
    )


# ------------------------------------------------------------------------------------------------ rows: root inertia
SINGLE_JOINT = {
    "root": {"name": "q", "dim": 2},
    "nodes": {"j0": {"parent": "q", "map": {"type": "select", "indices": [0]}, "rmp": {"type": "goal_attractor"}}},
}
DISTANCE_ONLY = {
    "root": {"name": "q", "dim": 2},
    "nodes": {
        "o": {
            "parent": "q",
            "map": {"type": "sphere_distance", "center": [0, 0], "radius": 1.0},
            "rmp": {"type": "collision_avoidance", "alpha": 0.1},
        }
    },
}
SINGULAR_STATES = (
    torch.tensor([[1.5, 0.3], [0.7, 1.2], [1.2, -0.4]], dtype=F64),
    torch.tensor([[-1.0, 0.2], [0.1, -0.3], [-1.0, 0.5]], dtype=F64),
)


@row(
    "inertia-singular",
    "singular root inertia M_r",
    "the only leaf sits on joint 0 of a 2-D root (M_r = diag(m, 0))",
    "q̈ = M⁺f (Moore–Penrose), SingularInertiaWarning, counted in tree.resolve_events",
    shows="resolve: the root inertia M is singular in 3 of 3 samples (samples [0, 1, 2]); used the Moore–Penrose "
    "pseudo-inverse there (q̈ = M⁺f has no component along M's null space). Add an identity_metric leaf "
    "on the root to keep M invertible.",
)
def _singular(tmp_path, monkeypatch):
    tree = rmpfusion.build_tree(SINGLE_JOINT)
    q, qd = SINGULAR_STATES
    other = rmpfusion.build_tree(SINGLE_JOINT)
    with pytest.warns(SingularInertiaWarning, match=r"singular in 3 of 3 samples") as rec:
        out = tree(q, qd)
    assert tree.resolve_events == {"pinv_fallback": 3, "unsolvable": 0}
    assert not other.resolve_events  # counts belong to the tree that met the state, not to the process
    torch.testing.assert_close(out.qdd, resolve(out.f, out.M, "pinv"), rtol=1e-12, atol=1e-12)
    assert out.qdd.isfinite().all() and (out.qdd[:, 1] == 0).all()
    events: dict = {}
    with pytest.warns(SingularInertiaWarning):
        resolve(out.f, out.M, events=events)  # a caller can count per object too
    assert events == {"pinv_fallback": 3, "unsolvable": 0}
    return str(rec[0].message)


@row(
    "inertia-numerically-singular",
    "numerically singular M_r (rank-deficient up to rounding)",
    "the only leaf is on a 1-D distance map of a 2-D root: LU finds a ~1e-17 pivot instead of 0",
    "q̈ = M⁺f like the exactly singular case: a negligible LU pivot counts as singular, so resolve falls back",
    shows="resolve: the root inertia M is singular in 3 of 3 samples (samples [0, 1, 2]); used the Moore–Penrose "
    "pseudo-inverse there (q̈ = M⁺f has no component along M's null space). Add an identity_metric leaf "
    "on the root to keep M invertible.",
)
def _numerically_singular(tmp_path, monkeypatch):
    tree = rmpfusion.build_tree(DISTANCE_ONLY)
    q, qd = SINGULAR_STATES
    with pytest.warns(SingularInertiaWarning) as rec:
        out = tree(q, qd)
    torch.testing.assert_close(out.qdd, resolve(out.f, out.M, "pinv"), rtol=1e-6, atol=1e-6)
    return str(rec[0].message)


@row(
    "certificate-singular",
    "numerically singular M_r, checked with the certificate",
    "certify(tree, q, qd) on the distance-only tree above",
    "the certificate fails M_r ≻ 0 and lists the states",
    shows="[FAIL] M_r positive definite    (min eig = <num>)",
)
def _certificate_singular(tmp_path, monkeypatch):
    tree = rmpfusion.build_tree(DISTANCE_ONLY)
    cert = certify(tree, *SINGULAR_STATES)
    assert not cert.ok and not cert.inertia_positive_definite and cert.failing_states == [0, 1, 2]
    return next(ln.strip() for ln in cert.summary().splitlines() if "positive definite" in ln)


@row(
    "inertia-indefinite",
    "indefinite root inertia M_r",
    "a custom leaf with M = diag(1, −2) on the root, built with check_leaves=False (the build refuses it otherwise)",
    "resolve stays defined; certify reports M_r not positive definite (min eig < 0)",
    shows="[FAIL] M_r positive definite    (min eig = -2.000e+00)",
)
def _indefinite(tmp_path, monkeypatch):
    spec = {
        "root": {"name": "q", "dim": 2},
        "nodes": {"bad": {"parent": "q", "map": {"type": "identity"}, "rmp": {"type": "test_indefinite"}}},
    }
    tree = rmpfusion.build_tree(spec, check_leaves=False)
    q, qd = SINGULAR_STATES
    out = tree(q, qd)
    assert out.qdd.isfinite().all()
    cert = certify(tree, q, qd)
    assert not cert.ok and not cert.inertia_positive_definite and cert.min_inertia_eigenvalue == pytest.approx(-2.0)
    return next(ln.strip() for ln in cert.summary().splitlines() if "positive definite" in ln)


# ------------------------------------------------------------------------------------------------ rows: barriers
@row(
    "inside-obstacle",
    "a state inside an obstacle",
    "q at depths 0.01R … 0.999R inside the sphere, moving inwards",
    "finite q̈ that points outward",
    shows="finite q̈ with outward component q̈·n = <num>, <num>, <num>, <num> (moving inwards at 1 m/s)",
)
def _inside(tmp_path, monkeypatch):
    spec = {
        "root": {"name": "q", "dim": 2},
        "nodes": {k: v for k, v in tree_spec()["nodes"].items() if k in ("obstacle", "regulariser")},
        "aux": AUX_DIMS,
    }
    tree = rmpfusion.build_tree(spec)
    depth = torch.tensor([0.01, 0.3, 0.9, 0.999], dtype=F64)  # fraction of the radius below the surface
    n = torch.nn.functional.normalize(
        torch.tensor([[1.0, 0.4], [-0.3, 1.0], [-1.0, -0.2], [0.5, -1.0]], dtype=F64), dim=-1
    )
    q = (1 - depth)[:, None] * n
    aux = {
        "obstacle_center": torch.zeros(4, 2, dtype=F64),
        "obstacle_radius": torch.ones(4, 1, dtype=F64),
        "goal": torch.zeros(4, 2, dtype=F64),
    }
    outward = []
    for speed in (0.0, 1.0):
        out = tree(q, -speed * n, aux)
        assert out.qdd.isfinite().all() and out.V.isfinite().all()
        push = (out.qdd * n).sum(-1)
        assert (push > 0).all(), push
        outward.append(push)
    return f"finite q̈ with outward component q̈·n = {', '.join(f'{v:.3g}' for v in outward[1].tolist())} (moving inwards at 1 m/s)"


@row(
    "beyond-joint-limit",
    "a state beyond a joint limit",
    "q₀ = 4.5 and −4.7 with limits ±4, moving further out",
    "finite q̈ that points back inside",
    shows="finite q̈₀ = <num> (above the upper limit), <num> (below the lower limit)",
)
def _beyond(tmp_path, monkeypatch):
    tree = make_tree()
    q = torch.tensor([[4.5, 0.0], [-4.7, 0.3]], dtype=F64)
    qd = torch.tensor([[0.5, 0.0], [-0.5, 0.0]], dtype=F64)
    aux = {
        "goal": q.clone(),
        "obstacle_center": torch.full((2, 2), 10.0, dtype=F64),
        "obstacle_radius": torch.ones(2, 1, dtype=F64),
    }
    out = tree(q, qd, aux)
    assert out.qdd.isfinite().all()
    assert out.qdd[0, 0] < 0 < out.qdd[1, 0]
    return f"finite q̈₀ = {out.qdd[0, 0]:.3g} (above the upper limit), {out.qdd[1, 0]:.3g} (below the lower limit)"


@row(
    "extreme-velocity",
    "extreme velocities",
    "|q̇| scaled to 1e3 and 1e6",
    "finite q̈ (float64)",
    shows="finite: max |q̈| = <num> at |q̇| = 1e3, <num> at |q̇| = 1e6",
)
def _extreme(tmp_path, monkeypatch):
    tree = make_tree()
    q, qd, aux = states()
    largest = []
    for s in (1e3, 1e6):
        out = tree(q, qd * s / qd.norm(dim=-1, keepdim=True), aux)
        assert out.qdd.isfinite().all() and out.M.isfinite().all()
        largest.append(float(out.qdd.detach().abs().max()))
    return f"finite: max |q̈| = {largest[0]:.2e} at |q̇| = 1e3, {largest[1]:.2e} at |q̇| = 1e6"


@row(
    "overflow-velocity",
    "velocities that overflow float64",
    "|q̇| = 1e200",
    "NumericalError naming the node where it overflowed and the input sizes, never a silent NaN",
    shows="non-finite Jdot_xdot at node 'obstacle' (map sphere_distance) in samples 0, 1, 2, 3; inputs were finite "
    "(max |q| = <num>, max |qd| = <num>e+200)",
)
def _overflow(tmp_path, monkeypatch):
    tree = make_tree()
    q, qd, aux = states()
    return raised(NumericalError, tree, q, qd * 1e200, aux, match=r"at node '\w+'.*max \|qd\| = ")


@row(
    "float32",
    "float32 instead of float64",
    "the same tree and weights in float32 vs float64, 64 ordinary states",
    "q̈ agrees to 1e-4 relative (to max|q̈| + 1)",
    shows="max relative difference <num> (tolerance 1e-4)",
)
def _float32(tmp_path, monkeypatch):
    t64 = make_tree()
    t32 = make_tree(dtype=torch.float32)
    t32.load_state_dict({k: v.float() for k, v in t64.state_dict().items()})
    q, qd, aux = states(64, seed=3)
    with torch.no_grad():
        a64 = t64(q, qd, aux).qdd
        a32 = t32(q.float(), qd.float(), {k: v.float() for k, v in aux.items()}).qdd
    rel = float(((a32.double() - a64).abs() / (a64.abs().amax(-1, keepdim=True) + 1)).max())
    assert rel < 1e-4
    return f"max relative difference {rel:.1e} (tolerance 1e-4)"


@row(
    "mixed-dtype",
    "a float32 state passed to a float64 tree",
    "tree(q.float(), qd.float(), aux) on a float64 tree",
    "a clear error naming the dtypes",
    shows="q and qd are torch.float32 and torch.float32 but the tree computes in torch.float64; convert the state "
    "(q.to(torch.float64)) or the tree (tree.to(torch.float32))",
)
def _mixed(tmp_path, monkeypatch):
    tree = make_tree()
    q, qd, aux = states()
    return raised((TypeError, ValueError), tree, q.float(), qd.float(), aux, match="float32|dtype")


# ------------------------------------------------------------------------------------------------ rows: files
def tiny_dataset(n: int = 40) -> Dataset:
    g = torch.Generator().manual_seed(0)
    r = lambda *s: torch.randn(*s, generator=g, dtype=F64)
    return Dataset(
        q=r(n, 2),
        qd=r(n, 2),
        aux={"goal": r(n, 2)},
        qdd=r(n, 2),
        env_id=torch.zeros(n, dtype=torch.long),
        traj_id=torch.arange(n) // 10,
        t=(torch.arange(n) % 10) * 0.1,
        collided=torch.zeros(n // 10, dtype=torch.bool),
        success=torch.ones(n // 10, dtype=torch.bool),
    )


META = {"seed": 0, "config_hash": "0123abcd", "split": "train"}


def flip_byte_in(path: Path, needle: bytes) -> None:
    raw = bytearray(path.read_bytes())
    i = raw.find(needle)
    assert i >= 0
    raw[i + len(needle) // 2] ^= 0x01
    path.write_bytes(bytes(raw))


def _dataset_row(case: str):
    def run(tmp_path, monkeypatch):
        p = tmp_path / "train-0123abcd.pt"
        ds = tiny_dataset()
        save_dataset(p, ds, META)
        meta = META
        if case == "missing":
            p = tmp_path / "nope.pt"
            pat = r"dataset file .*nope\.pt does not exist; run the experiment"
        elif case == "truncated":
            p.write_bytes(p.read_bytes()[:700])
            pat = r"dataset file .* is unreadable or truncated \(RuntimeError: PytorchStreamReader .*\); delete .* to have it collected again"
        elif case == "flipped":
            flip_byte_in(p, ds.qdd.numpy().tobytes())  # one bit of one label
            pat = r"dataset file .* fails its checksum .* it was modified or damaged; delete .* to have it collected again"
        elif case == "flipped-header":
            flip_byte_in(p, b"_rebuild_tensor_v2")  # one bit of the pickled structure
            pat = (
                r"dataset file .* is damaged or was not written by rmpfusion: it asks for the Python object \S+, which "
                r"no file of rmpfusion holds \(nothing in it was loaded or run\); delete"
            )
        else:  # foreign
            meta = {**META, "config_hash": "99999999"}
            pat = r"dataset file .* was made with a different configuration \(config_hash: file '0123abcd' vs expected '99999999'\)"
        msg = raised(DatasetError, load_dataset, p, meta, match=pat)
        assert "\n" not in msg and "weights_only" not in msg  # one line, and never torch's unsafe advice
        return msg

    return run


_DS, _AGAIN = "dataset file <dir>/train-0123abcd.pt", "delete <dir>/train-0123abcd.pt to have it collected again"
for _case, _fault, _trigger, _shows in [
    (
        "missing",
        "dataset file missing",
        "load_dataset on a path that does not exist",
        (
            "dataset file <dir>/nope.pt does not exist; run the experiment (it collects the data) or point data.cache_dir "
            "at the directory that holds it"
        ),
    ),
    (
        "truncated",
        "dataset file truncated",
        "the file cut after 700 bytes",
        f"{_DS} is unreadable or truncated (RuntimeError: PytorchStreamReader <text>); {_AGAIN}",
    ),
    (
        "flipped",
        "dataset tampered (one bit of the data)",
        "one bit flipped inside the stored labels",
        f"{_DS} fails its checksum (stored <hex>…, content <hex>…): it was modified or damaged; {_AGAIN}",
    ),
    (
        "flipped-header",
        "dataset damaged (one bit of the structure)",
        "one bit flipped in the pickled header",
        (
            f"{_DS} is damaged or was not written by rmpfusion: it asks for the Python object <text>, which no file of "
            f"rmpfusion holds (nothing in it was loaded or run); {_AGAIN}"
        ),
    ),
    (
        "foreign",
        "dataset made with a different config",
        "a file whose stored config hash differs from the run's",
        f"{_DS} was made with a different configuration (config_hash: file '0123abcd' vs expected '99999999'); {_AGAIN}",
    ),
]:
    row(f"dataset-{_case}", _fault, _trigger, "DatasetError naming the file and what to do", shows=_shows)(
        _dataset_row(_case)
    )


@row(
    "collect-expert-fails",
    "the expert fails on one trajectory while collecting data",
    "collect() on particle2d, 2 trajectories, the expert returns NaN for trajectory 1",
    "trajectory 1 is left out of the dataset with a RuntimeWarning saying why; no NaN reaches the data",
    shows="expert failed on 1 of 2 trajectories, left out of the dataset (trajectory 1: non-finite record)",
)
def _collect(tmp_path, monkeypatch):
    from rmpfusion.envs.demonstrations import collect
    from rmpfusion.envs.particle2d import Particle2D

    env = Particle2D()

    def expert(q, qd, a):
        out = (a["goal"] - q) - 2.0 * qd
        out[1] = float("nan")
        return out

    with pytest.warns(
        RuntimeWarning,
        match=r"expert failed on 1 of 2 trajectories, left out of the dataset "
        r"\(trajectory 1: non-finite record\)",
    ) as rec:
        ds = collect(env, expert, 1, 2, 5, 0.1, torch.Generator().manual_seed(0))
    assert len(ds) == 5 and ds.traj_id.unique().tolist() == [0] and ds.qdd.isfinite().all()
    assert ds.success.shape == ds.collided.shape == (1,)
    return str(rec[0].message)


@row(
    "dataset-non-finite",
    "a dataset with a NaN label about to be saved",
    "save_dataset on data whose qdd has a NaN in row 13",
    "DatasetError before anything is written: NaN never becomes training data",
    shows="refusing to write dataset <dir>/d.pt: qdd is non-finite in 1 rows (first rows [13], trajectories [1]); "
    "the expert failed there: drop those records (or fix the expert) before saving",
)
def _save_nan(tmp_path, monkeypatch):
    ds = tiny_dataset()
    ds.qdd[13, 1] = float("nan")
    msg = raised(
        DatasetError,
        save_dataset,
        tmp_path / "d.pt",
        ds,
        META,
        match=r"refusing to write dataset .*d\.pt: qdd is non-finite in 1 rows \(first rows \[13\], trajectories \[1\]\)",
    )
    assert not (tmp_path / "d.pt").exists()
    return msg


class TinyLearner(nn.Module):
    def __init__(self, hidden: int = 4):
        super().__init__()
        self.net = nn.Sequential(nn.Linear(4, hidden), nn.Tanh(), nn.Linear(hidden, 2)).to(F64)

    def forward(self, q, qd, aux):
        return self.net(torch.cat([q, qd], -1))


def _train(ckdir: Path, hidden: int = 4, lr: float = 1e-3, iterations: int = 4):
    from rmpfusion.learn.config import TrainConfig

    cfg = TrainConfig(
        iterations=iterations, batch_size=8, checkpoint_every=2, snapshots=[0, iterations], log_every=2, lr=lr
    )
    torch.manual_seed(0)
    return train(TinyLearner(hidden), tiny_dataset(), cfg, seed=0, checkpoint_dir=ckdir)


def _checkpoint_row(case: str):
    def run(tmp_path, monkeypatch):
        ck = tmp_path / "checkpoints" / "learner-rmp"
        _train(ck)
        path = latest_checkpoint(ck)
        assert load_checkpoint(path)["iteration"] == 4  # a sound checkpoint loads
        hidden, lr, exc = 4, 1e-3, CheckpointError
        if case == "missing":
            return raised(
                CheckpointError,
                load_checkpoint,
                ck / "ckpt-00000099.pt",
                match=r"checkpoint file .*ckpt-00000099\.pt does not exist; run rmpfusion-train first",
            )
        if case == "truncated":
            path.write_bytes(path.read_bytes()[:900])
            pat = r"checkpoint file .*ckpt-00000004\.pt is unreadable or truncated \(.*\); delete .*resumes from the previous"
        elif case == "flipped":
            flip_byte_in(path, torch.load(path, weights_only=True)["model"]["net.0.weight"].numpy().tobytes())
            pat = r"checkpoint file .*ckpt-00000004\.pt fails its checksum .* it was modified or damaged; delete"
        elif case == "other-model":
            hidden = 8
            pat = (
                r"checkpoint file .* holds the weights of a different model \(net\.0\.bias: file \(4,\) vs model \(8,\)"
            )
        else:  # other training settings
            lr, exc = 1e-2, RuntimeError
            pat = r"checkpoint .* was made with different training settings \(lr: 0\.001 vs 0\.01\); delete .* to start over"
        msg = raised(exc, _train, ck, hidden=hidden, lr=lr, iterations=6, match=pat)  # the user's path: resuming
        assert "\n" not in msg and "weights_only" not in msg
        return msg

    return run


_CK = "<dir>/checkpoints/learner-rmp/ckpt-00000004.pt"
_RESUME = (
    f"delete {_CK} (training then resumes from the previous checkpoint in <dir>/checkpoints/learner-rmp if there "
    "is one, else starts over)"
)
for _case, _fault, _trigger, _shows in [
    (
        "missing",
        "checkpoint file missing",
        "load_checkpoint on a path that does not exist",
        (
            "checkpoint file <dir>/checkpoints/learner-rmp/ckpt-00000099.pt does not exist; run rmpfusion-train first "
            "(it writes checkpoints/<learner>/ in the run directory)"
        ),
    ),
    (
        "truncated",
        "checkpoint truncated",
        "the latest checkpoint cut after 900 bytes, then training resumed",
        f"checkpoint file {_CK} is unreadable or truncated (RuntimeError: PytorchStreamReader <text>); {_RESUME}",
    ),
    (
        "flipped",
        "checkpoint tampered (one bit of a weight)",
        "one bit flipped in a stored weight, then training resumed",
        f"checkpoint file {_CK} fails its checksum (stored <hex>…, content <hex>…): it was modified or damaged; {_RESUME}",
    ),
    (
        "other-model",
        "checkpoint of a different model",
        "resume with a learner of another width",
        (
            f"checkpoint file {_CK} holds the weights of a different model (net.0.bias: file (4,) vs model (8,), "
            "net.0.weight: file (4, 4) vs model (8, 4), net.2.weight: file (2, 4) vs model (2, 8)); it was made by another "
            f"configuration of this learner: use the run directory that made it, or {_RESUME}"
        ),
    ),
    (
        "other-settings",
        "checkpoint made with different training settings",
        "resume with another learning rate",
        (
            f"checkpoint {_CK} was made with different training settings (lr: 0.001 vs 0.01); "
            "delete <dir>/checkpoints/learner-rmp to start over"
        ),
    ),
]:
    row(f"checkpoint-{_case}", _fault, _trigger, "an error naming the file and what to do", shows=_shows)(
        _checkpoint_row(_case)
    )


# ------------------------------------------------------------------------------------------------ rows: environment
NOMINAL = [0.6, -0.3, 0.0, -2.2, 0.0, 2.0, 0.785]
TRAP_TREE = {
    "root": {"name": "q", "dim": 7},
    "nodes": {
        "regulariser": {"parent": "q", "map": {"type": "identity"}, "rmp": {"type": "identity_metric", "scale": 1.0}},
        "damper": {"parent": "q", "map": {"type": "identity"}, "rmp": {"type": "damper", "w": 1.0, "eta": 2.0}},
        "trap": {
            "parent": "q",
            "map": {"type": "select", "indices": [0]},
            "rmp": {"type": "test_nan_beyond", "limit": 0.7},
        },
    },
}


def franka_setup(B: int = 2):
    from manipulators import franka_env, make_aux

    env = franka_env(control_rate=60.0)
    q0 = torch.tensor([NOMINAL] * B, dtype=F64)
    qd0 = torch.zeros(B, 7, dtype=F64)
    one = make_aux([0.4, -0.3, 0.35], [(-0.8, -0.8, 0.25)], [0.05])  # the cylinder out of the way
    aux = {k: v.expand(B, -1).contiguous() for k, v in one.items()}
    return env, q0, qd0, aux


def damping(q, qd, aux):
    return -2.0 * qd


def check_isolated(r, pattern: str) -> str:
    assert r.error[0] is None, r.error
    assert r.error[1] is not None and re.search(pattern, r.error[1]), r.error[1]
    assert r.q[:, 0].isfinite().all() and r.q[-1, 1].isnan().all()  # sample 0 ran to the end, sample 1 stopped
    return f"error[1] = {r.error[1]!r}; sample 0 completes (error[0] = None)"


def _recording_scenes(monkeypatch) -> list:
    from rmpfusion.envs.manipulator import torque as fr

    scenes = []

    class Recording(fr.TaskWorld):
        def __init__(self, *a, **kw):
            super().__init__(*a, **kw)
            scenes.append(self)

    monkeypatch.setattr(fr, "TaskWorld", Recording)
    return scenes


@row(
    "pybullet-disconnect",
    "pybullet connection lost mid-rollout",
    "torque mode, B = 2: the policy disconnects sample 1's pybullet client at its 3rd call",
    "sample 1 ends with a recorded reason, sample 0 completes",
    needs=("pybullet",),
    shows="error[1] = 'simulator error at t=0.0333s: pybullet: Not connected to physics server.'; sample 0 completes (error[0] = None)",
)
def _disconnect(tmp_path, monkeypatch):
    import pybullet

    env, q0, qd0, aux = franka_setup()
    scenes = _recording_scenes(monkeypatch)
    calls = []

    def policy(q, qd, a):
        calls.append(1)
        if len(calls) == 3:
            pybullet.disconnect(physicsClientId=scenes[1].sim.cid)
        return damping(q, qd, a)

    with torch.no_grad():
        r = env.rollout(policy, q0, qd0, aux, horizon=0.2, record_every=0.05, mode="torque")
    env.close()
    return check_isolated(r, r"simulator error at t=0\.0333s: pybullet: .*[Nn]ot connected")


@row(
    "pybullet-step-fails",
    "a simulator step raising",
    "torque mode, B = 2: stepSimulation raises for sample 1 at t = 0.05 s",
    "sample 1 ends with a recorded reason, sample 0 completes",
    needs=("pybullet",),
    shows="error[1] = 'simulator error at t=0.0500s: pybullet: simulated step failure'; sample 0 completes (error[0] = None)",
)
def _step_fails(tmp_path, monkeypatch):
    import pybullet

    env, q0, qd0, aux = franka_setup()
    scenes = _recording_scenes(monkeypatch)
    real, steps = pybullet.stepSimulation, []

    def step(*a, **kw):
        if kw.get("physicsClientId") == scenes[1].sim.cid:
            steps.append(1)
            if len(steps) == 4:
                raise pybullet.error("simulated step failure")
        return real(*a, **kw)

    monkeypatch.setattr(pybullet, "stepSimulation", step)
    with torch.no_grad():
        r = env.rollout(damping, q0, qd0, aux, horizon=0.2, record_every=0.05, mode="torque")
    env.close()
    return check_isolated(r, r"simulator error at t=0\.0500s: pybullet: simulated step failure")


def _tree_fault_row(mode: str):
    def run(tmp_path, monkeypatch):
        env, q0, qd0, aux = franka_setup()
        qd0[1, 0] = 3.0  # sample 1 drives joint 0 across the trap leaf's limit; sample 0 stays at rest
        tree = rmpfusion.build_tree(TRAP_TREE)
        with torch.no_grad():
            r = env.rollout(tree, q0, qd0, aux, horizon=0.2, record_every=0.05, mode=mode)
        env.close()
        what = "non-finite state" if mode == "kinematic" else "non-finite acceleration"
        return check_isolated(
            r,
            rf"{what} at t=\S+s: policy raised NumericalError: non-finite f in the RMP of node "
            r"'trap' \(leaf test_nan_beyond\) in sample 1",
        )

    return run


_TRAP_SHOWS = (
    'error[1] = "non-finite {what} at t=<num>s: policy raised NumericalError: non-finite f in the RMP of node '
    "'trap' (leaf test_nan_beyond) in sample 1; inputs were finite (max |q| = <num>, max |qd| = <num>)\"; "
    "sample 0 completes (error[0] = None)"
)
row(
    "rollout-tree-fault-kinematic",
    "the tree raises NumericalError for one sample of a kinematic rollout",
    "kinematic mode, B = 2: sample 1 moves joint 0 into a leaf that returns NaN",
    "sample 1 ends with the tree's diagnosis as reason, sample 0 completes",
    needs=("pybullet",),
    shows=_TRAP_SHOWS.format(what="state"),
)(_tree_fault_row("kinematic"))
row(
    "rollout-tree-fault-torque",
    "the tree raises NumericalError for one sample of a torque rollout",
    "torque mode, same tree and states",
    "sample 1 ends with the tree's diagnosis as reason, sample 0 completes",
    needs=("pybullet",),
    shows=_TRAP_SHOWS.format(what="acceleration"),
)(_tree_fault_row("torque"))


@row(
    "rollout-nonfinite-state",
    "a kinematic rollout producing a non-finite state",
    "kinematic mode, B = 2: a plain policy returns NaN for sample 1",
    "sample 1 ends with a recorded reason, sample 0 completes",
    needs=("pybullet",),
    shows="error[1] = 'non-finite state at t=0.0167s'; sample 0 completes (error[0] = None)",
)
def _nonfinite_state(tmp_path, monkeypatch):
    env, q0, qd0, aux = franka_setup()

    def policy(q, qd, a):
        out = damping(q, qd, a)
        out[1] = float("nan")
        return out

    with torch.no_grad():
        r = env.rollout(policy, q0, qd0, aux, horizon=0.2, record_every=0.05, mode="kinematic")
    env.close()
    return check_isolated(r, r"^non-finite state at t=0\.0167s$")


@row(
    "metrics-with-failure",
    "evaluation metrics over a batch with a failed sample",
    "online_loss + rollout_rates of the trap tree (sample 1 fails) against a sound expert, kinematic mode",
    "finite online loss over the records before the failure, failed = 0.5, no success for the failed sample",
    needs=("pybullet",),
    shows="online_loss = <num>, success = 0.0, failed = 0.5, lyapunov_monotone_fraction = 1.0",
)
def _metrics(tmp_path, monkeypatch):
    from rmpfusion.evaluate.metrics import online_loss, rollout_rates

    env, q0, qd0, aux = franka_setup()
    qd0[1, 0] = 3.0
    learner = rmpfusion.build_tree(TRAP_TREE)
    expert = rmpfusion.build_tree({**TRAP_TREE, "nodes": {k: v for k, v in TRAP_TREE["nodes"].items() if k != "trap"}})
    res = online_loss(learner, expert, env, q0, qd0, aux, horizon=0.2, interval=0.05)
    rates = rollout_rates(res.rollout)
    env.close()
    assert math.isfinite(res.loss) and res.loss > 0
    # the loss is the mean over sample 0's records and sample 1's records before its failure, and only those
    scored = res.rollout.qdd.isfinite().all(-1)
    assert scored[:, 0].all() and 0 < int(scored[:, 1].sum()) < scored.shape[0]
    assert res.loss == pytest.approx(float(((res.rollout.qdd - res.expert_qdd) ** 2)[scored].mean()), rel=1e-12)
    assert rates["failed"] == 0.5 and not bool(res.rollout.success[1])
    assert res.expert_qdd[:, 0].isfinite().all() and res.expert_qdd[-1, 1].isnan().all()
    assert rates["lyapunov_monotone_fraction"] == 1.0  # V before the failure did not rise
    # the keys this row is about, by name: rollout_rates and online_loss may report more
    return (
        f"online_loss = {res.loss:.3g}, success = {rates['success']}, failed = {rates['failed']}, "
        f"lyapunov_monotone_fraction = {rates['lyapunov_monotone_fraction']}"
    )


@row(
    "metrics-diverged-learner",
    "evaluation metrics of a learner that diverges",
    "particle2d, B = 2: a plain learner returns NaN for sample 1; the expert is a tree",
    "online loss inf (a diverged learner; the pipeline writes null), the expert is never asked at a NaN state",
    shows="online_loss = inf, success = 0.0, collision = 0.0",
)
def _diverged(tmp_path, monkeypatch):
    from rmpfusion.envs.particle2d import Particle2D
    from rmpfusion.evaluate.metrics import online_loss, rollout_rates

    env = Particle2D()
    expert = rmpfusion.build_tree(
        {
            "root": {"name": "q", "dim": 2},
            "nodes": {
                "goal": {"parent": "q", "map": {"type": "offset", "origin": "goal"}, "rmp": {"type": "goal_attractor"}},
                "regulariser": {"parent": "q", "map": {"type": "identity"}, "rmp": {"type": "identity_metric"}},
            },
        },
        aux_dims=env.aux_dims(),
    )
    q0, qd0, aux = env.sample(1, 2, seed=0)

    def learner(q, qd, a):  # a PD controller to the goal, broken for sample 1
        out = (a["goal"] - q) - 2.0 * qd
        out[1] = float("nan")
        return out

    res = online_loss(learner, expert, env, q0, qd0, aux, horizon=0.2, interval=0.1)
    rates = rollout_rates(res.rollout, with_lyapunov=False)
    assert res.loss == float("inf") and res.expert_qdd[:, 0].isfinite().all() and res.expert_qdd[1:, 1].isnan().all()
    return f"online_loss = {res.loss}, success = {rates['success']}, collision = {rates['collision']}"


# ------------------------------------------------------------------------------------------------ rows: config values
CONF = ROOT / "conf"
_REFUSED = "ConfigError at validation naming the key, what was given and what is allowed; nothing runs"


def validation_issue(overrides) -> str:
    """The one problem ``resolve_and_validate`` (what every entry point runs first) finds in conf/config.yaml
    composed with ``overrides``, as the line a user reads."""
    from rmpfusion.assembly.errors import ConfigError
    from rmpfusion.pipeline.compose import compose_run

    with pytest.raises(ConfigError) as info:
        compose_run(list(overrides), conf=CONF)
    issues = info.value.issues
    assert len(issues) == 1, [str(i) for i in issues]  # the bad value is the only problem, and it is found
    return str(issues[0])


def _config_row(*overrides: str):
    return lambda tmp_path, monkeypatch: validation_issue(overrides)


_ON_GRID = "(rollouts integrate and record on that step's grid only)"
for _id, _fault, _overrides, _shows, _needs in [
    (
        "negative-radius",
        "a negative radius on a tree's distance map",
        ["tree.nodes.obstacle.map.radius=-1"],
        (
            "tree.nodes.obstacle.map.radius: radius must be > 0 (a sphere of radius ≤ 0 has no surface to keep a distance "
            "from) or the name of an aux entry; given -1.0"
        ),
        (),
    ),
    (
        "negative-weight-radius",
        "a negative radius in an expert's weight",
        ["expert.obstacle.radius=-0.5"],
        (
            "expert.obstacle.radius: radius must be ≥ 0 (0 measures the distance from the centre point; a negative "
            "radius is no surface) or the name of an aux entry; given -0.5"
        ),
        (),
    ),
    (
        "negative-index",
        "a negative coordinate in a select map",
        ["tree.nodes.goal.map.type=select", "~tree.nodes.goal.map.origin", "+tree.nodes.goal.map.indices=[-1]"],
        (
            "tree.nodes.goal.map.indices: indices must be ≥ 0 (the parent's coordinates are numbered from 0; negative "
            "numbers do not count from the end); given [-1]"
        ),
        (),
    ),
    (
        "negative-scale",
        "a negative metric scale on a leaf",
        ["tree.nodes.conditioning.rmp.scale=-0.01"],
        "tree.nodes.conditioning.rmp.scale: Input should be greater than 0 (given: -0.01)",
        (),
    ),
    (
        "barrier-never-acts",
        "a barrier whose support ends before it starts",
        ["+tree.nodes.obstacle.rmp.min_distance=2"],
        (
            "tree.nodes.obstacle.rmp: min_distance must be < r_w (w(x) is evaluated at x ≥ min_distance and is zero from "
            "r_w on, so the barrier would never act); given min_distance=2.0, r_w=1.0"
        ),
        (),
    ),
    (
        "hidden-width-zero",
        "a hidden width of 0 in a learner's weight network",
        ["learners.rmp.weights.hidden=[0]"],
        (
            "learners.rmp.weights.hidden: hidden widths must be ≥ 1 (a layer of width 0 cuts the output off from the "
            "inputs, so nothing could be learned); given [0]"
        ),
        (),
    ),
    (
        "init-bias-below-floor",
        "a weight network asked to start below its floor",
        ["+learners.rmp.weights.init_bias=0.0005"],
        (
            "learners.rmp.weights: init_bias must be > floor (w = floor + a positive term never reaches floor or below); "
            "given init_bias=0.0005, floor=0.001"
        ),
        (),
    ),
    (
        "range-inverted",
        "an environment range with low > high",
        ["+env.obstacle_radius=[1.5,0.5]"],
        (
            "env.obstacle_radius: obstacle_radius must be (low, high) with low ≤ high (values are drawn uniformly between "
            "them); given (1.5, 0.5)"
        ),
        (),
    ),
    (
        "fraction-outside",
        "a fraction outside [0, 1]",
        ["+env.obstacle_along=[0.3,1.5]"],
        (
            "env.obstacle_along: obstacle_along must lie in [0, 1] (a fraction of the way from the starts to the goal: "
            "outside it the obstacle is not between them); given (0.3, 1.5)"
        ),
        (),
    ),
    ("zero-dt", "a zero integration step", ["env.dt=0"], "env.dt: Input should be greater than 0 (given: 0)", ()),
    (
        "interval-off-grid",
        "a recording interval off the environment's step grid",
        ["env.dt=0.03"],
        f"data.interval: must be a positive multiple of the environment's step env.dt = 0.03 s {_ON_GRID}; given 1.0",
        (),
    ),
    (
        "horizon-off-grid",
        "an evaluation horizon off the environment's step grid",
        ["eval.horizon=2.005"],
        f"eval.horizon: must be a multiple of the environment's step env.dt = 0.01 s {_ON_GRID}; given 2.005",
        (),
    ),
    (
        "snapshot-beyond-training",
        "a snapshot after the last training iteration",
        ["train.snapshots=[0,30000]"],
        (
            "train.snapshots: snapshots [30000] lie outside 0..train.iterations=20000 (a snapshot is the learner after "
            "that many iterations); given [0, 30000]"
        ),
        (),
    ),
    (
        "method-unknown",
        "a training method that is not registered",
        ["train.method=dager"],
        "train.method: unknown training method 'dager'; did you mean 'dagger', 'apg'? registered: apg, bc, dagger, field, match, pg",
        (),
    ),
    (
        "dagger-too-few-demonstrations",
        "DAgger asked for more demonstrations than the training split holds",
        ["train=dagger", "data=tiny"],
        (
            "train.initial_trajectories: round 0 would draw 500 demonstrations but the training split has 4 "
            "(data.train_envs × data.train_trajectories); lower it or collect more (a smoke run on data=tiny: "
            "train=dagger_smoke)"
        ),
        (),
    ),
    (
        "dagger-beta-unused",
        "a β that the DAgger schedule would ignore",
        ["train=dagger", "+train.beta=0.3"],
        (
            "train: beta is not used by beta_schedule=indicator (β = 0 after round 0); use beta_schedule=exponential or "
            "constant, or leave beta out; given beta=0.3"
        ),
        (),
    ),
    (
        "pg-decision-off-grid",
        "a policy-gradient decision interval off the environment's step grid",
        ["train=pg", "train.decision_interval=0.025"],
        "train.decision_interval: must be a positive multiple of the environment's step 0.01 s; given 0.025",
        (),
    ),
    (
        "apg-not-differentiable",
        "APG asked to back-propagate through a simulator stepped outside torch",
        ["experiment=franka", "train=apg"],
        (
            "train.method: apg back-propagates through rollouts, which the environment 'Manipulator' does not offer (it is not "
            "simulated in torch with a differentiable goal distance and clearance); use method pg, or an environment "
            "such as particle2d"
        ),
        ("pybullet",),
    ),
    (
        "match-torque-not-differentiable",
        "trajectory matching of an arm's recordings rolled out in pybullet's torque loop",
        ["experiment=recorded_arm", "train=match_arm_recordings", "env.mode=torque"],
        (
            "train.method: match back-propagates through rollouts, which the environment 'Manipulator' does not offer "
            "(env.mode=torque steps pybullet outside torch; set env.mode=kinematic); use method bc, or an environment "
            "such as plane, particle2d or the manipulator in kinematic mode"
        ),
        ("pybullet",),
    ),
    (
        "recorded-key-the-format-ignores",
        "a user's file given to the LASA experiment, whose data block reads the LASA shape",
        ["experiment=lasa", "data.files=[my_demos.csv]"],
        (
            "data: data.files=['my_demos.csv'] is not read by format lasa (read by: csv, hdf5, npz, rosbag); set data.files=[], "
            "or a data.format that reads it (for your own files start from data=recorded: no preset's values) "
            "(given: {'source': 'recorded', 'format': 'lasa', 'shape': 'Angle', 'files': ['my_demo...)"
        ),
        (),
    ),
    (
        "recorded-angles-on-a-plane",
        "joint-angle units for recordings learned on the plane",
        [
            "experiment=lasa",
            "data=recorded",
            "data.files=[rmpfusion:panda_via_points.csv]",
            "data.demo_column=demo",
            "data.units=deg",
            "name=mine",
        ],
        (
            "data: data.units=deg is for an arm's joint angles, but this environment's coordinates are positions; set "
            "data.units=m, cm or mm"
        ),
        (),
    ),
    (
        "recorded-eval-horizon",
        "an evaluation horizon for recorded demonstrations, whose rollouts last a multiple of the longest one",
        ["experiment=lasa", "eval.horizon=5"],
        (
            "eval.horizon: recorded demonstrations set how long the evaluation's rollouts last: data.horizon_factor "
            "times the longest demonstration; remove eval.horizon and set data.horizon_factor instead (given: 5.0)"
        ),
        (),
    ),
    (
        "joint-margin-no-room",
        "a joint margin that leaves lower ≥ upper for the starts",
        ["experiment=franka", "env.joint_margin=2.0"],
        (
            "env.joint_margin: joint_margin must be < half of every joint's range (starts are drawn in [lower + margin, "
            "upper − margin]); panda_joint2 spans [-1.8326, 1.8326], half of it is 1.833; given 2.0"
        ),
        ("pybullet",),
    ),
    (
        "render-trajectory-missing",
        "a rendered test trajectory that is not collected",
        ["experiment=franka", "env.render_trajectory=20"],
        (
            "env.render_trajectory: must be < 20, the number of test trajectories (data.test_envs × "
            "data.test_trajectories, numbered from 0); given 20"
        ),
        ("pybullet",),
    ),
    (
        "robot-joint-misspelt",
        "a robot description naming a joint its URDF does not have",
        ["experiment=franka", "env.robot.joints.6=panda_joint_7"],
        (
            "env.robot: joints[6] = 'panda_joint_7' is not a movable joint of pkg://pybullet_data/franka_panda/panda.urdf; "
            "did you mean 'panda_joint7', 'panda_joint6', 'panda_joint5'? movable joints: panda_joint1, panda_joint2, "
            "panda_joint3, panda_joint4, panda_joint5, panda_joint6, panda_joint7, panda_finger_joint1, "
            "panda_finger_joint2<text>"
        ),
        ("pybullet",),
    ),
    (
        "test-scene-other-shapes",
        "a test scene whose obstacles the training scene's tree cannot measure",
        ["experiment=franka", "scene@env.test_scene=iiwa_box"],
        (
            "env: test_scene must have the obstacles of the training scene, with the same shapes in the same order, "
            "each static or moving as there, and a ground plane if and only if it has one (the tree has one distance "
            "edge per obstacle); training: [('cylinder', 'static')], given: [('box', 'static')]"
        ),
        ("pybullet",),
    ),
    (
        "retired-environment",
        "a config naming the environment of old, before robots and scenes were data",
        ["experiment=franka", "env.type=franka"],
        (
            "env.type: 'franka' was retired: the environment 'franka' became 'manipulator', which takes its robot and "
            "scene from conf/robot/ and conf/scene/; compose the experiment anew (experiment=franka keeps its name and "
            "protocol)"
        ),
        ("pybullet",),
    ),
]:
    row(
        f"config-{_id}",
        _fault,
        "resolve_and_validate on conf/config.yaml with " + " ".join(_overrides),
        _REFUSED,
        shows=_shows,
        needs=_needs,
    )(_config_row(*_overrides))

URDF_INVERTED = """<robot name="arm">
  <link name="base"/><link name="l1"/><link name="tip"/>
  <joint name="j1" type="revolute"><parent link="base"/><child link="l1"/><axis xyz="0 0 1"/>
    <limit lower="1.0" upper="-1.0" effort="1" velocity="1"/></joint>
  <joint name="j2" type="revolute"><parent link="l1"/><child link="tip"/><origin xyz="1 0 0"/><axis xyz="0 0 1"/>
    <limit lower="-1.0" upper="1.0" effort="1" velocity="1"/></joint>
</robot>
"""


@row(
    "config-urdf-limits-inverted",
    "a URDF joint limit with lower > upper",
    "resolve_and_validate with a forward_kinematics node on a 2-joint URDF whose joint j1 has lower=1, upper=-1",
    "ConfigError at validation naming the node, the file and the joint; nothing runs",
    shows="tree.nodes.arm.map: <dir>/arm.urdf: URDF joint 'j1': limit lower=1.0 is above upper=-1.0 (the joint "
    "could take no angle at all); fix the <limit> of the joint",
)
def _urdf_inverted(tmp_path, monkeypatch):
    urdf = tmp_path / "arm.urdf"
    urdf.write_text(URDF_INVERTED, encoding="utf-8")
    return validation_issue(
        [
            (
                f"+tree.nodes.arm={{parent: q, map: {{type: forward_kinematics, robot: null, "
                f"urdf: '{urdf}', link: tip}}, rmp: {{type: damper}}}}"
            )
        ]
    )


# A 2-joint arm (so it fits the 2-D root of conf/config.yaml) with a tool fixed to its tip, for the robot leaves' rows.
URDF_ARM = """<robot name="arm">
  <link name="base"/><link name="l1"/><link name="tip"/><link name="tool"/>
  <joint name="j1" type="revolute"><parent link="base"/><child link="l1"/><axis xyz="0 0 1"/>
    <limit lower="-1.0" upper="1.0" effort="1"VELOCITY/></joint>
  <joint name="j2" type="revolute"><parent link="l1"/><child link="tip"/><origin xyz="1 0 0"/><axis xyz="0 1 0"/>
    <limit lower="-1.0" upper="1.0" effort="1"VELOCITY/></joint>
  <joint name="tool_mount" type="fixed"><parent link="tip"/><child link="tool"/><origin xyz="0.2 0 0"/></joint>
</robot>
"""


def _arm_row(node: str, velocity_limits: bool = True):
    """A row adding ``+tree.nodes.leaf=<node>`` to conf/config.yaml, with URDF standing for the 2-joint arm's path."""

    def run(tmp_path, monkeypatch):
        urdf = tmp_path / "arm.urdf"
        urdf.write_text(URDF_ARM.replace("VELOCITY", ' velocity="2"' if velocity_limits else ""), encoding="utf-8")
        return validation_issue([f"+tree.nodes.leaf={node.replace('URDF', str(urdf))}"])

    return run


_ARM = "robot: null, urdf: 'URDF'"
for _id, _fault, _node, _shows, _velocity in [
    (
        "link-axis-zero",
        "a tool axis of zero length",
        f"{{parent: q, map: {{type: link_axis, {_ARM}, link: tip, axis: [0, 0, 0]}}, rmp: {{type: orientation_attractor}}}}",
        (
            "tree.nodes.leaf.map.axis: axis must be a non-zero vector (it is a direction in the link frame); given "
            "[0.0, 0.0, 0.0]"
        ),
        True,
    ),
    (
        "orientation-parallel-axes",
        "two parallel axes for a full orientation",
        (
            f"{{parent: q, map: {{type: link_orientation, {_ARM}, link: tip, axes: [[1, 0, 0], [-2, 0, 0]]}}, "
            f"rmp: {{type: orientation_attractor}}}}"
        ),
        (
            "tree.nodes.leaf.map.axes: axes[0] and axes[1] are parallel: they pin the same direction twice; give "
            "directions that are not parallel; given [[1.0, 0.0, 0.0], [-2.0, 0.0, 0.0]]"
        ),
        True,
    ),
    (
        "orientation-target-dimension",
        "an orientation target of the wrong dimension",
        (
            f"{{parent: q, map: {{type: link_orientation, {_ARM}, link: tip, target: goal}}, "
            f"rmp: {{type: orientation_attractor}}}}"
        ),
        (
            "tree.nodes.leaf.map: link_orientation.target has dimension 2 but target_format 'quaternion_xyzw' with 3 "
            "axes needs 4; declare the aux entry with 4 numbers or change target_format"
        ),
        True,
    ),
    (
        "orientation-not-a-rotation",
        "a target matrix that is not a rotation",
        (
            f"{{parent: q, map: {{type: link_orientation, {_ARM}, link: tip, target_format: matrix, "
            f"target: [1, 0, 0, 0, 2, 0, 0, 0, 1]}}, rmp: {{type: orientation_attractor}}}}"
        ),
        (
            "tree.nodes.leaf.map: link_orientation.target: [1.0, 0.0, 0.0, 0.0, 2.0, 0.0, 0.0, 0.0, 1.0] is not a "
            "rotation matrix (rows orthonormal, determinant +1; |R Rᵀ − I| = 3); give the 9 entries of a rotation, row "
            "by row"
        ),
        True,
    ),
    (
        "self-collision-one-body",
        "self-collision spheres on links that move together",
        (
            f"{{parent: q, map: {{type: link_sphere_distance, {_ARM}, a: {{link: tip, radius: 0.05}}, "
            f"b: {{link: tool, radius: 0.05}}}}, rmp: {{type: collision_avoidance}}}}"
        ),
        (
            "tree.nodes.leaf.map: link_sphere_distance: links 'tip' and 'tool' move as one rigid body (no actuated joint "
            "between them), so the distance of their spheres never changes; pick spheres on links that move relative to "
            "each other (non_adjacent_link_pairs)"
        ),
        True,
    ),
    (
        "velocity-limit-absent",
        "a URDF without joint velocity limits, for a velocity cap",
        f"{{parent: q, map: {{type: velocity_scaled_joints, {_ARM}}}, rmp: {{type: velocity_limit}}}}",
        (
            "tree.nodes.leaf.map: velocity_scaled_joints: URDF '<dir>/arm.urdf' gives no velocity limit for joints j1, "
            "j2 (<limit velocity=...> absent or 0); give velocity_limit: one value per actuated joint"
        ),
        False,
    ),
    (
        "velocity-limit-count",
        "a velocity cap with one limit too many",
        "{parent: q, map: {type: identity}, rmp: {type: velocity_limit, limit: [1.0, 2.0, 0.5]}}",
        (
            "tree.nodes.leaf.rmp: velocity_limit.limit has 3 values for a 2-dimensional space; give one value, or one "
            "per coordinate"
        ),
        True,
    ),
    (
        "velocity-limit-onset",
        "a velocity cap that starts at its limit",
        "{parent: q, map: {type: identity}, rmp: {type: velocity_limit, onset: 1.0}}",
        "tree.nodes.leaf.rmp.onset: Input should be less than 1 (given: 1.0)",
        True,
    ),
    (
        "moving-goal-without-velocity",
        "a moving-goal attractor on a plain offset (no goal velocity)",
        "{parent: q, map: {type: offset, origin: goal}, rmp: {type: moving_goal_attractor}}",
        (
            "tree.nodes.leaf.rmp: 'moving_goal_attractor' reads the output of a 'moving_offset' map, but the map here "
            "gives plain coordinates; put it under a moving_offset map"
        ),
        True,
    ),
    (
        "moving-offset-plain-leaf",
        "a leaf that reads plain coordinates under a moving_offset map",
        "{parent: q, map: {type: moving_offset, origin: goal, velocity: [0.1, 0.0]}, rmp: {type: goal_attractor}}",
        (
            "tree.nodes.leaf.rmp: 'goal_attractor' reads plain coordinates but the map gives the output of a "
            "'moving_offset' map; put a leaf that reads it here, or change the map"
        ),
        True,
    ),
]:
    _arm = " (<dir>/arm.urdf: a 2-joint arm with a tool fixed to its tip)" if "URDF" in _node else ""
    row(
        f"config-{_id}",
        _fault,
        f"resolve_and_validate on conf/config.yaml with +tree.nodes.leaf={_node.replace('URDF', '<dir>/arm.urdf')}{_arm}",
        _REFUSED,
        shows=_shows,
    )(_arm_row(_node, _velocity))


# ------------------------------------------------------------------------------------------------ properties
PROPERTY = settings(max_examples=15, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])


@PROPERTY
@given(B=st.integers(1, 6), data=st.data(), value=st.sampled_from([float("nan"), float("inf"), float("-inf")]))
def test_any_non_finite_input_is_named_with_its_samples(B, data, value):
    tree = make_tree()
    q, qd, aux = states(B, seed=B)
    which = data.draw(st.sampled_from(["q", "qd", *AUX_DIMS]))
    bad = sorted(data.draw(st.sets(st.integers(0, B - 1), min_size=1)))
    inputs = {"q": q.clone(), "qd": qd.clone(), **{k: v.clone() for k, v in aux.items()}}
    inputs[which][bad, data.draw(st.integers(0, inputs[which].shape[1] - 1))] = value
    with pytest.raises(NumericalError) as info:
        tree(inputs["q"], inputs["qd"], {k: inputs[k] for k in AUX_DIMS})
    label = which if which in ("q", "qd") else f"aux['{which}']"
    assert info.value.where == label and info.value.samples == bad
    assert str(info.value).startswith(f"non-finite input {label} in sample")


@PROPERTY
@given(B=st.integers(2, 6), data=st.data())
def test_isolating_policy_answers_nan_exactly_for_the_faulty_samples(B, data):
    """Any subset of faulty samples (not all): those rows are NaN, every other row equals the tree's own answer."""
    from rmpfusion.envs.faults import IsolatingPolicy

    tree = make_tree(bad={"parent": "q", "map": {"type": "identity"}, "rmp": {"type": "test_nan_beyond", "limit": 3.2}})
    q, qd, aux = states(B, seed=B + 7)
    bad = sorted(data.draw(st.sets(st.integers(0, B - 1), min_size=1, max_size=B - 1)))
    q[bad, 0] = 3.5
    guarded = IsolatingPolicy(tree)
    with torch.no_grad():
        out = guarded(q, qd, aux)
        good = [b for b in range(B) if b not in bad]
        ref = tree(q[good], qd[good], {k: v[good] for k, v in aux.items()})
    assert sorted(guarded.reasons) == bad
    assert out.qdd[bad].isnan().all() and out.V[bad].isnan().all()
    torch.testing.assert_close(out.qdd[good], ref.qdd, rtol=1e-10, atol=1e-10)
    assert "node 'bad'" in guarded.explain(bad[0], "non-finite acceleration")


# ------------------------------------------------------------------------------------------------ certificate on rollouts
def test_certify_rollout_checks_every_record_and_skips_ended_samples():
    from rmpfusion.envs.particle2d import Particle2D
    from rmpfusion.evaluate.certificate import certify_rollout

    env = Particle2D()
    spec = {
        "root": {"name": "q", "dim": 2},
        "nodes": {
            "goal": {
                "parent": "q",
                "map": {"type": "offset", "origin": "goal"},
                "weight": {"type": "mlp", "hidden": [8], "aux": ["goal", "obstacle1_center"]},
                "rmp": {"type": "goal_attractor"},
            },
            "obstacle": {
                "parent": "q",
                "map": {"type": "sphere_distance", "center": "obstacle1_center", "radius": "obstacle1_radius"},
                "rmp": {"type": "collision_avoidance"},
            },
            "regulariser": {"parent": "q", "map": {"type": "identity"}, "rmp": {"type": "identity_metric"}},
        },
    }
    torch.manual_seed(0)
    tree = rmpfusion.build_tree(spec, aux_dims=env.aux_dims())
    q0, qd0, aux = env.sample(1, 3, seed=0)
    with torch.no_grad():
        ro = env.rollout(tree, q0, qd0, aux, horizon=1.0, record_every=0.1)
    ro.q[5:, 2] = float("nan")  # as a rollout that ended sample 2 after its 5th record leaves it
    cert = certify_rollout(tree, ro, aux)
    assert cert.states == 11 * 3 - 6 and cert.ok, cert.summary()
    # a broken record is reported by its flat time-major index (record i = time i // B, sample i % B)
    ro.qd[7, 1] = float("inf")
    cert = certify_rollout(tree, ro, aux)
    assert cert.states == 11 * 3 - 7 and cert.ok  # non-finite records are skipped, not certified
    tree.rmps["regulariser"].w = -1e3  # an indefinite M_r at every state
    cert = certify_rollout(tree, ro, aux)
    kept = [i for i in range(33) if not ((i % 3 == 2 and i // 3 >= 5) or i == 7 * 3 + 1)]
    assert not cert.inertia_positive_definite and cert.failing_states == kept


# ------------------------------------------------------------------------------------------------ rows: the command line
_SAID = "one or two lines naming the file, key or path and the fix, exit 2; nothing runs"


def command_line_message(*argv: str) -> str:
    """What ``rmpfusion-run`` / ``-validate`` say for a command line that cannot compose (before anything runs)."""
    from rmpfusion.cli.preflight import CommandLineError, check_command_line, check_output_dir

    with pytest.raises(CommandLineError) as info:
        check_command_line(str(CONF), list(argv))
        check_output_dir(list(argv))
    return f"error: {info.value}"


@row(
    "cli-misspelt-group",
    "a misspelt config group",
    "rmpfusion-run experimnt=2d1level",
    _SAID,
    shows="error: 'experimnt' is neither a config group nor a key of the config; did you mean 'experiment', "
    "'expert'? config groups: attractor_weight, data, env, eval, experiment, expert, <text>; top-level keys: env, tree, expert, "
    "learners, data, train, eval, logger, name, seed, device (to add a new key on purpose write +experimnt=...)",
)
def _cli_misspelt_group(tmp_path, monkeypatch):
    return command_line_message("experimnt=2d1level")


@row(
    "cli-misspelt-group-added",
    "a misspelt config group written as a new key",
    "rmpfusion-run +experimnt=2d1level",
    _SAID,
    shows="error: '+experimnt=2d1level' adds a new key 'experimnt', which the config does not have; did you "
    "mean the config group 'experiment' (experiment=2d1level)?",
)
def _cli_added_group(tmp_path, monkeypatch):
    return command_line_message("+experimnt=2d1level")


@row(
    "cli-missing-option",
    "a config group option that does not exist",
    "rmpfusion-run experiment=2d1levl",
    _SAID,
    shows="error: no config '2d1levl' in the group 'experiment' (experiment/2d1levl.yaml); did you mean '2d1level', "
    "<text>? options: 2d1level, <text>",
)
def _cli_missing_option(tmp_path, monkeypatch):
    return command_line_message("experiment=2d1levl")


@row(
    "cli-yaml-syntax",
    "a YAML syntax error in a user's config file",
    "rmpfusion-run --config-dir <dir> experiment=mine, where <dir>/experiment/mine.yaml has an unclosed [",
    _SAID,
    shows="error: YAML syntax error in <dir>/experiment/mine.yaml: while parsing a flow sequence (line 3, column 7), "
    "expected ',' or ']', but got '<stream end>' (line 4, column 1); fix the file (every config file must be "
    "valid YAML)",
)
def _cli_yaml_syntax(tmp_path, monkeypatch):
    (tmp_path / "experiment").mkdir()
    (tmp_path / "experiment" / "mine.yaml").write_text("name: mine\ntrain:\n  lr: [1, 2\n")
    return command_line_message("--config-dir", str(tmp_path), "experiment=mine")


@row(
    "cli-override-grammar",
    "an override Hydra cannot parse",
    "rmpfusion-run train.lr=[1,2",
    _SAID,
    shows="error: cannot read the command line 'train.lr=[1,2': no viable alternative at input '[1,2'; see "
    "https://hydra.cc/docs/advanced/override_grammar/basic/",
)
def _cli_grammar(tmp_path, monkeypatch):
    return command_line_message("train.lr=[1,2")


@row(
    "cli-output-dir",
    "an output directory that cannot be created",
    "hydra.run.dir=<dir>/a-file/run",
    _SAID,
    shows="error: hydra.run.dir=<dir>/a-file/run cannot be created (Not a directory); choose a directory you can "
    "write to",
)
def _cli_output_dir(tmp_path, monkeypatch):
    (tmp_path / "a-file").write_text("")
    return command_line_message(f"hydra.run.dir={tmp_path / 'a-file' / 'run'}")


@row(
    "plugin-import-error",
    "a plugin whose import raises",
    "an rmpfusion.plugins entry point naming a module that divides by zero on import",
    "the plugin's name, its own error and its own frames (none of rmpfusion's), exit 2",
    shows="error: rmpfusion plugin 'broken' (broken_plugin) failed to load: ZeroDivisionError: division by zero\n"
    '  File "<dir>/broken_plugin.py", line 2, in <module>\n    ratio = 1 / 0\n'
    "(RMPFUSION_DEBUG=1 shows the whole traceback)",
)
def _plugin_import_error(tmp_path, monkeypatch):
    import contextlib
    import io
    from importlib.metadata import EntryPoint

    from rmpfusion import registry
    from rmpfusion.cli._common import user_errors_exit

    (tmp_path / "broken_plugin.py").write_text('"""A plugin with a bug."""\nratio = 1 / 0\n')
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setattr(registry, "entry_points", lambda group: [EntryPoint("broken", "broken_plugin", group)])
    loader = registry.PluginLoader()  # an isolated loader: the default registries keep theirs
    err = io.StringIO()
    with contextlib.redirect_stderr(err), pytest.raises(SystemExit) as info, user_errors_exit():
        loader.load()
    assert info.value.code == 2
    return err.getvalue().strip()


def _checkpoint_message(path) -> str:
    from rmpfusion.cli.from_checkpoint import evaluate_checkpoint

    with pytest.raises(CheckpointError) as info:
        evaluate_checkpoint(path, figures=False, progress=False)
    return f"error: {info.value}"


@row(
    "checkpoint-given-a-directory",
    "rmpfusion-evaluate-checkpoint given a run directory",
    "rmpfusion-evaluate-checkpoint <dir> (a run directory holding checkpoints/rmp/)",
    "says it is a directory and names the checkpoints in it; nothing is changed",
    shows="error: <dir> is a directory, not a checkpoint file; its checkpoints: <dir>/checkpoints/rmp/ckpt-00000003.pt",
)
def _checkpoint_dir(tmp_path, monkeypatch):
    (tmp_path / "checkpoints" / "rmp").mkdir(parents=True)
    (tmp_path / "checkpoints" / "rmp" / "ckpt-00000003.pt").write_bytes(b"")
    return _checkpoint_message(tmp_path)


@row(
    "checkpoint-given-metrics",
    "rmpfusion-evaluate-checkpoint given a run's metrics.json",
    "rmpfusion-evaluate-checkpoint <dir>/metrics.json",
    "says what the file is; never advises deleting it",
    shows="error: <dir>/metrics.json is a JSON file, not a checkpoint; a checkpoint is "
    "checkpoints/<learner>/ckpt-<iteration>.pt in a run directory",
)
def _checkpoint_json(tmp_path, monkeypatch):
    (tmp_path / "metrics.json").write_text("{}")
    return _checkpoint_message(tmp_path / "metrics.json")


@row(
    "checkpoint-given-a-dataset",
    "rmpfusion-evaluate-checkpoint given a dataset file",
    "rmpfusion-evaluate-checkpoint <dir>/data/train.pt (written by save_dataset)",
    "says it is a dataset; never advises deleting it",
    shows="error: <dir>/data/train.pt is a dataset (demonstrations of a run's data/), not a checkpoint; nothing was "
    "changed",
)
def _checkpoint_dataset(tmp_path, monkeypatch):
    n = 3
    ds = Dataset(
        q=torch.zeros(n, 2, dtype=F64),
        qd=torch.zeros(n, 2, dtype=F64),
        qdd=torch.zeros(n, 2, dtype=F64),
        aux={},
        env_id=torch.zeros(n, dtype=torch.long),
        traj_id=torch.zeros(n, dtype=torch.long),
        t=torch.arange(n, dtype=F64),
        collided=torch.zeros(1, dtype=torch.bool),
        success=torch.ones(1, dtype=torch.bool),
    )
    (tmp_path / "data").mkdir()
    save_dataset(tmp_path / "data" / "train.pt", ds, {"seed": 0})
    return _checkpoint_message(tmp_path / "data" / "train.pt")


@row(
    "checkpoint-given-a-foreign-file",
    "rmpfusion-evaluate-checkpoint given a file rmpfusion did not write",
    "rmpfusion-evaluate-checkpoint <dir>/weights.bin (random bytes)",
    "says so; never advises deleting it",
    shows="error: <dir>/weights.bin is not a checkpoint written by rmpfusion (not a torch file it can read); nothing "
    "was changed",
)
def _checkpoint_foreign(tmp_path, monkeypatch):
    (tmp_path / "weights.bin").write_bytes(bytes(range(64)))
    return _checkpoint_message(tmp_path / "weights.bin")


# ------------------------------------------------------------------------------------------------ rows: whole commands
# Each row runs a console script in this process as a user would (its own command line, no RMPFUSION_DEBUG) and
# asserts its exit status, that no traceback is printed and the message: the output from its first "error:" line on.
_ONE_LINE = "one message naming the file, key or node and what to do; exit status {code}; no traceback"
TINY = ["data=tiny", "train=tiny", "eval=fast", "logger=disabled"]
_TINY_RUN: dict[str, Path] = {}


def cli(entry, *argv: str) -> tuple[int, str]:
    """Run a console script's entry point in this process with ``argv``: (exit status, everything it printed)."""
    import contextlib
    import io

    from hydra.core.global_hydra import GlobalHydra

    out, old_argv, code = io.StringIO(), sys.argv, 0
    sys.argv = ["rmpfusion", *argv]
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(out):
            try:
                returned = entry()
                code = returned if isinstance(returned, int) else 0
            except SystemExit as e:
                code = e.code if isinstance(e.code, int) else (0 if e.code is None else 1)
    finally:
        sys.argv = old_argv
        GlobalHydra.instance().clear()
    return code, out.getvalue()


def said(entry, *argv: str, code: int, monkeypatch=None) -> str:
    """What a failing command says (from its first ``error:`` line), asserting its exit status and no traceback."""
    if monkeypatch is not None:
        monkeypatch.delenv("RMPFUSION_DEBUG", raising=False)
    got, out = cli(entry, *argv)
    assert got == code, f"exit status {got}, expected {code}:\n{out[-3000:]}"
    assert "Traceback" not in out and "Error executing job" not in out, out[-3000:]
    assert "error:" in out, out[-3000:]
    return out[out.index("error:") :].strip()


def _run_main():
    from rmpfusion.cli.run import main as run_main

    return run_main


def _validate_main():
    from rmpfusion.cli.validate import main as validate_main

    return validate_main


def tiny_run(tmp_path: Path) -> Path:
    """A finished run of TINY in ``tmp_path/run`` (run once per process, copied for every row that damages it)."""
    import shutil
    import tempfile

    if "dir" not in _TINY_RUN:
        made = Path(tempfile.mkdtemp(prefix="rmpfusion-tiny-")) / "run"
        code, out = cli(_run_main(), *TINY, f"hydra.run.dir={made}")
        assert code == 0, out[-3000:]
        _TINY_RUN["dir"] = made
    shutil.copytree(_TINY_RUN["dir"], tmp_path / "run")
    return tmp_path / "run"


@row(
    "resume-damaged-checkpoint",
    "a damaged latest checkpoint when a run resumes",
    "rmpfusion-run (tiny) again in its finished run directory, its checkpoints/rmp/ckpt-00000003.pt cut after 900 bytes",
    _ONE_LINE.format(code=2),
    shows="error: checkpoint file <dir>/run/checkpoints/rmp/ckpt-00000003.pt is unreadable or truncated (RuntimeError: "
    "PytorchStreamReader <text>); delete <dir>/run/checkpoints/rmp/ckpt-00000003.pt (training then resumes "
    "from the previous checkpoint in <dir>/run/checkpoints/rmp if there is one, else starts over)",
)
def _resume_damaged(tmp_path, monkeypatch):
    run = tiny_run(tmp_path)
    ck = run / "checkpoints" / "rmp" / "ckpt-00000003.pt"
    ck.write_bytes(ck.read_bytes()[:900])
    return said(_run_main(), *TINY, f"hydra.run.dir={run}", code=2, monkeypatch=monkeypatch)


@row(
    "evaluate-damaged-dataset",
    "a damaged test dataset when rmpfusion-evaluate runs",
    "rmpfusion-evaluate (tiny) in a finished run directory whose data/test-*.pt has one bit of a label flipped",
    _ONE_LINE.format(code=2),
    shows="error: dataset file <dir>/run/data/test-<hex>.pt fails its checksum (stored <hex>…, content <hex>…): it "
    "was modified or damaged; delete <dir>/run/data/test-<hex>.pt to have it collected again",
)
def _evaluate_damaged(tmp_path, monkeypatch):
    from rmpfusion.cli.run import evaluate as evaluate_main

    run = tiny_run(tmp_path)
    path = next((run / "data").glob("test-*.pt"))
    flip_byte_in(path, torch.load(path, weights_only=True)["tensors"]["qdd"].numpy().tobytes())
    return said(evaluate_main, *TINY, f"hydra.run.dir={run}", code=2, monkeypatch=monkeypatch)


def _mounted_tmpfs(path: Path, size: str) -> bool:
    import subprocess

    path.mkdir(parents=True, exist_ok=True)
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(path)], capture_output=True)
    return r.returncode == 0


@row(
    "disk-full",
    "a full disk under the run directory",
    "rmpfusion-run (tiny) with hydra.run.dir on a 160 KiB tmpfs (skipped where this machine cannot mount one)",
    "the file, the space left and that a rerun resumes; exit status 1; no traceback",
    shows="error: no space left to write <dir>/disk/run/<text> (<num> <B|KiB> free of 160.0 KiB on the file system "
    "of <dir>/disk/run/<text>); the files written before it are intact: free some space (or point the run "
    "elsewhere) and run the same command again: it resumes from what was written",
)
def _disk_full(tmp_path, monkeypatch):
    import subprocess

    disk = tmp_path / "disk"
    if not _mounted_tmpfs(disk, "160k"):
        pytest.skip("cannot mount a tmpfs here (mount -t tmpfs needs root or a user namespace)")
    try:
        return said(_run_main(), *TINY, f"hydra.run.dir={disk / 'run'}", code=1, monkeypatch=monkeypatch)
    finally:
        subprocess.run(["umount", "-l", str(disk)], capture_output=True)


@row(
    "robot-urdf-missing",
    "a robot file whose urdf: does not exist",
    "rmpfusion-validate --config-dir <dir> experiment=franka robot=mine, where robot/mine.yaml names /nonexistent/arm.urdf",
    _ONE_LINE.format(code=2),
    needs=("pybullet",),
    shows="error: invalid configuration: 1 problem(s)\n  - env.robot: urdf: URDF file not found: /nonexistent/arm.urdf; "
    "fix urdf: in the robot's file (conf/robot/<name>.yaml or env.robot.urdf=...) to name a URDF that exists (a "
    "path from the working directory, or pkg://<package>/<path>) (given: <text>)",
)
def _urdf_missing(tmp_path, monkeypatch):
    (tmp_path / "robot").mkdir()
    text = (CONF / "robot" / "panda.yaml").read_text()
    (tmp_path / "robot" / "mine.yaml").write_text(re.sub(r"(?m)^urdf: .*$", "urdf: /nonexistent/arm.urdf", text))
    return said(
        _validate_main(),
        "--config-dir",
        str(tmp_path),
        "experiment=franka",
        "robot=mine",
        f"hydra.run.dir={tmp_path / 'v'}",
        code=2,
        monkeypatch=monkeypatch,
    )


@row(
    "cache-dir-is-a-file",
    "data.cache_dir that is an existing file",
    "rmpfusion-validate data.cache_dir=<dir>/cache",
    _ONE_LINE.format(code=2),
    shows="error: invalid configuration: 1 problem(s)\n  - data.cache_dir: <dir>/cache is a file, not a directory, so no "
    "dataset can be cached in it; point data.cache_dir at a directory (it is created if missing), or leave it out "
    "to keep data in the run directory (given: '<dir>/cache')",
)
def _cache_file(tmp_path, monkeypatch):
    (tmp_path / "cache").write_text("")
    return said(
        _validate_main(),
        f"data.cache_dir={tmp_path / 'cache'}",
        f"hydra.run.dir={tmp_path / 'v'}",
        code=2,
        monkeypatch=monkeypatch,
    )


def _validate_recorded_arm(tmp_path: Path, monkeypatch, *overrides: str) -> str:
    """What rmpfusion-validate says for experiment=recorded_arm with ``overrides`` (exit status 2)."""
    hydra_dir = f"hydra.run.dir={tmp_path / 'v'}"
    return said(_validate_main(), "experiment=recorded_arm", *overrides, hydra_dir, code=2, monkeypatch=monkeypatch)


_PANDA = ", ".join(f"panda_joint{k}" for k in range(1, 8))


@row(
    "recorded-bag-of-another-arm",
    "a ROS bag of another arm's joint states for the Panda's experiment",
    "rmpfusion-validate experiment=recorded_arm data.format=rosbag data.demo_column=null data.files=[<dir>/ur5e.bag] "
    "(a UR5e driver's /joint_states: six joints of other names)",
    _ONE_LINE.format(code=2),
    shows="error: invalid configuration: 1 problem(s)\n  - data: <dir>/ur5e.bag [/joint_states]: no message carries "
    f"every joint of {_PANDA} (never named: {_PANDA}); the topic's messages name elbow_joint, shoulder_lift_joint, "
    "shoulder_pan_joint, wrist_1_joint, wrist_2_joint, wrist_3_joint. Choose the joints in data.columns, or the robot "
    "those joints belong to",
    needs=("rosbags",),
)
def _bag_of_another_arm(tmp_path, monkeypatch):
    import numpy as np

    from tools.rosbag_recordings import CLOCK_NS, joint_state, typestore, write_bag

    ur = ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint", "wrist_2_joint", "wrist_3_joint"]
    store, stamps = typestore("ros1"), CLOCK_NS + 10_000_000 * np.arange(20)
    log = [
        ("/joint_states", "sensor_msgs/msg/JointState", joint_state(store, "ros1", int(t), ur, [0.1 * k] * 6), int(t))
        for k, t in enumerate(stamps)
    ]
    write_bag(tmp_path / "ur5e.bag", "ros1", log)
    return _validate_recorded_arm(
        tmp_path, monkeypatch, "data.format=rosbag", "data.demo_column=null", f"data.files=[{tmp_path / 'ur5e.bag'}]"
    )


@row(
    "recorded-aux-misspelt",
    "aux state per demonstration under a name the environment does not read",
    "rmpfusion-validate experiment=recorded_arm data.files=[<dir>/obstacles.csv] "
    "'data.aux_columns={obstacle_centre: [ox, oy, oz]}' (the shipped Panda recordings with the cylinder's centre "
    "in three more columns)",
    _ONE_LINE.format(code=2),
    shows="error: invalid configuration: 1 problem(s)\n  - data: <dir>/obstacles.csv [demo=demo00]: aux state "
    "'obstacle_centre' (data.aux_columns / aux_keys / aux_topics) is not read by the environment manipulator; its aux state "
    "(name and width): goal (3), obstacle1_center (3), obstacle1_radius (1), obstacle1_axis (3), "
    "obstacle1_half_height (1), posture (7); did you mean 'obstacle1_center'?",
)
def _aux_misspelt(tmp_path, monkeypatch):
    lines = (ROOT / "rmpfusion" / "recordings" / "files" / "panda_via_points.csv").read_text().splitlines()
    rows = [f"{lines[0]},ox,oy,oz", *(f"{line},0.6,0.0,0.5" for line in lines[1:] if line)]
    (tmp_path / "obstacles.csv").write_text("\n".join(rows) + "\n")
    return _validate_recorded_arm(
        tmp_path,
        monkeypatch,
        f"data.files=[{tmp_path / 'obstacles.csv'}]",
        "data.aux_columns={obstacle_centre: [ox, oy, oz]}",
    )


@row(
    "recorded-joint-jump",
    "an arm's recording in which the joints jump (two demonstrations logged back to back without the return between)",
    "rmpfusion-validate experiment=recorded_arm data.files=[<dir>/jump.csv] data.demo_column=null (the shipped "
    "demo00, then demo01 10 ms after its end)",
    _ONE_LINE.format(code=2),
    shows="error: invalid configuration: 1 problem(s)\n  - data: <dir>/jump.csv, row 408, column 'panda_joint<num>': "
    "panda_joint<num> moves <num> rad in <num> ms from the sample before, over 2 times its velocity limit of <num> "
    "rad/s on the robot 'panda': a jump in the recording (a glitch, or demonstrations logged back to back without the "
    "motion between them); drop those samples, or cut the recording there",
)
def _joint_jump(tmp_path, monkeypatch):
    import numpy as np
    from sessions import shipped_demonstrations

    (t0, q0), (t1, q1) = list(shipped_demonstrations().values())[:2]
    t = np.concatenate([t0 - t0[0], t1 - t1[0] + (t0[-1] - t0[0]) + 0.01])
    joints = ",".join(f"panda_joint{k}" for k in range(1, 8))
    lines = [",".join(map(repr, [a, *b])) for a, b in zip(t.tolist(), np.concatenate([q0, q1]).tolist())]
    (tmp_path / "jump.csv").write_text(f"t,{joints}\n" + "\n".join(lines) + "\n")
    return _validate_recorded_arm(
        tmp_path, monkeypatch, f"data.files=[{tmp_path / 'jump.csv'}]", "data.demo_column=null"
    )


def _three_shipped_takes(path: Path, takes: tuple[str, ...] = ("demo00", "demo01", "demo03")) -> Path:
    """Three of the Panda's shipped recordings, copied row by row into one CSV."""
    lines = (ROOT / "rmpfusion" / "recordings" / "files" / "panda_via_points.csv").read_text().splitlines()
    path.write_text("\n".join([lines[0], *(line for line in lines[1:] if line.split(",")[0] in takes)]) + "\n")
    return path


@row(
    "recorded-obstacle-entry",
    "a recording that passes through an obstacle of the run's world (the user's world is not the experiment's)",
    "rmpfusion-validate experiment=recorded_arm data.files=[<dir>/three.csv] data.val=1 data.test=1 "
    "'env.scene.obstacles=[{type: sphere, center: [0.379, 0.321, 0.59], radius: 0.03}]' (three shipped recordings; "
    "the ball where demo03's hand is 0.8 s in)",
    _ONE_LINE.format(code=2),
    shows="error: invalid configuration: 1 problem(s)\n  - data.obstacle_entries: 1 of 3 recordings enters an obstacle of the run's "
    "world (1 entry; measured by the robot's spheres, which contain its links' meshes, against the scene's distance "
    "maps; the simulator's closest points on the meshes confirm each entry): <dir>/three.csv [demo=demo03]: from "
    "<num> to <num> s, deepest at <num> s (file time <num> s): cp14 (control sphere on panda_hand) <num> m inside "
    "obstacle1 (sphere); the links' meshes <num> m deep by the simulator. Learning from them would teach the tree to "
    "pass through the obstacle. If your world is not the run's scene, state it in one line: env.scene.obstacles=[] "
    "(no obstacles) or scene=<your scene file> (docs/guides/scenes.md); or leave those recordings out "
    "(data.obstacle_entries=drop), or learn from them anyway (data.obstacle_entries=warn)",
)
def _obstacle_entry(tmp_path, monkeypatch):
    three = _three_shipped_takes(tmp_path / "three.csv")
    ball = "env.scene.obstacles=[{type: sphere, center: [0.379, 0.321, 0.59], radius: 0.03}]"
    return _validate_recorded_arm(tmp_path, monkeypatch, f"data.files=[{three}]", "data.val=1", "data.test=1", ball)


@row(
    "recorded-some-joints-named",
    "an arm's CSV naming some of the robot's joints but not all (a log of six of the seven joints, and the gripper)",
    "rmpfusion-validate experiment=recorded_arm data.files=[<dir>/six.csv] data.demo_column=null (t, "
    "panda_joint1 … panda_joint6, panda_finger_joint1)",
    _ONE_LINE.format(code=2),
    shows="error: invalid configuration: 1 problem(s)\n  - data: <dir>/six.csv, row 1: the header names some of the "
    "robot's joints but not panda_joint7; it has panda_joint1, panda_joint2, panda_joint3, panda_joint4, "
    "panda_joint5, panda_joint6, panda_finger_joint1. Name each joint's column as the robot file does "
    f"({_PANDA}), or list the columns to read, in the robot's joint order, in data.columns",
)
def _some_joints_named(tmp_path, monkeypatch):
    header = ",".join(["t", *(f"panda_joint{k}" for k in range(1, 7)), "panda_finger_joint1"])
    rows = [",".join([f"{0.01 * i:.2f}", *["0.1"] * 6, "0.04"]) for i in range(40)]
    (tmp_path / "six.csv").write_text("\n".join([header, *rows]) + "\n")
    return _validate_recorded_arm(
        tmp_path, monkeypatch, f"data.files=[{tmp_path / 'six.csv'}]", "data.demo_column=null"
    )


def _nan_weight_checkpoint(tmp_path) -> Path:
    """final.pt of a tiny run re-written (valid format and checksum) with one NaN in a weight network."""
    from rmpfusion.learn.checkpoints import save_checkpoint

    run = tiny_run(tmp_path)
    path = run / "checkpoints" / "rmp" / "final.pt"
    state = load_checkpoint(path)
    name = next(k for k, v in state["model"].items() if v.is_floating_point() and v.numel() > 1)
    state["model"][name] = state["model"][name].clone()
    state["model"][name].view(-1)[0] = float("nan")
    save_checkpoint({k: v for k, v in state.items() if k not in ("format", "sha256")}, path)
    return path


_NAN_CK = (
    "error: checkpoint file <dir>/run/checkpoints/rmp/final.pt holds non-finite weights (<text>: 1 of <num> "
    "entries): the training that wrote it diverged; use an earlier checkpoint in <dir>/run/checkpoints/rmp, or "
    "train again with a lower train.lr"
)


@row(
    "checkpoint-nan-weight-evaluate",
    "a non-finite weight in a valid checkpoint, evaluated",
    "rmpfusion-evaluate-checkpoint on a tiny run's final.pt re-saved (valid checksum) with one NaN weight",
    _ONE_LINE.format(code=2),
    shows=_NAN_CK,
)
def _nan_evaluate(tmp_path, monkeypatch):
    from rmpfusion.cli.from_checkpoint import main as evaluate_checkpoint_main

    path = _nan_weight_checkpoint(tmp_path)
    return said(lambda: evaluate_checkpoint_main([str(path), "--no-figures"]), code=2, monkeypatch=monkeypatch)


@row(
    "checkpoint-nan-weight-export",
    "a non-finite weight in a valid checkpoint, exported",
    "rmpfusion-export on the same checkpoint",
    _ONE_LINE.format(code=2),
    shows=_NAN_CK,
)
def _nan_export(tmp_path, monkeypatch):
    from rmpfusion.cli.export import main as export_main

    path = _nan_weight_checkpoint(tmp_path)
    msg = said(lambda: export_main([str(path)]), code=2, monkeypatch=monkeypatch)
    assert not list(path.parent.glob("*.pt2"))
    return msg


@row(
    "plugin-leaf-wrong-shape",
    "a plugin leaf returning a metric of the wrong shape",
    "rmpfusion-validate +tree.nodes.bad={parent: q, map: {type: identity}, rmp: {type: test_wrong_shape}} (M, G, B "
    "are 3 × 3 on a 2-D node)",
    "refused when the tree is built, naming the node and the leaf; exit status 2",
    shows="error: invalid configuration: 1 problem(s)\n  - tree.nodes.bad.rmp: the leaf 'test_wrong_shape' fails the "
    "leaf contract at sample states: it returns M of shape (16, 3, 3) on a 2-dimensional node, where it must be "
    "(16, 2, 2) for a batch of 16; a leaf must give symmetric positive semi-definite G and B and an M whose "
    "symmetric part is positive semi-definite, with f (B, d), M, G, B (B, d, d), Φ, L, V (B,) (docs/math.md §3), "
    "or the tree's q̈ = M⁺f and Theorem 2 do not hold; fix the leaf",
)
def _wrong_shape(tmp_path, monkeypatch):
    return said(
        _validate_main(),
        "+tree.nodes.bad={parent: q, map: {type: identity}, rmp: {type: test_wrong_shape}}",
        f"hydra.run.dir={tmp_path / 'v'}",
        code=2,
        monkeypatch=monkeypatch,
    )


@row(
    "plugin-leaf-negative-metric",
    "a plugin leaf whose metric is −I (it pushes away from the goal)",
    "rmpfusion-validate +tree.nodes.bad={parent: q, map: {type: offset, origin: goal}, rmp: {type: test_negative_metric}}",
    "refused when the tree is built (G symmetric PSD, B symmetric PSD, sym(M) PSD on sample states), naming the "
    "node and the leaf; exit status 2 (exit 0 before: q̈ pushed away from the goal)",
    shows="error: invalid configuration: 1 problem(s)\n  - tree.nodes.bad.rmp: the leaf 'test_negative_metric' fails "
    "the leaf contract at sample states: G has the negative eigenvalue -1, so it is not positive semi-definite; "
    "a leaf must give symmetric positive semi-definite G and B and an M whose symmetric part is positive "
    "semi-definite, with f (B, d), M, G, B (B, d, d), Φ, L, V (B,) (docs/math.md §3), or the tree's q̈ = M⁺f "
    "and Theorem 2 do not hold; fix the leaf",
)
def _negative_metric(tmp_path, monkeypatch):
    return said(
        _validate_main(),
        "+tree.nodes.bad={parent: q, map: {type: offset, origin: goal}, rmp: {type: test_negative_metric}}",
        f"hydra.run.dir={tmp_path / 'v'}",
        code=2,
        monkeypatch=monkeypatch,
    )


@row(
    "aux-wrong-batch",
    "aux state with the wrong batch size",
    "tree(q, qd, aux) with B = 4 states and aux['goal'] of 3 rows",
    "ValueError naming the aux entry, its shape and the shapes allowed",
    shows="aux 'goal' has shape (3, 2) but q holds 4 states; give it one row per state, (4, 2), or one row for them "
    "all, (1, 2)",
)
def _aux_batch(tmp_path, monkeypatch):
    tree = make_tree()
    q, qd, aux = states()
    aux["goal"] = aux["goal"][:3]
    return raised(ValueError, tree, q, qd, aux, match="aux 'goal'")


def _tool(name: str):
    import importlib.util

    spec = importlib.util.spec_from_file_location(name, ROOT / "tools" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@row(
    "compare-truncated-metrics",
    "rmpfusion-study compare on a truncated metrics.json",
    "rmpfusion-study compare <dir>/a.json <dir>/b.json, b.json cut in the middle",
    _ONE_LINE.format(code=2),
    shows="error: <dir>/b.json is not readable JSON (<text>): a run killed while writing it, or a damaged copy; rerun "
    "that run (it resumes and writes metrics.json again)",
)
def _compare_truncated(tmp_path, monkeypatch):
    text = '{"learners": {"rmp": {"online_loss": 0.5, "success": 1.0}}}'
    (tmp_path / "a.json").write_text(text)
    (tmp_path / "b.json").write_text(text[:30])
    from rmpfusion.cli import study

    return said(lambda: study.main(["compare", str(tmp_path / "a.json"), str(tmp_path / "b.json")]), code=2)


@row(
    "sweep-damaged-overrides",
    "tools/summarize_sweep.py with one job's .hydra/overrides.yaml damaged",
    "two finished jobs of a sweep, job 1's overrides.yaml cut inside a list",
    "a warning naming the file, the other job summarised; exit status 0",
    shows="warning: 1_x left out: <dir>/sweep/1_x/.hydra/overrides.yaml is damaged (ScannerError: <text>); the job's "
    "overrides are unknown; left out of the summary",
)
def _sweep_damaged(tmp_path, monkeypatch):
    import json

    for k in (0, 1):
        job = tmp_path / "sweep" / f"{k}_x"
        (job / ".hydra").mkdir(parents=True)
        (job / ".hydra" / "overrides.yaml").write_text(f"- seed={k}\n")
        (job / "metrics.json").write_text(json.dumps({"learners": {"rmp": {"online_loss": 0.1 * (k + 1)}}}))
    (tmp_path / "sweep" / "1_x" / ".hydra" / "overrides.yaml").write_text("- seed=1\n- 'train.lr=\n  : [\n")
    tool = _tool("summarize_sweep")
    code, out = cli(lambda: tool.main([str(tmp_path / "sweep")]))
    assert code == 0 and "Traceback" not in out and "| rmp | 1 | 0 |" in out.replace("  ", " "), out
    return next(ln for ln in out.splitlines() if ln.startswith("warning:"))


@row(
    "dt-tiny-hang",
    "an integration step so small no rollout would end (env.dt=1e-300)",
    "rmpfusion-validate env.dt=1e-300",
    "refused at validation naming env.dt, the control rate and the step count "
    "(before: validation passed and collection never ended); exit status 2",
    shows="error: invalid configuration: 1 problem(s)\n  - env.dt: a step of 1e-300 s (env.dt, a control rate of 1e+300 "
    "Hz) makes a rollout of 60 s (data.points × data.interval) take 6e+301 integration steps, more than the 1e+06 "
    "a run allows (it would never finish); use a step of at least 6e-05 s (given: 1e-300)",
)
def _dt_hang(tmp_path, monkeypatch):
    return said(_validate_main(), "env.dt=1e-300", f"hydra.run.dir={tmp_path / 'v'}", code=2, monkeypatch=monkeypatch)


@row(
    "starts-impossible",
    "a sampling region that cannot hold a start clear of the obstacles",
    "rmpfusion-run (tiny) experiment=2d1level with +env.clearance=4 (every start must be 4 m from the obstacle)",
    "one line naming the keys to change, no traceback, no metrics or checkpoints (before: a RuntimeError traceback "
    "inside Hydra's job); exit status 2",
    shows="error: particle2d: could not sample <num> environments in 1000 rounds (env.max_tries) with the goal "
    "env.clearance = 4.0 from every obstacle, the obstacles env.obstacle_gap = <num> apart and inside "
    "env.workspace; widen env.goal_region or env.obstacle_along/obstacle_across, or lower env.obstacle_radius, "
    "env.clearance or env.obstacle_gap",
)
def _starts_impossible(tmp_path, monkeypatch):
    msg = said(
        _run_main(), *TINY, "+env.clearance=4", f"hydra.run.dir={tmp_path / 'run'}", code=2, monkeypatch=monkeypatch
    )
    assert not (tmp_path / "run" / "metrics.json").exists() and not (tmp_path / "run" / "checkpoints").exists()
    return msg


@row(
    "expert-diverges",
    "an expert whose rollouts diverge (tree.nodes.goal.rmp.gain=1e6 env.dt=0.1)",
    "rmpfusion-run (tiny) tree.nodes.goal.rmp.gain=1e6 env.dt=0.1",
    "the run stops after collecting, before training, stating the tolerance (before: exit 0 and normal-looking "
    "metrics); exit status 1",
    shows="error: the expert diverged on 4 of 4 train demonstrations (trajectories [0, 1, 2, 3]): the state grew to "
    "<num> × (1 + its start) (tolerance 100 ×); nothing it demonstrates could be learned, so the run stops. Lower "
    "the tree's gains (tree.nodes.<leaf>.rmp.gain) or the step (env.dt, or a higher env.control_rate), and check "
    "the expert alone with a short run (data=tiny train=tiny eval=fast)",
)
def _expert_diverges(tmp_path, monkeypatch):
    msg = said(
        _run_main(),
        *TINY,
        "tree.nodes.goal.rmp.gain=1e6",
        "env.dt=0.1",
        f"hydra.run.dir={tmp_path / 'run'}",
        code=1,
        monkeypatch=monkeypatch,
    )
    assert not (tmp_path / "run" / "checkpoints").exists() and not (tmp_path / "run" / "metrics.json").exists()
    return msg


@row(
    "expert-lyapunov-rises",
    "an expert whose V_r rises where Theorem 2 applies",
    "divergence() of a particle2d rollout of a tree whose V_r is made to rise by 50 % (moving=False)",
    "diverged, stating the tolerance; the same rollout with obstacles that moved (Theorem 2 does not apply) is not",
    shows="V_r rose by 0.5 of its largest value where Theorem 2 says it never rises (tolerance 0.1)",
)
def _lyapunov_rises(tmp_path, monkeypatch):
    from rmpfusion.evaluate.divergence import divergence

    T, B = 5, 2
    q, qd = torch.zeros(T, B, 2, dtype=F64), torch.zeros(T, B, 2, dtype=F64)
    V = torch.tensor(
        [[2.0, 2.0], [1.5, 1.5], [1.0, 1.0], [2.0, 1.0], [0.5, 0.5]], dtype=F64
    )  # sample 0 rises by 1 of 2
    assert divergence(q, qd, V, theorem2_applies=False) is None
    found = divergence(q, qd, V, theorem2_applies=True)
    assert found is not None and found.samples == [0]
    return found.reason


@row(
    "learner-diverges",
    "a trained learner whose test rollouts diverge",
    "flag_divergence on a learner's particle2d rollouts from q̈ = 50 q (it runs away from the origin)",
    "kept and evaluated, but a WARNING line in the console and `diverged` in its metrics.json entry",
    shows="WARNING: learner rmp DIVERGED on 2 of 2 test rollouts: the state grew to <num> × (1 + its start) "
    "(tolerance 100 ×); its metrics describe a policy that does not work (metrics.json: learners.rmp.diverged)",
)
def _learner_diverges(tmp_path, monkeypatch):
    from types import SimpleNamespace

    from rmpfusion.envs.particle2d import Particle2D
    from rmpfusion.pipeline.evaluation import LearnerEval, flag_divergence

    env = Particle2D()
    q0, qd0, aux = env.sample(1, 2, seed=0)
    with torch.no_grad():
        ro = env.rollout(lambda q, qd, a: 50.0 * q, q0, qd0, aux, horizon=1.0, record_every=0.1)
    lines: list[str] = []
    out = LearnerEval(final={}, final_rollout=ro)
    flag_divergence(SimpleNamespace(say=SimpleNamespace(say=lines.append)), "rmp", out)
    assert out.final["diverged"]["trajectories"] == 2 and out.final["diverged"]["growth_limit"] == 100.0
    return lines[0]


@row(
    "training-overflow",
    "a learning rate that makes the parameters overflow (train.lr=1e300)",
    "rmpfusion-run (tiny) train.lr=1e300",
    "training stops naming the iteration and the parameter (before: "
    "parameters reached 1e301 and ordinary metrics were reported); exit status 1",
    shows="error: training diverged at iteration 1: parameter <text> holds <num> (<num> of its <num> entries are "
    "non-finite or beyond 1e+15), so nothing it computes means anything; lower train.lr (now 1e+300) or set "
    "train.grad_clip, and run again in a new run directory",
)
def _overflow(tmp_path, monkeypatch):
    return said(
        _run_main(), *TINY, "train.lr=1e300", f"hydra.run.dir={tmp_path / 'run'}", code=1, monkeypatch=monkeypatch
    )


@row(
    "batch-size-capped",
    "a batch size above the dataset's size (train.batch_size=200000000)",
    "behavior cloning of TinyLearner on a 40-point dataset with batch_size=200000000",
    "trains on the whole dataset each step and says it is capped (before: not a word)",
    shows="train.batch_size=200000000 is more than the 40 training points: every step draws 40 (capped at the "
    "dataset's size)",
)
def _batch_capped(tmp_path, monkeypatch):
    from rmpfusion.learn.config import BCParams
    from rmpfusion.learn.method import MethodContext
    from rmpfusion.learn.methods.bc import MinibatchSteps

    told: list[str] = []
    model = TinyLearner()
    params = BCParams(iterations=1, batch_size=200000000, snapshots=[0, 1], checkpoint_every=1, log_every=1)
    ctx = MethodContext(data={"train": tiny_dataset()}, seed=0, say=told.append)
    MinibatchSteps(model, params, ctx, torch.optim.SGD(model.parameters(), lr=1e-3), torch.Generator()).step(0)
    return told[0]


@row(
    "conf-env-nowhere",
    "RMPFUSION_CONF pointing at a directory that does not exist",
    "RMPFUSION_CONF=<dir>/nonexistent rmpfusion-validate",
    "an error naming the variable (before: silently ignored, the checkout's conf/ used); exit status 2",
    shows="error: RMPFUSION_CONF=<dir>/nonexistent does not exist; point it at a conf/ directory (one with "
    "config.yaml, like the checkout's conf/) or unset it to use the checkout's",
)
def _conf_nowhere(tmp_path, monkeypatch):
    monkeypatch.setenv("RMPFUSION_CONF", str(tmp_path / "nonexistent"))
    return said(_validate_main(), code=2, monkeypatch=monkeypatch)


@row(
    "sweep-empty",
    "a sweep over no values",
    "rmpfusion-run -m 'seed=range(0,0)'",
    'refused before Hydra starts (before: "Launching 0 jobs" and exit 0); exit status 2',
    shows="error: 'seed=range(0,0)' sweeps over no value, so the sweep would launch no job; give it at least one "
    "(range(0,3) is 0, 1, 2: the end is left out)",
)
def _sweep_empty(tmp_path, monkeypatch):
    return said(
        _run_main(), "-m", "seed=range(0,0)", f"hydra.sweep.dir={tmp_path / 'sweep'}", code=2, monkeypatch=monkeypatch
    )


@row(
    "sweep-one-invalid-job",
    "one invalid job in a sweep",
    "rmpfusion-run -m (tiny) 'train.lr=1e-3,-1,3e-3'",
    "the invalid job fails alone (its number and overrides named) and leaves no directory, the other two run, the "
    "sweep lists it at the end; exit status 1",
    shows="error: invalid configuration: 1 problem(s)\n  - train.lr: Input should be greater than 0 (given: -1)\n"
    "job 1 (train.lr=-1 data=tiny train=tiny eval=fast logger=disabled) failed with exit status 2; the sweep goes "
    "on with its other jobs\nerror: 1 job of the sweep failed (job 1 (train.lr=-1 data=tiny train=tiny eval=fast "
    "logger=disabled): exit status 2); each said why above. The others ran; fix the failed jobs' overrides and "
    "run them again",
)
def _sweep_invalid_job(tmp_path, monkeypatch):
    sweep = tmp_path / "sweep"
    msg = said(
        _run_main(), "-m", "train.lr=1e-3,-1,3e-3", *TINY, f"hydra.sweep.dir={sweep}", code=1, monkeypatch=monkeypatch
    )
    jobs = sorted(p.name for p in sweep.iterdir() if p.is_dir())
    assert [j.split("_")[0] for j in jobs] == ["0", "2"], jobs  # no directory of the failed job
    assert all((sweep / j / "metrics.json").is_file() for j in jobs)
    return "\n".join(
        ln
        for ln in msg.splitlines()
        if not ln.startswith(
            ("[", "data:", "eval", "expert", "learner", "train.", "done", "result", "collect", "rollout", "train ")
        )
    )


@row(
    "validate-leaves-nothing",
    "rmpfusion-validate leaving a run directory each time",
    "rmpfusion-validate hydra.run.dir=<dir>/run",
    "nothing was run, so nothing is left (before: a directory with Hydra's files each time); exit status 0",
    shows="<dir>/run exists: False",
)
def _validate_nothing(tmp_path, monkeypatch):
    code, out = cli(_validate_main(), f"hydra.run.dir={tmp_path / 'run'}")
    assert code == 0 and "OK: the configuration is valid" in out, out
    return f"<dir>/run exists: {(tmp_path / 'run').exists()}"


@row(
    "export-truncated-final",
    "rmpfusion-export on a truncated final.pt",
    "rmpfusion-export <dir>/run/checkpoints/rmp/final.pt cut after 3000 bytes",
    _ONE_LINE.format(code=2),
    shows="error: checkpoint file <dir>/run/checkpoints/rmp/final.pt is unreadable or truncated (RuntimeError: "
    "PytorchStreamReader <text>); delete <dir>/run/checkpoints/rmp/final.pt (training then resumes from the "
    "previous checkpoint in <dir>/run/checkpoints/rmp if there is one, else starts over)",
)
def _export_truncated(tmp_path, monkeypatch):
    from rmpfusion.cli.export import main as export_main

    path = tiny_run(tmp_path) / "checkpoints" / "rmp" / "final.pt"
    path.write_bytes(path.read_bytes()[:3000])
    return said(lambda: export_main([str(path)]), code=2, monkeypatch=monkeypatch)


class _Hostile:
    def __reduce__(self):
        import os

        return (os.system, ("echo hostile-pickle-ran > hostile.txt",))


@row(
    "export-hostile-pickle",
    "a hostile pickle in place of a checkpoint",
    "rmpfusion-export ckpt-00000003.pt holding a pickled os.system call",
    "names the refused object (not torch's weights_only advice); nothing runs; exit status 2",
    shows="error: checkpoint file <dir>/run/checkpoints/rmp/ckpt-00000003.pt is damaged or was not written by "
    "rmpfusion: it asks for the Python object <text>.system, which no file of rmpfusion holds (nothing in it was "
    "loaded or run); delete <dir>/run/checkpoints/rmp/ckpt-00000003.pt (training then resumes from the previous "
    "checkpoint in <dir>/run/checkpoints/rmp if there is one, else starts over)",
)
def _hostile(tmp_path, monkeypatch):
    from rmpfusion.cli.export import main as export_main

    path = tiny_run(tmp_path) / "checkpoints" / "rmp" / "ckpt-00000003.pt"
    torch.save({"format": "rmpfusion-checkpoint/1", "model": _Hostile()}, path)
    monkeypatch.chdir(tmp_path)
    msg = said(lambda: export_main([str(path)]), code=2, monkeypatch=monkeypatch)
    assert "weights_only" not in msg and not (tmp_path / "hostile.txt").exists()
    return msg


@row(
    "export-quiet",
    "a successful export printing torch's '.pt2 … Unable to load package' line",
    "rmpfusion-export <dir>/run/checkpoints/rmp/final.pt",
    "only the file written; exit status 0",
    shows="wrote <dir>/run/checkpoints/rmp/rmp-final.pt2",
)
def _export_quiet(tmp_path, monkeypatch):
    import logging

    from rmpfusion.cli.export import main as export_main

    path = tiny_run(tmp_path) / "checkpoints" / "rmp" / "final.pt"
    logged: list[str] = []
    keep = logging.Handler()
    keep.emit = lambda record: logged.append(record.getMessage())  # torch warns through its loggers, not warnings
    logging.getLogger("torch.export.pt2_archive._package").addHandler(keep)
    try:
        code, out = cli(lambda: export_main([str(path)]))
    finally:
        logging.getLogger("torch.export.pt2_archive._package").removeHandler(keep)
    assert code == 0 and not [m for m in logged if ".pt2" in m], logged
    return out.strip()


@row(
    "cli-argparse-habit",
    "a setting written as an option (--experiment 2d1level)",
    "rmpfusion-validate --experiment 2d1level",
    _SAID,
    shows="error: '--experiment 2d1level' is not an option of rmpfusion's commands: settings are written "
    "key=value (Hydra's overrides); write experiment=2d1level",
)
def _argparse_habit(tmp_path, monkeypatch):
    return command_line_message("--experiment", "2d1level")


@row(
    "cli-habitual-key",
    "another library's name for a key (train.learning_rate)",
    "rmpfusion-run train.learning_rate=0.01",
    _SAID,
    shows="error: 'train.learning_rate': train has no key 'learning_rate'; did you mean 'train.lr', "
    "'train.lr_final_fraction'? keys of train: method, optimizer, lr, lr_schedule, lr_final_fraction, "
    "batch_size, iterations, snapshots, checkpoint_every, log_every, dtype, grad_clip, compile (to add a "
    "new key on purpose write +train.learning_rate=...)",
)
def _habitual_key(tmp_path, monkeypatch):
    return command_line_message("train.learning_rate=0.01")


@row(
    "cli-block-merged-into-another",
    "a block of another kind given where the config has one (tree.obstacle_weight={type: constant})",
    "rmpfusion-run experiment=recorded_arm 'tree.obstacle_weight={type: constant}'",
    _SAID,
    shows="error: 'tree.obstacle_weight': a block given on the command line is merged into the config's "
    "tree.obstacle_weight, which has no key 'type'; to replace the whole block write ~tree.obstacle_weight "
    "'+tree.obstacle_weight={...}' (or give the key on its own: +tree.obstacle_weight.type=...)",
)
def _block_merged(tmp_path, monkeypatch):
    return command_line_message("experiment=recorded_arm", "tree.obstacle_weight={type: constant}")


@row(
    "config-device-gpu",
    "device=gpu",
    "resolve_and_validate on conf/config.yaml with device=gpu",
    _REFUSED,
    shows="device: 'gpu' is not a device torch knows; did you mean 'cuda'? (devices: cpu, cuda, cuda:<index>)",
)
def _device_gpu(tmp_path, monkeypatch):
    return validation_issue(["device=gpu"])


@row(
    "pkg-url-imports-nothing",
    "a pkg:// URDF whose package part is a module with code (pkg://this.x/model.urdf)",
    "resolve_and_validate with experiment=franka env.robot.urdf=pkg://this.x/model.urdf",
    "refused without importing anything (before: the module `this` was imported and its top-level code ran)",
    needs=("pybullet",),
    shows="env.robot: urdf: URDF 'pkg://this.x/model.urdf': no installed Python package 'this.x' to look in; write "
    "pkg://<package>/<path inside it> for a package that is installed, or a file path; fix urdf: in the robot's "
    "file (conf/robot/<name>.yaml or env.robot.urdf=...) to name a URDF that exists (a path from the working "
    "directory, or pkg://<package>/<path>) (given: <text>)",
)
def _pkg_imports_nothing(tmp_path, monkeypatch):
    monkeypatch.delitem(sys.modules, "this", raising=False)
    msg = validation_issue(["experiment=franka", "env.robot.urdf=pkg://this.x/model.urdf"])
    assert "this" not in sys.modules
    return msg


@row(
    "result-line-last",
    "the run's result buried under the logger's summary",
    "rmpfusion-run (tiny), its last line",
    "the result line is printed last, after everything else",
    shows="result: learner rmp: online_loss=<num>, batch_loss=<num>, success=<num>, collision=<num> "
    "(<dir>/run/metrics.json)",
)
def _result_last(tmp_path, monkeypatch):
    run = tiny_run(tmp_path)
    code, out = cli(_run_main(), *TINY, f"hydra.run.dir={run}")
    assert code == 0, out[-3000:]
    return out.strip().splitlines()[-1]


@row(
    "compile-silent",
    "minutes of silence while the first call compiles",
    "prepare() of a run with eval.compile=true (torch.compile itself replaced by a no-op)",
    "a line saying what compiles and that it is cached afterwards",
    shows="compiling the expert's tree with torch.compile (first call, cached afterwards: it can take minutes; "
    "eval.compile=false or train.compile=false skip it)",
)
def _compile_said(tmp_path, monkeypatch):
    import contextlib
    import io

    from rmpfusion.core.tree import RMPTree
    from rmpfusion.pipeline.compose import compose_run
    from rmpfusion.pipeline.experiment import prepare
    from rmpfusion.pipeline.progress import Progress

    monkeypatch.setattr(RMPTree, "compile", lambda self, *a, **k: self)
    run = compose_run(["data=tiny", "eval.compile=true"], conf=CONF)
    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(out):
        prepare(run, tmp_path, Progress(True))
    return next(ln for ln in out.getvalue().splitlines() if ln.startswith("compiling"))


@row(
    "install-license-warning",
    "setuptools' deprecation warning about project.license on every install",
    "setuptools applies pyproject.toml to a distribution (what pip install does)",
    "no warning",
    shows="warnings about the license: []",
)
def _license_quiet(tmp_path, monkeypatch):
    from setuptools.config.pyprojecttoml import apply_configuration
    from setuptools.dist import Distribution

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        apply_configuration(Distribution(), ROOT / "pyproject.toml")
    return f"warnings about the license: {[str(w.message)[:80] for w in caught if 'license' in str(w.message).lower()]}"


# ------------------------------------------------------------------------------------------------ the tests
# Last in the file: the parametrisation takes the rows defined above it.
MESSAGES: dict[str, str] = {}


def _normalise(msg: str, tmp_path: Path) -> str:
    return str(msg).replace(str(tmp_path), "<dir>")


def _param(r: Row):
    marks = [pytest.mark.xfail(strict=True, reason=f"known gap: {r.gap}")] if r.gap else []
    return pytest.param(r, id=r.id, marks=marks)


@pytest.mark.parametrize("r", [_param(r) for r in ROWS])
def test_fault_table(r: Row, tmp_path, monkeypatch):
    for mod in r.needs:
        pytest.importorskip(mod)
    msg = _normalise(r.run(tmp_path, monkeypatch), tmp_path)
    check_shows(r, msg)
    MESSAGES[r.id] = msg


def markdown_table(messages: dict[str, str]) -> str:
    esc = lambda s: s.replace("|", "\\|").replace("\n", " ")
    lines = [
        "| Bad input or fault | How it is triggered | What happens | What the user sees |",
        "| --- | --- | --- | --- |",
    ]
    for r in ROWS:
        seen = f"known gap: {r.gap}" if r.gap else f"`{esc(messages.get(r.id, '(not run)'))}`"
        lines.append(f"| {esc(r.fault)} | {esc(r.trigger)} | {esc(r.expect)} | {seen} |")
    return "\n".join(lines)


def test_the_documentation_lists_every_row():
    page, section = section_of("# When things go wrong")
    missing = [r.id for r in ROWS if f"| {r.fault.replace('|', chr(92) + '|')} |" not in section]
    assert not missing, (
        f"{page}'s table lacks rows {missing}; regenerate it with PYTHONPATH=. python tests/test_robustness.py"
    )


def test_table_rows_are_unique_and_described():
    ids = [r.id for r in ROWS]
    assert len(ids) == len(set(ids))
    assert all(r.fault and r.trigger and r.expect and r.shows for r in ROWS)


def main() -> None:
    """Run every row outside pytest and print the markdown table (messages as a user sees them)."""
    import tempfile

    torch.set_default_dtype(F64)
    register_components()
    messages = {}
    for r in ROWS:
        with tempfile.TemporaryDirectory() as d, pytest.MonkeyPatch.context() as mp, warnings.catch_warnings():
            warnings.simplefilter("ignore")
            try:
                messages[r.id] = _normalise(r.run(Path(d), mp), Path(d))
            except pytest.skip.Exception as e:  # a row this machine cannot run (a tmpfs it cannot mount)
                messages[r.id] = f"skipped here: {e}"
            except Exception as e:  # noqa: BLE001 - a gap row, or a row that fails: show it
                messages[r.id] = f"FAILED: {type(e).__name__}: {e}"
    print(markdown_table(messages))


if __name__ == "__main__":  # PYTHONPATH=. python tests/test_robustness.py: rmpfusion's tools/ import from the root
    main()
