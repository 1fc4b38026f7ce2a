"""Every robot leaf in one Panda tree, each edge with a random positive neural weight: Theorem 2's identity at
arbitrary states (velocities inside the velocity cap's band included), level-batched evaluation equal to the
node-by-node computation, and the compiled tree equal to the eager one."""

import copy

import pytest
import torch
from conftest import assert_energy_identity
from manipulators import PANDA_ARM as PANDA
from manipulators import PANDA_HOME as HOME
from reference_tree import FIELDS, node_by_node

import rmpfusion


def mlp(*aux):
    return {"type": "mlp", "hidden": [8], "activation": "tanh", "aux": list(aux)}


def every_robot_leaf_tree():
    torch.manual_seed(0)
    tree = rmpfusion.build_tree(
        {
            "root": {"name": "q", "dim": 7},
            "aux": {"goal": 3, "goal_velocity": 3, "tool_direction": 3, "frame": 4},
            "nodes": {
                "ee": {
                    "parent": "q",
                    "map": {"type": "forward_kinematics", **PANDA, "link": "panda_hand", "offset": [0, 0, 0.1]},
                },
                "track": {
                    "parent": "ee",
                    "map": {"type": "moving_offset", "origin": "goal", "velocity": "goal_velocity"},
                    "weight": mlp("goal_velocity"),
                    "rmp": {"type": "moving_goal_attractor", "gain": 5.0, "alpha": 10.0},
                },
                "tool": {
                    "parent": "q",
                    "map": {"type": "link_axis", **PANDA, "link": "panda_hand", "target": "tool_direction"},
                    "weight": mlp("tool_direction"),
                    "rmp": {"type": "orientation_attractor", "gain": 3.0, "w_u": 4.0},
                },
                "frame": {
                    "parent": "q",
                    "map": {
                        "type": "link_orientation",
                        **PANDA,
                        "link": "panda_link6",
                        "target": "frame",
                        "axes": [[1, 0, 0], [0, 1, 0]],
                    },
                    "weight": mlp("frame"),
                    "rmp": {"type": "orientation_attractor"},
                },
                "self": {
                    "parent": "q",
                    "map": {
                        "type": "link_sphere_distance",
                        **PANDA,
                        "a": {"link": "panda_link3", "offset": [0.1, 0.07, 0.0], "radius": 0.1},
                        "b": {"link": "panda_hand", "offset": [0, 0, 0.09], "radius": 0.09},
                    },
                    "weight": mlp(),
                    "rmp": {"type": "collision_avoidance", "r_w": 1.0, "alpha": 0.1, "eta": 0.5},
                },
                "speed": {
                    "parent": "q",
                    "map": {"type": "velocity_scaled_joints", **PANDA},
                    "weight": mlp(),
                    "rmp": {"type": "velocity_limit", "eta": 2.0},
                },
                **{
                    f"posture{k}": {
                        "parent": "q",
                        "map": {"type": "offset", "origin": (HOME + 0.1 * k).tolist()},
                        "weight": mlp(),
                        "rmp": {"type": "orientation_attractor", "gain": 1.0 + k, "sigma": 0.3 + k},
                    }
                    for k in range(2)
                },  # two orientation attractors of one group (their numbers stacked)
                "regulariser": {"parent": "q", "map": {"type": "identity"}, "rmp": {"type": "identity_metric"}},
            },
        }
    )
    g = torch.Generator().manual_seed(3)
    with torch.no_grad():
        for p in tree.parameters():
            p.copy_(0.5 * torch.randn(p.shape, generator=g))
    return tree


def inputs(B: int, seed: int):
    g = torch.Generator().manual_seed(seed)
    q = HOME + 0.4 * torch.randn(B, 7, generator=g)
    qd = 2.2 * (2 * torch.rand(B, 7, generator=g) - 1)  # up to the Panda's limits: some joints in the cap's band
    aux = {
        "goal": torch.tensor([0.5, 0.0, 0.4]) + 0.1 * torch.randn(B, 3, generator=g),
        "goal_velocity": 0.2 * torch.randn(B, 3, generator=g),
        "tool_direction": torch.randn(B, 3, generator=g),
        "frame": torch.randn(B, 4, generator=g),
    }
    return q, qd, aux


def test_theorem_2_identity_with_every_robot_leaf_and_neural_weights():
    tree = every_robot_leaf_tree()
    q, qd, aux = inputs(16, 0)
    speed = qd.abs() / torch.tensor([2.175] * 4 + [2.61] * 3)
    assert ((speed > 0.8) & (speed < 1.0)).any()  # the cap acts at some of these states
    assert_energy_identity(tree, q, qd, aux)


def test_level_batched_evaluation_equals_the_node_by_node_computation():
    tree = every_robot_leaf_tree()
    assert any(g.nodes == ["posture0", "posture1"] for g in tree.plan.groups)
    q, qd, aux = inputs(5, 2)
    out, ref = tree(q, qd, aux), node_by_node(tree, q, qd, aux)
    for field in (*FIELDS, "qdd"):
        torch.testing.assert_close(getattr(out, field), ref[field], rtol=1e-12, atol=1e-12)


@pytest.mark.slow
def test_the_compiled_tree_equals_the_eager_one():
    """torch.compile of every robot leaf and map (about 90 s on 2 cores)."""
    eager = every_robot_leaf_tree()
    fast = copy.deepcopy(eager).compile(dynamic=False)
    q, qd, aux = inputs(4, 1)
    with torch.no_grad():
        a, b = eager(q, qd, aux), fast(q, qd, aux)
    for field in ("qdd", "f", "M", "G", "B", "Phi", "V"):
        torch.testing.assert_close(getattr(b, field), getattr(a, field), rtol=1e-9, atol=1e-9)
