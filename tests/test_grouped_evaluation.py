"""Level-batched evaluation (docs/math.md §9) against an independent node-by-node computation of eq. 6
(tests/reference_tree.py), in float64 to 1e-12: random trees whose siblings group with a number per member, the
Franka tree, and plugins' leaves (one that declares how it stacks, with a learned number, and one that does not)."""

import copy

import pytest
import torch
from pydantic import Field
from reference_tree import FIELDS, node_by_node
from trees import TWO_LEVEL, grouping_tree_spec, two_level_inputs

import rmpfusion
from rmpfusion.core.gds import GDS
from rmpfusion.core.groups import Alone
from rmpfusion.registry import LEAF_RMPS, Params

TOL = 1e-12


def _assert_equal(out, ref, tol=TOL):
    for k in (*FIELDS, "qdd"):
        a, b = getattr(out, k), ref[k]
        scale = 1.0 + b.abs().max()
        assert (a - b).abs().max() <= tol * scale, f"{k}: {(a - b).abs().max():.3e} (scale {scale:.3g})"


def _inputs(seed: int, dim: int, B: int):
    g = torch.Generator().manual_seed(seed)
    q = 2 * torch.rand(B, dim, generator=g, dtype=torch.float64) - 1
    qd = torch.randn(B, dim, generator=g, dtype=torch.float64)
    aux = {k: 3 * torch.rand(B, dim, generator=g, dtype=torch.float64) - 1.5 for k in ("goal", "c", "c1", "c2", "c3")}
    return q, qd, aux


def _randomise(tree, seed):
    g = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for p in tree.parameters():
            p.copy_(0.4 * torch.randn(p.shape, generator=g, dtype=p.dtype))


@pytest.mark.parametrize("seed", range(4))
def test_random_trees_equal_the_node_by_node_computation(seed):
    tree = rmpfusion.build_tree(grouping_tree_spec(seed))
    _randomise(tree, seed)
    sizes = sorted((len(g.nodes) for g in tree.plan.groups), reverse=True)
    assert sizes[0] >= 6 and sum(1 for s in sizes if s > 1) >= 5, f"the tree should group: {sizes}"
    assert any(len(w.edges) > 1 for w in tree.plan.weights)
    q, qd, aux = _inputs(seed, 3, 5)
    _assert_equal(tree(q, qd, aux), node_by_node(tree, q, qd, aux))


def test_parameter_gradients_equal_the_node_by_node_computation():
    """Gradients reach every weight network through the stacked weights and the h_i terms, as node by node."""
    tree = rmpfusion.build_tree(grouping_tree_spec(7))
    _randomise(tree, 7)
    q, qd, aux = _inputs(7, 3, 4)
    grads = []
    for evaluate in (lambda: tree(q, qd, aux), lambda: node_by_node(tree, q, qd, aux)):
        tree.zero_grad()
        out = evaluate()
        qdd, V = (out.qdd, out.V) if hasattr(out, "qdd") else (out["qdd"], out["V"])
        (qdd.square().sum() + V.sum()).backward()
        grads.append({n: p.grad.clone() for n, p in tree.named_parameters()})
    assert grads[0]
    for n, g in grads[0].items():
        assert (g - grads[1][n]).abs().max() <= TOL * (1 + grads[1][n].abs().max()), n


def test_policy_equals_the_full_evaluation_where_only_f_and_m_are_needed():
    """A tree without configuration-dependent weights evaluates only f and M for ``policy`` (no potentials)."""
    spec = grouping_tree_spec(3)
    spec["nodes"] = {n: {k: v for k, v in nd.items() if k != "weight"} for n, nd in spec["nodes"].items()}
    spec["shared_weights"] = {}
    tree = rmpfusion.build_tree(spec)
    assert tree.plan.lean
    q, qd, aux = _inputs(3, 3, 6)
    torch.testing.assert_close(tree.policy(q, qd, aux), node_by_node(tree, q, qd, aux)["qdd"], rtol=TOL, atol=TOL)
    assert not rmpfusion.build_tree(grouping_tree_spec(3)).plan.lean


#: Leaves that do not stack (each runs alone as a group of one), with a map each can read.
UNSTACKED_LEAVES = {
    "velocity_limit": {"type": "identity"},
    "moving_goal_attractor": {"type": "moving_offset", "origin": "goal", "velocity": [0.1, -0.2]},
}


@pytest.mark.parametrize("leaf", sorted(UNSTACKED_LEAVES))
def test_policy_of_constant_weights_with_a_leaf_that_runs_alone_equals_the_full_evaluation(leaf):
    """Where only f and M are needed, a leaf that does not stack answers them alone (its other fields absent) and
    ``policy`` still gives the full evaluation's q̈, and the node-by-node one."""
    spec = {
        "root": {"name": "x", "dim": 2},
        "aux": {"goal": 2},
        "nodes": {
            "goal": {
                "parent": "x",
                "map": {"type": "identity"},
                "weight": {"type": "constant", "value": 2.0},
                "rmp": {"type": "goal_attractor"},
            },
            "alone": {"parent": "x", "map": UNSTACKED_LEAVES[leaf], "rmp": {"type": leaf}},
        },
    }
    tree = rmpfusion.build_tree(spec)
    assert tree.plan.lean
    assert any(isinstance(g.leaf, Alone) for g in tree.plan.groups)  # the case at hand: a leaf run alone
    q, qd, aux = _inputs(11, 2, 5)
    aux = {"goal": aux["goal"]}
    qdd = tree.policy(q, qd, aux)
    torch.testing.assert_close(qdd, tree(q, qd, aux).qdd, rtol=TOL, atol=TOL)
    torch.testing.assert_close(qdd, node_by_node(tree, q, qd, aux)["qdd"], rtol=TOL, atol=TOL)


@pytest.mark.parametrize("aux_only", [("goal", "obstacles", "o1", "o2"), ("goal", "obstacles", "o1")])
def test_weights_reading_only_aux_state_across_node_groups_equal_the_node_by_node_computation(aux_only):
    """Networks that read only aux state (no ∇w, no h_i term) and evaluate as one batch for edges of several node
    groups: every field as node by node; also where a group's other member (o2) keeps a weight with a gradient."""
    spec = copy.deepcopy(TWO_LEVEL)
    for n in aux_only:
        spec["nodes"][n]["weight"] = {"type": "mlp", "hidden": [4], "aux": ["goal"], "use_config": False}
    tree = rmpfusion.build_tree(spec)
    _randomise(tree, 5)
    shared = [w.edges for w in tree.plan.weights if len(w.edges) > 1]
    assert shared == [list(aux_only)] and not tree.plan.lean
    q, qd, aux = two_level_inputs(6, torch.Generator().manual_seed(5))
    q, qd, aux = q.double(), qd.double(), {k: v.double() for k, v in aux.items()}
    out = tree(q, qd, aux)
    assert out.qdd.isfinite().all()
    _assert_equal(out, node_by_node(tree, q, qd, aux))


@pytest.mark.parametrize("n_obstacles", [1, 3])
@pytest.mark.parametrize("weights", ["expert", "learner"])
def test_the_franka_tree_equals_the_node_by_node_computation(n_obstacles, weights):
    from manipulators import franka_tree_spec

    from rmpfusion.assembly.weighting import tree_with_weights

    spec = franka_tree_spec(n_obstacles=n_obstacles)
    if weights == "expert":
        logistic = {
            "type": "logistic",
            "center": "obstacle_center",
            "radius": "obstacle_radius",
            "steepness": -20.0,
            "switch_distance": 0.2,
            "low": 1.0,
            "high": 200.0,
        }
        spec = tree_with_weights(
            spec,
            {
                "attractor": {"type": "rbf", "center": "goal", "sigma": 0.2, "low": 40.0, "high": 60.0},
                **{n: logistic for n in spec["shared_weights"]},
            },
        )
    tree = rmpfusion.build_tree(spec)
    _randomise(tree, n_obstacles)
    kinds = {g.nodes[0]: len(g.nodes) for g in tree.plan.groups}
    assert kinds["ee"] == 15 and kinds["jl1_upper"] == 14 and kinds["cp1_obstacle1"] == 14 * n_obstacles
    g = torch.Generator().manual_seed(n_obstacles)
    lo, hi = tree.maps["ee"].chain.joint_limits()
    q = lo + (hi - lo) * torch.rand(4, 7, generator=g, dtype=torch.float64)
    qd = torch.randn(4, 7, generator=g, dtype=torch.float64)
    aux = {"goal": torch.tensor([[0.4, -0.3, 0.4]], dtype=torch.float64).expand(4, 3)}
    for k in range(1, n_obstacles + 1):
        aux[f"obstacle{k}_center"] = torch.tensor([[0.5, 0.1 * k, 0.3]], dtype=torch.float64).expand(4, 3)
        aux[f"obstacle{k}_radius"] = torch.full((4, 1), 0.05 * k, dtype=torch.float64)
    _assert_equal(tree(q, qd, aux), node_by_node(tree, q, qd, aux))


class Spring(GDS):
    """A plugin's leaf that declares how it stacks: G = m·I, B = c·I, Φ = ½k|y|², its stiffness learned."""

    stack_fields = ("m", "c", "k")

    class Params(Params):
        m: float = Field(1.0, gt=0)
        c: float = Field(1.0, ge=0)
        k: float = Field(1.0, gt=0)

    def __init__(self, params, dim):
        super().__init__(dim)
        self.m, self.c = params.m, params.c
        self.log_k = torch.nn.Parameter(torch.tensor(params.k, dtype=torch.float64).log())

    @property
    def k(self):
        return self.log_k.exp()

    def metric(self, y, yd):
        return (self.m + torch.zeros_like(y[..., 0]))[..., None, None] * torch.eye(y.shape[-1], dtype=y.dtype)

    def damping(self, y, yd):
        return (self.c + torch.zeros_like(y[..., 0]))[..., None, None] * torch.eye(y.shape[-1], dtype=y.dtype)

    def potential(self, y):
        return 0.5 * self.k * (y * y).sum(-1)

    def curvature(self, y, yd):
        return torch.zeros(*y.shape, y.shape[-1], dtype=y.dtype), torch.zeros_like(y)


class Rubber(Spring):
    """The same leaf from a plugin that declares nothing: it runs alone."""

    stack_fields = None


@pytest.fixture
def plugin_leaves():
    LEAF_RMPS.register("test_spring")(Spring)
    LEAF_RMPS.register("test_rubber")(Rubber)
    yield
    LEAF_RMPS.unregister("test_spring")
    LEAF_RMPS.unregister("test_rubber")


def test_plugin_leaves_group_when_they_declare_how_and_run_alone_otherwise(plugin_leaves):
    nodes = {}
    for k in range(3):
        for kind in ("spring", "rubber"):
            nodes[f"{kind}{k}"] = {
                "parent": "q",
                "map": {"type": "offset", "origin": [0.3 * k, -0.2 * k]},
                "weight": {"type": "mlp", "hidden": [4]},
                "rmp": {"type": f"test_{kind}", "m": 1.0 + k, "c": 0.5 * k, "k": 2.0 + k},
            }
    tree = rmpfusion.build_tree({"root": {"name": "q", "dim": 2}, "nodes": nodes})
    sizes = {g.nodes[0]: len(g.nodes) for g in tree.plan.groups}
    assert sizes["spring0"] == 3 and all(sizes[f"rubber{k}"] == 1 for k in range(3))
    q, qd, _ = _inputs(1, 2, 5)
    grads = []
    for evaluate in (lambda: tree(q, qd), lambda: node_by_node(tree, q, qd)):
        tree.zero_grad()
        out = evaluate()
        qdd = out.qdd if hasattr(out, "qdd") else out["qdd"]
        if not grads:
            _assert_equal(out, node_by_node(tree, q, qd))
        qdd.square().sum().backward()
        grads.append({n: p.grad.clone() for n, p in tree.named_parameters() if "log_k" in n})
    assert len(grads[0]) == 6
    for n, g in grads[0].items():
        assert g.abs().max() > 0, f"the learned stiffness {n} gets a gradient through its group"
        torch.testing.assert_close(g, grads[1][n], rtol=TOL, atol=TOL)


def test_only_a_non_finite_answer_is_walked_down_node_by_node(monkeypatch):
    """One check of the answer at the root; the node-by-node diagnosis runs only when that check fails, and then
    names the node."""
    from rmpfusion.core.tree import NumericalError, RMPTree

    calls = []
    original = RMPTree._diagnose
    monkeypatch.setattr(RMPTree, "_diagnose", lambda self, *a: calls.append(1) or original(self, *a))
    tree = rmpfusion.build_tree(grouping_tree_spec(5))
    q, qd, aux = _inputs(5, 3, 4)
    tree(q, qd, aux)
    assert calls == []
    with torch.no_grad():
        tree.shared["near"].layers[0].bias.fill_(float("nan"))
    with pytest.raises(NumericalError, match=r"non-finite weight at node 'o0' \(weight shared:near\)"):
        tree(q, qd, aux)
    assert calls == [1]


def test_a_manipulator_tree_with_every_option_equals_the_node_by_node_computation():
    """The Panda among a cylinder, a sphere and a box, with self-collision barriers, a tool axis and a velocity cap:
    distances to each shape one group, the gaps one group; values equal node by node, Theorem 2's identity holds."""
    from conftest import assert_energy_identity
    from manipulators import robot

    from rmpfusion.envs.manipulator_tree import manipulator_tree_spec

    shapes = {
        "obstacles": [
            {"type": "cylinder", "center": [0.5, 0.0, 0.3], "radius": 0.05, "height": 0.6},
            {"type": "sphere", "center": [0.4, 0.3, 0.4], "radius": 0.08},
            {"type": "box", "center": [0.3, -0.3, 0.2], "half_extents": [0.05, 0.1, 0.2]},
        ]
    }
    spec = manipulator_tree_spec(
        robot("panda"),
        shapes,
        self_collision={"min_separation": 3},
        orientation={"target": [0.0, 0.0, -1.0]},
        velocity_limits={},
    )
    tree = rmpfusion.build_tree(spec)
    _randomise(tree, 3)
    assert sorted(len(g.nodes) for g in tree.plan.groups if len(g.nodes) > 2) == [14, 14, 14, 14, 15, 20]
    g = torch.Generator().manual_seed(3)
    lo, hi = tree.maps["ee"].chain.joint_limits()
    B = 4
    q = lo + (hi - lo) * (0.25 + 0.5 * torch.rand(B, 7, generator=g, dtype=torch.float64))
    qd = 0.5 * torch.randn(B, 7, generator=g, dtype=torch.float64)
    aux = {"goal": torch.tensor([[0.4, -0.3, 0.4]], dtype=torch.float64).expand(B, 3)}
    for k, o in enumerate(shapes["obstacles"], start=1):
        aux[f"obstacle{k}_center"] = torch.tensor([o["center"]], dtype=torch.float64).expand(B, 3)
    aux.update(
        {
            "obstacle1_radius": torch.full((B, 1), 0.05, dtype=torch.float64),
            "obstacle1_axis": torch.tensor([[0.0, 0.0, 1.0]], dtype=torch.float64).expand(B, 3),
            "obstacle1_half_height": torch.full((B, 1), 0.3, dtype=torch.float64),
            "obstacle2_radius": torch.full((B, 1), 0.08, dtype=torch.float64),
            "obstacle3_half_extents": torch.tensor([[0.05, 0.1, 0.2]], dtype=torch.float64).expand(B, 3),
            "obstacle3_rotation": torch.eye(3, dtype=torch.float64).reshape(1, 9).expand(B, 9),
            "obstacle3_radius": torch.full((B, 1), 0.1, dtype=torch.float64),
        }
    )
    aux = {k: v for k, v in aux.items() if k in tree.aux_dims}
    missing = sorted(set(tree.aux_dims) - set(aux) - {"obstacle_center", "obstacle_radius"})
    assert not missing, missing
    _assert_equal(tree(q, qd, aux), node_by_node(tree, q, qd, aux))
    assert_energy_identity(tree, q, qd, aux)
