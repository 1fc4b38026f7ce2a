"""Every registered task map, leaf RMP and weight function against finite differences, driven by the registries.

The tests are parametrized over the registries' contents at collection time: rmpfusion's built-ins, plugins
installed under the ``rmpfusion.plugins`` entry point, and the example plugin in tests/plugin_example (loaded
here as its entry point would load it, and unloaded again afterwards). No entry is checked by a hand-written
case: each is built from the sample parameters listed for it in MAP_EXAMPLES, LEAF_EXAMPLES or WEIGHT_EXAMPLES
below, keyed by its registry name. A registered entry without sample parameters FAILS, with a message saying
which entry it is and how to add them; it is never skipped.

What is checked, on every example:

* task maps: y = ψ(x), J against central differences of ψ, ẏ = Jẋ, J̇ẋ against d/dt[J(x + tẋ)ẋ]; a map that
  overrides the autodiff derivatives of ``TaskMap`` agrees with them;
* leaf RMPs: M and f against the GDS definitions (docs/math.md §3) with every derivative of the leaf's own
  G(y, ẏ), B(y, ẏ) and Φ(y) taken by central differences, and L, V from G and Φ; for a ``GDS`` subclass also
  its analytic curvature against the autodiff one and its fused ``terms`` against the separate methods;
* weights: w > 0, ∇_x w against central differences of w, and against the autodiff default of
  ``WeightFunction``; a weight without a gradient term is constant.
"""
from __future__ import annotations

import importlib
import sys
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import pybullet_data
import pytest
import torch

from conftest import fd_directional, fd_jacobian
from rmpfusion.core.gds import GDS, quad
from rmpfusion.core.taskmap import TaskMap
from rmpfusion.core.weight import WeightFunction
from rmpfusion.registry import LEAF_RMPS, TASK_MAPS, WEIGHTS, Registry

HERE = Path(__file__).resolve()
PLUGIN_EXAMPLE = HERE.parent / "plugin_example"
B = 6


@dataclass(frozen=True)
class Example:
    """Sample parameters of one registry entry and the space it is checked on.

    ``params``: the entry's YAML parameters (validated by its own Params model). ``dim``: the parent space's
    dimension (maps, weights) or the leaf's dimension. ``state(gen, B, dim)``: the (x, ẋ) to check at (default:
    x ~ scale·N(0, I), ẋ ~ N(0, I)); pick states away from points where the entry is not differentiable.
    """

    params: dict = field(default_factory=dict)
    dim: int = 2
    state: Callable | None = None
    scale: float = 1.0

    def states(self, gen: torch.Generator, n: int = B):
        if self.state is not None:
            return self.state(gen, n, self.dim)
        return self.scale * torch.randn(n, self.dim, generator=gen), torch.randn(n, self.dim, generator=gen)


# aux state every example may name (maps and weights read centres, radii, goals and target orientations from it)
AUX = {"c": 2, "r": 1, "c3": 3, "goal": 2, "obstacle_center": 2, "obstacle_radius": 1, "goal_velocity": 2,
       "quaternion": 4, "directions": 6}


def sample_aux(n: int, gen: torch.Generator) -> dict:
    return {"c": torch.randn(n, 2, generator=gen), "r": 0.5 + torch.rand(n, 1, generator=gen),
            "c3": torch.randn(n, 3, generator=gen), "goal": torch.randn(n, 2, generator=gen),
            "obstacle_center": torch.randn(n, 2, generator=gen), "obstacle_radius": 0.5 + torch.rand(n, 1, generator=gen),
            "goal_velocity": torch.randn(n, 2, generator=gen), "quaternion": torch.randn(n, 4, generator=gen),
            "directions": torch.randn(n, 6, generator=gen)}


def barrier_states(gen, n, dim):
    """A distance coordinate inside a barrier's support, inside the obstacle too; approaching and receding."""
    y = -0.3 + 0.6 * torch.rand(n, dim, generator=gen)
    y[0, 0] = 0.25
    return y, torch.randn(n, dim, generator=gen)


def positive_distance_states(gen, n, dim):
    """Distances in [0.3, 2]: RMPflow's 1/x⁴ barrier, away from its clipping and from x = 0."""
    return 0.3 + 1.7 * torch.rand(n, dim, generator=gen), torch.randn(n, dim, generator=gen)


PANDA = {"urdf": "pkg://pybullet_data/franka_panda/panda.urdf", "joints": [f"panda_joint{i}" for i in range(1, 8)]}
#: a rotation about (1, 2, 2)/3 by 0.7 rad, row by row: the box's axes in the world
BOX_ROTATION = [0.791, -0.3772, 0.4817, 0.4817, 0.8694, -0.1102, -0.3772, 0.3193, 0.8694]


def panda_states(gen, n, dim):
    from rmpfusion.maps.urdf import parse_urdf
    from rmpfusion.maps.kinematics import Chain
    lo, hi = Chain(parse_urdf(PANDA["urdf"]), PANDA["joints"]).joint_limits()
    return lo + torch.rand(n, dim, generator=gen) * (hi - lo), torch.randn(n, dim, generator=gen)


IIWA = str(Path(pybullet_data.getDataPath()) / "kuka_iiwa" / "model.urdf")


def iiwa_states(gen, n, dim):
    from rmpfusion.maps.urdf import parse_urdf
    from rmpfusion.maps.kinematics import Chain
    lo, hi = Chain(parse_urdf(IIWA)).joint_limits()
    return lo + torch.rand(n, dim, generator=gen) * (hi - lo), torch.randn(n, dim, generator=gen)


def band_states(limit=(1.0,), onset=0.8, linear_from=0.99):
    """States for a velocity_limit leaf: each velocity below its onset, inside its band or beyond its limit, never
    within 0.05 band widths of the onset, of the start of the linear continuation or of the limit (where its metric
    is only C¹, or changes fast); positions do not matter. One sample has every coordinate inside the band."""
    def states(gen, n, dim):
        L = torch.tensor(limit).expand(dim)
        on, band = onset * L, (1 - onset) * L
        r_lin = on + linear_from * band
        pick = torch.randint(0, 3, (n, dim), generator=gen)
        lo = torch.stack([torch.zeros_like(on), on + 0.05 * band, L + 0.05 * band])
        hi = torch.stack([on - 0.05 * band, r_lin - 0.05 * band * linear_from, L + 2 * band])
        lo, hi = lo.gather(0, pick), hi.gather(0, pick)
        sign = torch.where(torch.rand(n, dim, generator=gen) < 0.5, -1.0, 1.0)
        yd = sign * (lo + (hi - lo) * torch.rand(n, dim, generator=gen))
        yd[0] = on + band * 0.5
        return torch.randn(n, dim, generator=gen), yd
    return states


MAP_EXAMPLES: dict[str, list[Example]] = {
    "identity": [Example({}, 2, scale=3.0)],
    "offset": [Example({"origin": [-3.0, 3.0]}, 2, scale=3.0), Example({"origin": "c"}, 2, scale=3.0)],
    "linear": [Example({"matrix": [[1.0, 2.0], [0.5, -1.0], [3.0, 0.0]], "bias": [1.0, 0.0, -1.0]}, 2, scale=3.0)],
    "select": [Example({"indices": [2, 0]}, 3, scale=3.0)],
    "sphere_distance": [Example({"center": [0.3, -0.2], "radius": 1.5}, 2, scale=3.0),
                        Example({"center": "c", "radius": "r", "normalized": True}, 2, scale=3.0)],
    "cylinder_distance": [Example({"center": [0.1, 0.2, 0.0], "radius": 0.3, "axis": [0.0, 0.3, 1.0]}, 3, scale=3.0)],
    "box_distance": [Example({"center": [0.0, 0.0, 0.0], "half_extents": [0.5, 1.0, 0.25]}, 3, scale=3.0)],
    "joint_limit": [Example({"side": "upper", "limit": [2.0, 1.0, 0.5]}, 3, scale=3.0),
                    Example({"side": "lower", "limit": -1.0, "joints": [1]}, 3, scale=3.0)],
    "compose": [Example({"maps": [{"type": "linear", "matrix": [[1.0, 1.0], [0.0, 2.0], [1.0, -1.0]]},
                                  {"type": "sphere_distance", "center": [1.0, 0.0, 0.5], "radius": 0.2}]}, 2, scale=3.0),
                Example({"maps": [{"type": "offset", "origin": "c"}, {"type": "sphere_distance", "center": [0.0, 0.0]}]},
                        2, scale=3.0)],
    "forward_kinematics": [Example({**PANDA, "link": "panda_hand", "offset": [0.05, -0.01, 0.02]}, 7, state=panda_states),
                           Example({**PANDA, "link": "panda_link4"}, 7, state=panda_states)],
    # distances to obstacles, static (velocity absent: ẏ = Jẋ); tests/test_scenes.py checks moving ones in time
    "sphere_obstacle": [Example({"center": [0.3, -0.2, 0.1], "radius": 0.5}, 3, scale=2.0),
                        Example({"center": "c3", "radius": "r"}, 3, scale=2.0)],
    "capsule_obstacle": [Example({"center": [0.1, 0.0, 0.2], "radius": 0.2, "half_length": 0.6,
                                  "axis": [0.6, 0.0, 0.8]}, 3, scale=1.5)],
    "cylinder_obstacle": [Example({"center": [0.0, 0.1, 0.0], "radius": 0.4, "half_height": 0.5,
                                   "axis": [0.0, 0.6, 0.8]}, 3, scale=1.5)],
    "box_obstacle": [Example({"center": [0.1, 0.0, -0.1], "half_extents": [0.3, 0.5, 0.2],
                              "rotation": BOX_ROTATION}, 3, scale=1.5)],
    "plane_distance": [Example({"normal": [0.0, 0.3, 1.0], "height": 0.2}, 3, scale=2.0)],
    "link_axis": [Example({**PANDA, "link": "panda_hand", "axis": [0.0, 0.0, 1.0]}, 7, state=panda_states),
                  Example({**PANDA, "link": "panda_link5", "axis": [1.0, -2.0, 0.5], "target": [0.0, 0.0, -1.0]}, 7,
                          state=panda_states),
                  Example({"urdf": IIWA, "link": "lbr_iiwa_link_7", "target": "c3"}, 7, state=iiwa_states)],
    "link_orientation": [Example({**PANDA, "link": "panda_hand", "target": [0.0, 1.0, 0.0, 0.0]}, 7, state=panda_states),
                         Example({**PANDA, "link": "panda_hand", "target": "quaternion", "target_format": "quaternion_wxyz",
                                  "axes": [[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]}, 7, state=panda_states),
                         Example({"urdf": IIWA, "link": "lbr_iiwa_link_6", "target": "directions",
                                  "target_format": "axes", "axes": [[0.0, 1.0, 0.0], [1.0, 1.0, 0.0]]}, 7,
                                 state=iiwa_states),
                         Example({"urdf": IIWA, "link": "lbr_iiwa_link_7",
                                  "target": [0.0, -1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0], "target_format": "matrix"},
                                 7, state=iiwa_states)],
    "link_sphere_distance": [Example({**PANDA, "a": {"link": "panda_link3", "offset": [0.1, 0.07, 0.0], "radius": 0.1},
                                      "b": {"link": "panda_hand", "offset": [0.0, 0.0, 0.09], "radius": 0.09}}, 7,
                                     state=panda_states),
                             Example({"urdf": IIWA, "a": {"link": "lbr_iiwa_link_2"},
                                      "b": {"link": "lbr_iiwa_link_6", "offset": [0.0, 0.05, 0.0], "radius": 0.08}}, 7,
                                     state=iiwa_states)],
    "velocity_scaled_joints": [Example(PANDA, 7, state=panda_states),
                               Example({"urdf": IIWA, "velocity_limit": [1.0, 2.0, 1.5, 1.0, 3.0, 2.0, 2.5]},
                                       7, state=iiwa_states)],
    "diffeomorphism": [Example({}, 2, scale=2.0),
                       Example({"layers": 3, "hidden": [8], "activation": "softplus", "init_std": 0.5, "origin": "c"}, 2,
                               scale=2.0),
                       Example({"layers": 2, "hidden": [6, 6], "activation": "silu", "init_std": 0.4,
                                "origin": [0.1, 0.2, 0.3]}, 3, scale=2.0)],
    "normalize": [Example({"shift": [0.1, -0.2], "scale": [0.05, 2.0]}, 2), Example({"scale": 40.0}, 3)],
    "moving_offset": [Example({"origin": "c", "velocity": "goal_velocity"}, 2, scale=3.0),
                      Example({"origin": [0.5, -1.0, 0.2], "velocity": [0.1, 0.0, -0.3]}, 3, scale=3.0)],
}

LEAF_EXAMPLES: dict[str, list[Example]] = {
    "goal_attractor": [Example({}, 2),
                       Example({"w_u": 10.0, "w_l": 1.0, "sigma": 0.7, "gain": 2.0, "alpha": 3.0, "eta": 1.0}, 3),
                       Example({"w_u": {"learn": True, "init": 10.0}, "sigma": {"learn": True, "init": 0.7},  # learned
                                "gain": {"learn": True, "init": 2.0, "max": 5.0}}, 3)],
    "collision_avoidance": [Example({"r_w": 2.0, "eta": 0.5, "alpha": 0.1}, 1, state=barrier_states),
                            Example({"r_w": {"learn": True, "init": 2.0}, "eta": {"learn": True, "init": 0.5},
                                     "sigma": {"learn": True, "init": 0.5}}, 1, state=barrier_states)],
    "joint_limit": [Example({}, 1, state=barrier_states)],
    "damper": [Example({"w": 2.0, "eta": 3.0}, 2)],
    "identity_metric": [Example({}, 3)],
    "rmpflow_collision_avoidance": [Example({"alpha": 1e-3, "eta": 0.5}, 1, state=positive_distance_states)],
    "rmpflow_goal_attractor": [Example({}, 2, scale=2.0), Example({"gain": 1.5, "sigma": 0.8, "eta": 1.0}, 3, scale=2.0)],
    "rmpflow_damper": [Example({"w": 2.0, "eta": 0.5}, 3)],
    "orientation_attractor": [Example({}, 3),
                              Example({"gain": 3.0, "eta": 1.5, "w_u": 5.0, "w_l": 1.0, "sigma": 0.4}, 9)],
    "moving_goal_attractor": [Example({}, 4), Example({"gain": 2.0, "alpha": 4.0, "eta": 3.0, "w": 0.5}, 6)],
    "velocity_limit": [Example({}, 3, state=band_states()),
                       Example({"limit": [2.0, 0.5], "onset": 0.6, "w": 3.0, "eta": 0.5, "linear_from": 0.9}, 2,
                               state=band_states((2.0, 0.5), 0.6, 0.9))],
    "spring": [Example({"gain": 3.0, "eta": 0.5, "w": 2.0}, 2)],  # tests/plugin_example
}

WEIGHT_EXAMPLES: dict[str, list[Example]] = {
    "constant": [Example({"value": 2.5}, 2)],
    "rbf": [Example({"low": 0.5, "high": 4.0, "center": "obstacle_center", "radius": "obstacle_radius", "sigma": 0.7},
                    2, scale=2.0),
            Example({"low": 2.0, "high": 0.1, "center": [1.0, -1.0]}, 2, scale=2.0)],
    "logistic": [Example({"low": 0.2, "high": 3.0, "center": "obstacle_center", "radius": "obstacle_radius",
                          "steepness": -3.0, "switch_distance": 0.5}, 2, scale=2.0)],
    "mlp": [Example({"hidden": [16, 16], "aux": ["goal", "obstacle_center", "obstacle_radius"]}, 2, scale=2.0),
            Example({"hidden": [8], "activation": "softplus", "positivity": "exp"}, 2, scale=2.0),
            Example({"hidden": [8, 8, 8], "activation": "elu"}, 2, scale=2.0),
            Example({"hidden": [8], "activation": "silu", "aux": ["goal"]}, 2, scale=2.0),
            Example({"hidden": [8], "activation": "sigmoid"}, 2, scale=2.0)],
}

KINDS = {"map": (TASK_MAPS, MAP_EXAMPLES, "MAP_EXAMPLES"), "leaf": (LEAF_RMPS, LEAF_EXAMPLES, "LEAF_EXAMPLES"),
         "weight": (WEIGHTS, WEIGHT_EXAMPLES, "WEIGHT_EXAMPLES")}


# ------------------------------------------------------------------------------------------------ the registries
@contextmanager
def plugin_example_loaded():
    """Register tests/plugin_example's entries (as its entry point does), and remove them again on exit, so the
    rest of the suite (tests/test_plugins.py) still meets an rmpfusion without the plugin."""
    before = {reg: set(reg.names()) for reg, _, _ in KINDS.values()}
    had_module = "rmpfusion_spring" in sys.modules
    sys.path.insert(0, str(PLUGIN_EXAMPLE))
    try:
        importlib.import_module("rmpfusion_spring")
        yield
    finally:
        sys.path.remove(str(PLUGIN_EXAMPLE))
        if not had_module:
            for reg, names in before.items():
                for name in set(reg.names()) - names:
                    reg.unregister(name)
            for mod in [m for m in sys.modules if m == "rmpfusion_spring" or m.startswith("rmpfusion_spring.")]:
                del sys.modules[mod]


def registered(reg: Registry) -> list[str]:
    with plugin_example_loaded():
        return reg.names()


REGISTERED = {kind: registered(reg) for kind, (reg, _, _) in KINDS.items()}
_UNLOADED_AFTER_COLLECTION = "spring" not in LEAF_RMPS.names()


@pytest.fixture(scope="module", autouse=True)
def _plugin_example():
    with plugin_example_loaded():
        yield


def cases(kind: str):
    """One test per (entry, example); an entry without examples still gets one, which fails."""
    _, table, _ = KINDS[kind]
    out = []
    for name in REGISTERED[kind]:
        examples = table.get(name) or [None]
        out += [pytest.param(name, i, id=f"{name}-{i}" if ex is not None else f"{name}-NO-EXAMPLE")
                for i, ex in enumerate(examples)]
    return out


def example(kind: str, name: str, i: int) -> Example:
    reg, table, table_name = KINDS[kind]
    if not table.get(name):
        entry = reg.get(name)
        fields = ", ".join(f"{k}=<required>" if f.is_required() else f"{k}={f.default!r}"
                           for k, f in entry.params.model_fields.items()) or "no parameters"
        pytest.fail(f"{reg.kind} '{name}' (registered by {entry.owner}) has no sample parameters for the "
                    f"finite-difference check: add \"{name}\": [Example({{...}}, dim=...)] to {table_name} in "
                    f"{HERE.relative_to(HERE.parent.parent)} (its parameters: {fields}); pass state=... to pick "
                    f"states where it is differentiable", pytrace=False)
    return table[name][i]


def test_every_example_names_a_registered_entry():
    stale = {table_name: sorted(set(table) - set(REGISTERED[kind])) for kind, (_, table, table_name) in KINDS.items()}
    stale = {k: v for k, v in stale.items() if v}
    assert not stale, f"examples for entries that are not registered (renamed or removed?): {stale}"


def test_the_plugin_example_is_among_the_checked_entries():
    assert "spring" in REGISTERED["leaf"] and "spring" in LEAF_EXAMPLES
    assert _UNLOADED_AFTER_COLLECTION  # and unloaded again for the rest of the suite


def build(kind: str, name: str, ex: Example):
    reg, _, _ = KINDS[kind]
    entry = reg.get(name)
    params = entry.validate(ex.params)
    if kind == "leaf":
        return entry.obj(params, ex.dim)
    return entry.obj(params, ex.dim, AUX).double()


def overrides(obj, base: type, *methods: str) -> bool:
    return any(getattr(type(obj), m) is not getattr(base, m) for m in methods)


# ------------------------------------------------------------------------------------------------ task maps
@pytest.mark.parametrize("name,i", cases("map"))
def test_map_jacobian_and_curvature_match_finite_differences(name, i, gen):
    ex = example("map", name, i)
    m = build("map", name, ex)
    x, xd = ex.states(gen)
    aux = sample_aux(B, gen)
    y, yd, J, c = m(x, xd, aux)
    assert y.shape == (B, m.out_dim) and J.shape == (B, m.out_dim, ex.dim) and c.shape == (B, m.out_dim)
    psi = lambda z: m.psi(z, aux)  # noqa: E731
    torch.testing.assert_close(y, psi(x))
    torch.testing.assert_close(J, fd_jacobian(psi, x), atol=1e-7, rtol=1e-6)
    torch.testing.assert_close(yd, (J @ xd[..., None])[..., 0])
    # J̇ẋ = d/dt [J(x + t ẋ) ẋ] at t = 0
    Jxd = lambda z: (m(z, xd, aux)[2] @ xd[..., None])[..., 0]  # noqa: E731
    torch.testing.assert_close(c, fd_directional(Jxd, x, xd), atol=1e-6, rtol=1e-5)
    if overrides(m, TaskMap, "forward", "jacobian", "curvature"):  # analytic paths agree with the autodiff base
        J_ad = TaskMap.jacobian(m, x, aux)
        torch.testing.assert_close(J, J_ad, atol=1e-12, rtol=1e-10)
        torch.testing.assert_close(c, TaskMap.curvature(m, x, xd, aux, J_ad), atol=1e-10, rtol=1e-10)


# ------------------------------------------------------------------------------------------------ leaf RMPs
def gds_by_finite_differences(G_of, B_of, Phi_of, y, yd, eps=1e-6):
    """M and f from the GDS definitions of docs/math.md §3, every derivative by central differences:
    Ξ = ½ Σ_i ẏ_i ∂_ẏ g_i, ξ = Ġẏ − ½∇_y(ẏᵀGẏ), M = G + Ξ, f = −∇Φ − Bẏ − ξ."""
    n = y.shape[1]
    G = G_of(y, yd)
    Xi = torch.zeros_like(G)
    for k in range(n):
        e = torch.zeros_like(yd)
        e[:, k] = eps
        dG = (G_of(y, yd + e) - G_of(y, yd - e)) / (2 * eps)  # ∂G/∂ẏ_k
        Xi[:, :, k] = 0.5 * (dG @ yd[..., None])[..., 0]  # ½ Σ_i ẏ_i ∂G[:, i]/∂ẏ_k
    Gdot = (G_of(y + eps * yd, yd) - G_of(y - eps * yd, yd)) / (2 * eps)
    grad_quad = fd_jacobian(lambda z: quad(yd, G_of(z, yd))[:, None], y, eps)[:, 0, :]
    xi = (Gdot @ yd[..., None])[..., 0] - 0.5 * grad_quad
    grad_Phi = fd_jacobian(lambda z: Phi_of(z, yd)[:, None], y, eps)[:, 0, :]
    f = -grad_Phi - (B_of(y, yd) @ yd[..., None])[..., 0] - xi
    return G + Xi, f


@pytest.mark.parametrize("name,i", cases("leaf"))
def test_leaf_M_and_f_match_the_gds_definitions_by_finite_differences(name, i, gen):
    ex = example("leaf", name, i)
    leaf = build("leaf", name, ex)
    y, yd = ex.states(gen)
    out = leaf(y, yd)
    assert out.f.shape == y.shape and out.M.shape == (B, ex.dim, ex.dim)
    M_fd, f_fd = gds_by_finite_differences(lambda a, b: leaf(a, b).G, lambda a, b: leaf(a, b).B,
                                           lambda a, b: leaf(a, b).Phi, y, yd)
    torch.testing.assert_close(out.M, M_fd, rtol=1e-6, atol=1e-6)
    torch.testing.assert_close(out.f, f_fd, rtol=1e-6, atol=1e-6)
    K = 0.5 * quad(yd, out.G)
    torch.testing.assert_close(out.V, K + out.Phi)
    torch.testing.assert_close(out.L, K - out.Phi)
    if isinstance(leaf, GDS):
        torch.testing.assert_close(out.G, leaf.metric(y, yd))
        # the autodiff curvature of the GDS base agrees with any analytic override
        Xi_ad, xi_ad = GDS.curvature(leaf, y, yd)
        Xi, xi = leaf.curvature(y, yd)
        torch.testing.assert_close(Xi, Xi_ad, atol=1e-10, rtol=1e-10)
        torch.testing.assert_close(xi, xi_ad, atol=1e-10, rtol=1e-10)
        # a fused ``terms`` (one evaluation shared by all six terms) equals the separate definitions exactly
        plain = (leaf.metric(y, yd), leaf.damping(y, yd), leaf.potential(y), GDS.potential_grad(leaf, y), Xi_ad, xi_ad)
        for got, want in zip(leaf.terms(y, yd), plain):
            torch.testing.assert_close(got, want, atol=1e-10, rtol=1e-10)


# ------------------------------------------------------------------------------------------------ weights
@pytest.mark.parametrize("name,i", cases("weight"))
def test_weight_gradient_matches_finite_differences_and_weight_is_positive(name, i, gen):
    ex = example("weight", name, i)
    w = build("weight", name, ex)
    with torch.no_grad():  # learnable weights away from their initialisation
        for p in w.parameters():
            torch.nn.init.normal_(p, std=0.8, generator=gen)
    x, _ = ex.states(gen)
    a = sample_aux(B, gen)
    val, grad = w(x, a)
    assert val.shape == (B,) and (val > 0).all()
    fd = fd_jacobian(lambda z: w.value(z, a)[:, None], x)[:, 0, :]
    if grad is None:  # no h_i term: only a constant weight may say so
        assert w.is_constant and float(fd.abs().max()) == 0.0, f"{name} has no ∇w but is not constant"
        return
    assert grad.shape == x.shape
    torch.testing.assert_close(grad, fd, rtol=1e-6, atol=1e-8)
    # agrees with the autodiff default of the base class
    torch.testing.assert_close(grad, WeightFunction.forward(w, x, a)[1], rtol=1e-10, atol=1e-12)
