"""What ``print(tree)`` shows of a node: every registered task map, leaf RMP and weight function states its numbers
in its ``extra_repr`` (``rmpfusion.registry.numbers_repr``), a learned number at its current value.

The entries are built through the registries from the examples they declare (as tests/test_registry_derivatives.py
builds them), and every built-in entry of the three registries is held to having an ``extra_repr`` of its own.
"""

from __future__ import annotations

import math

import pytest
import torch
from torch import nn

import rmpfusion
from rmpfusion.core.taskmap import TaskMap
from rmpfusion.registry import LEAF_RMPS, TASK_MAPS, WEIGHTS, Params, Registry, numbers_repr

KINDS = {"map": TASK_MAPS, "leaf": LEAF_RMPS, "weight": WEIGHTS}


def built(kind: str, name: str, example: int) -> nn.Module:
    """Entry ``name`` built from its example number ``example``, as the registry builds it."""
    entry = KINDS[kind].get(name)
    ex = entry.examples[example]
    params = entry.validate(dict(ex.params))
    return entry.obj(params, ex.dim) if kind == "leaf" else entry.obj(params, ex.dim, ex.aux_dims())


@pytest.mark.parametrize(
    "kind, name, example, shown",
    [
        (
            "leaf",
            "goal_attractor",
            1,
            ["GoalAttractor(dim=3, gain=2.0, alpha=3.0, eta=1.0, w_u=10.0, w_l=1.0, sigma=0.7)"],
        ),
        ("leaf", "collision_avoidance", 0, ["r_w=2.0", "alpha=0.1", "eta=0.5", "min_distance=0.001"]),
        ("leaf", "velocity_limit", 1, ["dim=2", "limit=[2.0, 0.5]", "onset=0.6", "w=3.0", "linear_from=0.9"]),
        ("leaf", "rmpflow_goal_attractor", 1, ["gain=1.5", "sigma=0.8", "tol=0.005"]),
        ("leaf", "moving_goal_attractor", 1, ["dim=6, gain=2.0, alpha=4.0, eta=3.0, w=0.5"]),
        ("map", "linear", 0, ["matrix=[[1.0, 2.0], [0.5, -1.0], [3.0, 0.0]]", "bias=[1.0, 0.0, -1.0]"]),
        ("map", "select", 0, ["Select(in_dim=3, out_dim=2, indices=[2, 0])"]),
        ("map", "joint_limit", 1, ["side='lower', joints=[1], limit=[-1.0]"]),
        ("map", "normalize", 0, ["shift=[0.1, -0.2], scale=[0.05, 2.0]"]),
        ("map", "sphere_distance", 0, ["in_dim=2, out_dim=1", "const=[0.3, -0.2]", "const=[1.5]"]),
        ("map", "forward_kinematics", 0, ["link='panda_hand', offset=[0.05, -0.01, 0.02]", "dof=7"]),
        ("map", "diffeomorphism", 2, ["layers=2", "scale_bound=2.0", "out_features=6"]),
        ("weight", "constant", 0, ["Constant(in_dim=2, value=2.5)"]),
        ("weight", "rbf", 1, ["low=2.0, high=0.1, sigma=1.0", "const=[1.0, -1.0]"]),
        ("weight", "logistic", 0, ["steepness=-3.0, switch_distance=0.5", "aux='obstacle_center'"]),
        ("weight", "mlp", 0, ["hidden=[16, 16]", "aux=['goal', 'obstacle_center', 'obstacle_radius']", "floor=0.001"]),
    ],
)
def test_the_repr_shows_the_numbers(kind, name, example, shown):
    text = repr(built(kind, name, example))
    for part in shown:
        assert part in text, f"{part!r} not in {text}"


def test_a_learned_number_shows_its_current_value():
    leaf = built("leaf", "goal_attractor", 2)  # gain in (0, 5), w_u and sigma in (0, ∞), all learned
    assert "gain=2.0" in repr(leaf) and "w_u=10.0" in repr(leaf) and "sigma=0.7" in repr(leaf)
    with torch.no_grad():
        leaf.gain_raw.fill_(0.0)  # gain = 5·sigmoid(0)
        leaf.sigma_raw.fill_(0.5)  # sigma = exp(0.5) = 1.6487...: 4 significant digits
    assert "gain=2.5" in repr(leaf) and "sigma=1.649" in repr(leaf) and f"{math.exp(0.5)}" not in repr(leaf)


def test_a_big_tensor_is_shown_by_its_shape():
    entry = TASK_MAPS.get("linear")
    m = entry.obj(entry.validate({"matrix": torch.eye(4).tolist()}), 4, {})
    assert "matrix=tensor(shape=(4, 4)), bias=[0.0, 0.0, 0.0, 0.0]" in repr(m)
    assert (
        numbers_repr({"n": 3, "x": 0.1, "t": torch.tensor(2.0 / 3.0), "flag": True})
        == "n=3, x=0.1, t=0.6667, flag=True"
    )


def test_print_tree_shows_every_node_numbers():
    tree = rmpfusion.build_tree(
        {
            "root": {"name": "q", "dim": 2},
            "nodes": {
                "goal": {
                    "parent": "q",
                    "map": {"type": "offset", "origin": [1.0, -2.0]},
                    "weight": {"type": "constant", "value": 4.0},
                    "rmp": {"type": "goal_attractor", "gain": 3.0, "alpha": 10.0, "eta": 2.0},
                },
                "damp": {"parent": "q", "map": {"type": "identity"}, "rmp": {"type": "damper", "w": 0.1}},
            },
        }
    )
    text = str(tree)
    for part in ("GoalAttractor(dim=2, gain=3.0, alpha=10.0, eta=2.0", "const=[1.0, -2.0]", "value=4.0", "w=0.1"):
        assert part in text, f"{part!r} not in {text}"


# ------------------------------------------------------------------------------------- every entry has its own
def without_extra_repr(registry: Registry) -> list[str]:
    """The built-in entries of ``registry`` whose class shows nothing of itself (``nn.Module``'s empty
    ``extra_repr``); plugins' entries are their authors' to describe."""
    return [
        e.name
        for e in registry.entries()
        if e.owner.startswith("rmpfusion.") and e.obj.extra_repr is nn.Module.extra_repr
    ]


@pytest.mark.parametrize("kind", sorted(KINDS))
def test_every_registered_class_defines_extra_repr(kind):
    assert KINDS[kind].names(), f"no {kind} is registered"
    assert without_extra_repr(KINDS[kind]) == []


def test_a_class_without_extra_repr_is_named():
    class Bare(TaskMap):
        class Params(Params):
            pass

    Bare.__module__ = "rmpfusion.maps.bare"  # counted as a built-in
    isolated = Registry("task map")
    isolated.register("bare")(Bare)
    isolated.register("identity")(TASK_MAPS.get("identity").obj)
    assert without_extra_repr(isolated) == ["bare"]


@pytest.mark.parametrize("kind", sorted(KINDS))
def test_every_example_shows_something(kind):
    """Each class's own ``extra_repr`` says something on every example it declares (at least its dimensions)."""
    empty = [
        f"{e.name}[{i}]"
        for e in KINDS[kind].entries()
        if e.owner.startswith("rmpfusion.")
        for i in range(len(e.examples))
        if not built(kind, e.name, i).extra_repr()
    ]
    assert empty == []
