"""Every registered task map, leaf RMP and weight function against finite differences, driven by the registries.

The tests are parametrized over the registries' contents at collection time: rmpfusion's built-ins, plugins
installed under the ``rmpfusion.plugins`` entry point, and the example plugin in tests/plugin_example (loaded
here as its entry point would load it, and unloaded again afterwards). No entry is checked by a hand-written
case: each is built from the examples it declares where it is registered (``@TASK_MAPS.register(name,
examples=[Example(...)])``, ``rmpfusion.examples``), so a plugin brings its own. A registered entry without
examples FAILS, with a message naming it, its owner and how to add them; it is never skipped.

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
import importlib.util
import sys
from contextlib import contextmanager
from pathlib import Path

import pytest
import torch
from conftest import fd_directional, fd_jacobian
from pydantic import BaseModel

from rmpfusion.core.gds import GDS, quad
from rmpfusion.core.taskmap import TaskMap
from rmpfusion.core.weight import WeightFunction
from rmpfusion.examples import Example
from rmpfusion.registry import LEAF_RMPS, TASK_MAPS, WEIGHTS, Entry, Params, Registry

PLUGIN_EXAMPLE = Path(__file__).resolve().parent / "plugin_example"
B = 6

#: kind -> (its registry, the registry's name in rmpfusion.registry, which a missing-example message names)
KINDS = {"map": (TASK_MAPS, "TASK_MAPS"), "leaf": (LEAF_RMPS, "LEAF_RMPS"), "weight": (WEIGHTS, "WEIGHTS")}


# ------------------------------------------------------------------------------------------------ the registries
@contextmanager
def plugin_example_loaded():
    """Register tests/plugin_example's entries (as its entry point does), and remove them again on exit, so the
    rest of the suite (tests/test_plugins.py) still meets an rmpfusion without the plugin."""
    before = {reg: set(reg.names()) for reg, _ in KINDS.values()}
    had_module = "rmpfusion_spring" in sys.modules
    package = PLUGIN_EXAMPLE / "rmpfusion_spring"
    spec = importlib.util.spec_from_file_location(
        "rmpfusion_spring", package / "__init__.py", submodule_search_locations=[str(package)]
    )
    assert spec is not None and spec.loader is not None
    try:
        if not had_module:  # loaded from its folder as its entry point would import it once installed
            module = importlib.util.module_from_spec(spec)
            sys.modules["rmpfusion_spring"] = module
            spec.loader.exec_module(module)
        yield
    finally:
        if not had_module:
            for reg, names in before.items():
                for name in set(reg.names()) - names:
                    reg.unregister(name)
            for mod in [m for m in sys.modules if m == "rmpfusion_spring" or m.startswith("rmpfusion_spring.")]:
                del sys.modules[mod]


def registered(reg: Registry) -> list[Entry]:
    with plugin_example_loaded():
        return reg.entries()


REGISTERED = {kind: registered(reg) for kind, (reg, _) in KINDS.items()}
_UNLOADED_AFTER_COLLECTION = "spring" not in LEAF_RMPS.names()


@pytest.fixture(scope="module", autouse=True)
def _plugin_example():
    with plugin_example_loaded():
        yield


def cases_of(entries: list[Entry]):
    """One test per (entry, example); an entry without examples still gets one, which fails."""
    return [
        pytest.param(e.name, i, id=f"{e.name}-{i}" if e.examples else f"{e.name}-NO-EXAMPLE")
        for e in entries
        for i in range(max(len(e.examples), 1))
    ]


def cases(kind: str):
    return cases_of(REGISTERED[kind])


def missing_examples(entry: Entry, registry_name: str, kind: str) -> str:
    """What a developer reads when an entry declares no examples: which entry, who registered it, and the register
    call that adds them."""
    fields = (
        ", ".join(
            f"{k}=<required>" if f.is_required() else f"{k}={f.default!r}" for k, f in entry.params.model_fields.items()
        )
        or "no parameters"
    )
    dim = "the leaf's dimension" if kind == "leaf" else "the parent's dimension"
    return (
        f"{KINDS[kind][0].kind} '{entry.name}' (registered by {entry.owner}) declares no examples for the "
        f'finite-difference check: add them where it is registered, @{registry_name}.register("{entry.name}", '
        f"examples=[Example({{...its params...}}, dim=<{dim}>)]) with Example from rmpfusion.examples (its "
        f"parameters: {fields}); pass state=... to pick states where it is differentiable"
        + ("" if kind == "leaf" else ", aux={name: AuxInput.normal(dim)} for the aux state its params name")
    )


def example(kind: str, name: str, i: int) -> Example:
    reg, registry_name = KINDS[kind]
    entry = reg.get(name)
    if not entry.examples:
        pytest.fail(missing_examples(entry, registry_name, kind), pytrace=False)
    return entry.examples[i]


def test_an_entry_without_examples_fails_naming_itself_and_the_fix():
    """The message of an entry without examples, from an isolated registry holding one."""
    reg = Registry("leaf RMP")

    @reg.register("bare")
    class Bare(GDS):
        class Params(Params):
            gain: float = 1.0

    msg = missing_examples(reg.get("bare"), "LEAF_RMPS", "leaf")
    assert "leaf RMP 'bare'" in msg and f"registered by {Bare.__module__}." in msg
    assert '@LEAF_RMPS.register("bare", examples=[Example(' in msg and "gain=1.0" in msg
    assert [p.id for p in cases_of([reg.get("bare")])] == ["bare-NO-EXAMPLE"]


def test_examples_must_be_examples():
    reg = Registry("leaf RMP")
    with pytest.raises(TypeError, match="examples must be rmpfusion.examples.Example, got dict"):
        reg.register("wrong", examples=[{"gain": 1.0}])(LEAF_RMPS.get("damper").obj)
    assert "wrong" not in reg


def test_a_params_model_must_subclass_the_registrys_params():
    """A plain pydantic model would drop a misspelt key without a word, so an entry whose parameters are one, given
    to ``register`` or as the class's own ``Params``, is refused naming the base it must subclass."""

    class Loose(BaseModel):
        gain: float = 1.0

    assert Loose.model_validate({"gian": 2.0}).gain == 1.0  # what registering it would let through
    reg = Registry("leaf RMP")
    refused = r"leaf RMP 'loose' \(.*\) needs a Params model: a subclass of rmpfusion\.registry\.Params"
    with pytest.raises(TypeError, match=refused):
        reg.register("loose", params=Loose)(LEAF_RMPS.get("damper").obj)
    with pytest.raises(TypeError, match=refused):

        @reg.register("loose")
        class LooseLeaf(GDS):
            Params = Loose

    assert "loose" not in reg


def test_the_plugin_example_is_among_the_checked_entries():
    spring = {e.name: e for e in REGISTERED["leaf"]}["spring"]
    assert spring.owner == "rmpfusion_spring.Spring" and spring.examples
    assert _UNLOADED_AFTER_COLLECTION  # and unloaded again for the rest of the suite


def build(kind: str, name: str, ex: Example):
    reg, _ = KINDS[kind]
    entry = reg.get(name)
    params = entry.validate(dict(ex.params))
    if kind == "leaf":
        return entry.obj(params, ex.dim)
    return entry.obj(params, ex.dim, ex.aux_dims()).double()


def overrides(obj, base: type, *methods: str) -> bool:
    return any(getattr(type(obj), m) is not getattr(base, m) for m in methods)


# ------------------------------------------------------------------------------------------------ task maps
@pytest.mark.parametrize("name,i", cases("map"))
def test_map_jacobian_and_curvature_match_finite_differences(name, i, gen):
    ex = example("map", name, i)
    m = build("map", name, ex)
    x, xd = ex.states(gen, B)
    aux = ex.sample_aux(gen, B)
    y, yd, J, c = m(x, xd, aux)
    assert y.shape == (B, m.out_dim) and J.shape == (B, m.out_dim, ex.dim) and c.shape == (B, m.out_dim)
    psi = lambda z: m.psi(z, aux)
    torch.testing.assert_close(y, psi(x))
    torch.testing.assert_close(J, fd_jacobian(psi, x), atol=1e-7, rtol=1e-6)
    torch.testing.assert_close(yd, (J @ xd[..., None])[..., 0])
    # J̇ẋ = d/dt [J(x + t ẋ) ẋ] at t = 0
    Jxd = lambda z: (m(z, xd, aux)[2] @ xd[..., None])[..., 0]
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
    y, yd = ex.states(gen, B)
    out = leaf(y, yd)
    assert out.f.shape == y.shape and out.M.shape == (B, ex.dim, ex.dim)
    M_fd, f_fd = gds_by_finite_differences(
        lambda a, b: leaf(a, b).G, lambda a, b: leaf(a, b).B, lambda a, b: leaf(a, b).Phi, y, yd
    )
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
    x, _ = ex.states(gen, B)
    a = ex.sample_aux(gen, B)
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
