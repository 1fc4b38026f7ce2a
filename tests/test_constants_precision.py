"""A spec's numbers keep their float64 value: centres, radii, goals, gains, limits and designed-weight parameters
are built in float64 whatever torch's default dtype is, and the tree is then cast to its own dtype once.

conftest.py makes float64 torch's default for the whole suite, which would hide constants built at the default
dtype; these tests build their trees under torch's out-of-the-box default, float32, as a user's script does.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import rmpflow_reference as ref
import torch

import rmpfusion


@pytest.fixture
def default_float32():
    """torch's own default dtype (float32) while the test builds its trees, as outside this test suite."""
    old = torch.get_default_dtype()
    torch.set_default_dtype(torch.float32)
    yield
    torch.set_default_dtype(old)


def _inexact32(*values: float) -> None:
    """The test is only meaningful for numbers float32 cannot hold."""
    for v in values:
        assert float(np.float32(v)) != v, v


def _rel(out: torch.Tensor, expect: np.ndarray) -> float:
    return float(np.abs(out.detach().numpy() - expect).max() / max(np.abs(expect).max(), 1e-300))


# --------------------------------------------------------------------------- against RMPflow's reference
def test_issue_example_matches_rmpflow_to_rounding(default_float32):
    """The tree of the report (centre [0.3, −1.7], radius 0.7, goal [2.1, 1.3], RMPflow leaves with defaults):
    with float32-rounded constants q̈ was off by 4e-7 relative; in float64 it is RMPflow's to rounding."""
    spec = {
        "root": {"name": "q", "dim": 2},
        "nodes": {
            "obstacle": {
                "parent": "q",
                "map": {"type": "sphere_distance", "center": [0.3, -1.7], "radius": 0.7, "normalized": True},
                "rmp": {"type": "rmpflow_collision_avoidance"},
            },
            "goal": {
                "parent": "q",
                "map": {"type": "offset", "origin": [2.1, 1.3]},
                "rmp": {"type": "rmpflow_goal_attractor"},
            },
        },
    }
    tree = rmpfusion.build_tree(spec)
    q, qd = np.array([0.3, -0.85]), np.array([0.2, -0.5])
    out = tree(torch.from_numpy(q)[None], torch.from_numpy(qd)[None])
    children = [
        (ref.sphere_map(np.array([0.3, -1.7]), 0.7), ref.collision_avoidance),
        (ref.offset_map(np.array([2.1, 1.3])), ref.goal_attractor),
    ]
    a, f, M = ref.rmpflow_root(q, qd, children)
    np.testing.assert_allclose(a, [0.29787391, 1.94333152], atol=5e-9)  # the reference's value quoted in the report
    assert _rel(out.qdd[0], a) <= 1e-12
    assert _rel(out.f[0], f) <= 1e-12 and _rel(out.M[0], M) <= 1e-12


def _random_rmpflow_tree(seed: int, n_obstacles: int = 2):
    """A depth-1 tree of RMPflow leaves with random constants (spec, reference children, obstacles)."""
    rng = np.random.default_rng(seed)
    nodes, children, obstacles = {}, [], []
    for k in range(n_obstacles):
        c, R = rng.uniform(-2, 2, 2), float(rng.uniform(0.3, 1.2))
        eps, alpha, eta = float(rng.uniform(0.1, 0.5)), float(rng.uniform(1e-6, 1e-4)), float(rng.uniform(0.05, 1.0))
        _inexact32(*c, R, eps, alpha, eta)
        nodes[f"o{k}"] = {
            "parent": "q",
            "map": {"type": "sphere_distance", "center": c.tolist(), "radius": R, "normalized": True},
            "rmp": {"type": "rmpflow_collision_avoidance", "epsilon": eps, "alpha": alpha, "eta": eta},
        }
        children.append(
            (ref.sphere_map(c, R), lambda x, xd, e=eps, a=alpha, n=eta: ref.collision_avoidance(x, xd, e, a, n))
        )
        obstacles.append((c, R))
    g = rng.uniform(-3, 3, 2)
    gp = {
        "w_u": float(rng.uniform(2, 12)),
        "w_l": float(rng.uniform(0.3, 1.5)),
        "sigma": float(rng.uniform(0.4, 2.0)),
        "alpha": float(rng.uniform(0.5, 3.0)),
        "eta": float(rng.uniform(0.5, 3.0)),
        "gain": float(rng.uniform(0.3, 3.0)),
        "tol": float(rng.uniform(1e-3, 1e-2)),
    }
    _inexact32(*g, *gp.values())
    nodes["goal"] = {
        "parent": "q",
        "map": {"type": "offset", "origin": g.tolist()},
        "rmp": {"type": "rmpflow_goal_attractor", **gp},
    }
    children.append((ref.offset_map(g), lambda x, xd: ref.goal_attractor(x, xd, **gp)))
    dp = {"w": float(rng.uniform(0.05, 0.5)), "eta": float(rng.uniform(0.3, 2.0))}
    _inexact32(*dp.values())
    nodes["damper"] = {"parent": "q", "map": {"type": "identity"}, "rmp": {"type": "rmpflow_damper", **dp}}
    children.append((ref.offset_map(np.zeros(2)), lambda x, xd: ref.damper(x, xd, **dp)))
    return {"root": {"name": "q", "dim": 2}, "nodes": nodes}, children, obstacles


def _states(seed: int, obstacles, n: int = 16):
    """States at normalised distance ≥ 0.3 from every obstacle (the leaves' ordinary regime)."""
    rng = np.random.default_rng(1000 + seed)
    qs = []
    while len(qs) < n:
        q = rng.uniform(-3, 3, 2)
        if all(np.linalg.norm(q - c) / R - 1 >= 0.3 for c, R in obstacles):
            qs.append(q)
    return np.array(qs), rng.normal(size=(n, 2))


@pytest.mark.parametrize("seed", [0, 1, 2, 3, 4])
def test_random_constants_match_rmpflow_to_rounding(seed, default_float32):
    spec, children, obstacles = _random_rmpflow_tree(seed)
    tree = rmpfusion.build_tree(spec)
    q, qd = _states(seed, obstacles)
    out = tree(torch.from_numpy(q), torch.from_numpy(qd))
    worst = 0.0
    for b in range(len(q)):
        a, f, M = ref.rmpflow_root(q[b], qd[b], children)
        worst = max(worst, _rel(out.qdd[b], a), _rel(out.f[b], f), _rel(out.M[b], M))
    assert worst <= 1e-12, f"max relative difference to RMPflow {worst:.2e}"


@pytest.mark.parametrize("seed", [0, 1])
def test_float32_trees_still_work(seed, default_float32):
    """Built in float32 (or cast there) the same tree runs in float32, agrees with RMPflow to float32 precision,
    and its constants are the float32 roundings of the spec's numbers (rounded once, from float64)."""
    spec, children, obstacles = _random_rmpflow_tree(seed)
    t32 = rmpfusion.build_tree(spec, dtype=torch.float32)
    cast = rmpfusion.build_tree(spec).to(torch.float32)
    default = rmpfusion.build_tree(spec, dtype=None)  # None: torch's current default, float32 here
    for t in (t32, cast, default):
        assert {v.dtype for v in t.state_dict().values() if v.is_floating_point()} == {torch.float32}
    for k, v in t32.state_dict().items():
        assert torch.equal(v, cast.state_dict()[k]) and torch.equal(v, default.state_dict()[k]), k
    c = spec["nodes"]["o0"]["map"]["center"]
    assert t32.maps["o0"].center.const.tolist() == [float(np.float32(x)) for x in c]
    q, qd = _states(seed, obstacles)
    out = t32(torch.from_numpy(q).float(), torch.from_numpy(qd).float())
    assert out.qdd.dtype == torch.float32
    for b in range(len(q)):
        a, _, _ = ref.rmpflow_root(q[b], qd[b], children)
        assert _rel(out.qdd[b].double(), a) < 1e-4


# --------------------------------------------------------------------------- every constant stored exactly
EXACT_SPEC = {
    "root": {"name": "q", "dim": 3},
    "aux": {"goal": 3},
    "nodes": {
        "sphere": {
            "parent": "q",
            "map": {"type": "sphere_distance", "center": [0.3, -1.7, 0.1], "radius": 0.7},
            "weight": {
                "type": "rbf",
                "center": [0.3, -1.7, 0.1],
                "radius": 0.7,
                "sigma": 0.35,
                "low": 0.1,
                "high": 2.3,
            },
            "rmp": {"type": "collision_avoidance", "r_w": 0.9, "sigma": 0.3, "epsilon": 0.15, "alpha": 1.1e-5},
        },
        "cylinder": {
            "parent": "q",
            "map": {"type": "cylinder_distance", "center": [0.7, 0.2, -0.3], "radius": 0.45, "axis": [0.3, 0.4, 1.1]},
            "weight": {
                "type": "logistic",
                "center": [0.7, 0.2, -0.3],
                "radius": 0.45,
                "low": 0.3,
                "high": 1.7,
                "steepness": -3.3,
                "switch_distance": 0.1,
            },
            "rmp": {"type": "rmpflow_collision_avoidance", "epsilon": 0.3, "alpha": 1.3e-5, "eta": 0.1},
        },
        "box": {
            "parent": "q",
            "map": {"type": "box_distance", "center": [-1.1, 0.9, 0.3], "half_extents": [0.2, 0.3, 0.7]},
            "weight": {"type": "constant", "value": 0.3},
            "rmp": {"type": "collision_avoidance"},
        },
        "goal": {
            "parent": "q",
            "map": {"type": "offset", "origin": "goal"},
            "weight": {"type": "mlp", "hidden": [8], "init_bias": 0.7, "floor": 0.01, "aux": ["goal"]},
            "rmp": {"type": "goal_attractor", "gain": 1.3, "alpha": 0.9, "sigma": 0.6},
        },
        "home": {
            "parent": "q",
            "map": {"type": "offset", "origin": [2.1, 1.3, -0.9]},
            "rmp": {"type": "rmpflow_goal_attractor"},
        },
        "plane": {
            "parent": "q",
            "map": {"type": "linear", "matrix": [[0.1, 0.2, 0.3], [-0.7, 0.0, 1.9]], "bias": [0.3, -0.6]},
            "rmp": {"type": "damper", "w": 0.1, "eta": 1.3},
        },
        "shifted": {
            "parent": "q",
            "map": {
                "type": "compose",
                "maps": [{"type": "select", "indices": [2, 0]}, {"type": "offset", "origin": [0.1, 0.7]}],
            },
            "rmp": {"type": "rmpflow_damper", "w": 0.3, "eta": 0.7},
        },
        "limit": {
            "parent": "q",
            "map": {"type": "joint_limit", "side": "upper", "limit": 1.1, "joints": 1},
            "rmp": {"type": "joint_limit"},
        },
        "lower": {
            "parent": "q",
            "map": {"type": "joint_limit", "side": "lower", "limit": [-0.3, -2.9], "joints": [0, 2]},
            "rmp": {"type": "identity_metric", "scale": 0.03},
        },
    },
}

#: state_dict key -> the spec's numbers, which the float64 tree must hold exactly
EXACT_BUFFERS = {
    "maps.sphere.center.const": [0.3, -1.7, 0.1],
    "maps.sphere.radius.const": [0.7],
    "weights.sphere.fn.center.const": [0.3, -1.7, 0.1],
    "weights.sphere.fn.radius.const": [0.7],
    "maps.cylinder.center.const": [0.7, 0.2, -0.3],
    "maps.cylinder.radius.const": [0.45],
    "weights.cylinder.fn.center.const": [0.7, 0.2, -0.3],
    "weights.cylinder.fn.radius.const": [0.45],
    "maps.box.center.const": [-1.1, 0.9, 0.3],
    "maps.box.half_extents.const": [0.2, 0.3, 0.7],
    "maps.home.origin.const": [2.1, 1.3, -0.9],
    "maps.plane.A": [[0.1, 0.2, 0.3], [-0.7, 0.0, 1.9]],
    "maps.plane.b": [0.3, -0.6],
    "maps.shifted.stages.0.A": [[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]],
    "maps.shifted.stages.0.b": [0.0, 0.0],
    "maps.shifted.stages.1.origin.const": [0.1, 0.7],
    "maps.limit.limit": [1.1],
    "maps.limit.S": [[0.0, -1.0, 0.0]],
    "maps.lower.limit": [-0.3, -2.9],
    "maps.lower.S": [[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]],
    "weights.goal.fn.layers.1.bias": [math.log(math.expm1(0.7 - 0.01))],
    "weights.goal.fn.layers.1.weight": [[0.0] * 8],
}


def test_every_constant_is_stored_exactly_in_float64(default_float32):
    tree = rmpfusion.build_tree(EXACT_SPEC)
    sd = tree.state_dict()
    floating = {k: v for k, v in sd.items() if v.is_floating_point()}
    assert {v.dtype for v in floating.values()} == {torch.float64}, {k: v.dtype for k, v in floating.items()}
    for key, value in EXACT_BUFFERS.items():
        assert sd[key].tolist() == value, (key, sd[key].tolist(), value)
    a = np.array([0.3, 0.4, 1.1]) / np.linalg.norm([0.3, 0.4, 1.1])
    np.testing.assert_allclose(sd["maps.cylinder.P"].numpy(), np.eye(3) - np.outer(a, a), rtol=0, atol=1e-15)
    # the keys above are every constant buffer of the tree: a new one must be added to the table
    constants = {k for k in floating if not k.startswith("weights.goal.fn.layers.")}
    assert constants - set(EXACT_BUFFERS) == {"maps.cylinder.P"}
    # scalars kept as Python numbers are exact by nature; they meet float64 tensors as float64
    assert tree.rmps["sphere"].alpha == 1.1e-5 and tree.weights["cylinder"].fn.k == -3.3
    _inexact32(0.3, -1.7, 0.1, 0.7, 0.45, 2.1, 1.3, 0.9, 1.1, 2.9, 1.9, math.log(math.expm1(0.69)))


def test_constant_helper_is_exact_whatever_the_default_dtype(default_float32):
    from rmpfusion.core.auxstate import constant  # what registered classes (plugins too) build constants with

    t = constant([[0.1, 0.2], [0.3, 1.7]])
    assert t.dtype == torch.float64 and t.tolist() == [[0.1, 0.2], [0.3, 1.7]]


def test_mlp_initialisation_does_not_depend_on_the_default_dtype(default_float32):
    """One seed gives one network: its initial weights are drawn in float64 under any default dtype."""
    torch.manual_seed(7)
    under32 = rmpfusion.build_tree(EXACT_SPEC).state_dict()
    torch.set_default_dtype(torch.float64)
    torch.manual_seed(7)
    under64 = rmpfusion.build_tree(EXACT_SPEC).state_dict()
    for k, v in under64.items():
        assert torch.equal(v, under32[k]), k


def test_aux_given_as_python_numbers_keeps_float64(default_float32):
    spec = {
        "root": {"name": "q", "dim": 2},
        "aux": {"goal": 2},
        "nodes": {
            "goal": {
                "parent": "q",
                "map": {"type": "offset", "origin": "goal"},
                "rmp": {"type": "rmpflow_goal_attractor"},
            },
            "damp": {"parent": "q", "map": {"type": "identity"}, "rmp": {"type": "rmpflow_damper"}},
        },
    }
    tree = rmpfusion.build_tree(spec)
    q, qd = torch.tensor([[0.3, -0.85]], dtype=torch.float64), torch.tensor([[0.2, -0.5]], dtype=torch.float64)
    as_list = tree(q, qd, {"goal": [2.1, 1.3]}).qdd
    as_tensor = tree(q, qd, {"goal": torch.tensor([[2.1, 1.3]], dtype=torch.float64)}).qdd
    assert as_list.dtype == torch.float64 and torch.equal(as_list, as_tensor)
