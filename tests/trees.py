"""Trees several test modules share: the two-level 2-D tree with its inputs, random trees of depth ≥ 2 with
random positive neural weights (and their start states), and a tree whose nodes group when evaluated level by
level."""

import random

import torch

import rmpfusion

TWO_LEVEL = {
    "root": {"name": "q", "dim": 2},
    "aux": {"goal": 2, "obstacle1_center": 2, "obstacle1_radius": 1, "obstacle2_center": 2, "obstacle2_radius": 1},
    "nodes": {
        "goal": {
            "parent": "q",
            "map": {"type": "offset", "origin": "goal"},
            "weight": {"type": "mlp", "hidden": [16, 16], "aux": ["goal", "obstacle1_center", "obstacle2_center"]},
            "rmp": {"type": "goal_attractor", "w_u": 4.0, "w_l": 1.0},
        },
        "obstacles": {
            "parent": "q",
            "map": {"type": "identity"},
            "weight": {"type": "mlp", "hidden": [16], "aux": ["obstacle1_center", "obstacle1_radius"]},
        },
        "o1": {
            "parent": "obstacles",
            "map": {"type": "sphere_distance", "center": "obstacle1_center", "radius": "obstacle1_radius"},
            "weight": {"type": "mlp", "hidden": [8], "aux": ["obstacle1_center"]},
            "rmp": {"type": "collision_avoidance", "r_w": 1.5},
        },
        "o2": {
            "parent": "obstacles",
            "map": {"type": "sphere_distance", "center": "obstacle2_center", "radius": "obstacle2_radius"},
            "weight": {
                "type": "rbf",
                "low": 0.5,
                "high": 2.0,
                "center": "obstacle2_center",
                "radius": "obstacle2_radius",
            },
            "rmp": {"type": "collision_avoidance", "r_w": 1.5},
        },
        "damp": {"parent": "q", "map": {"type": "identity"}, "rmp": {"type": "damper", "w": 0.1, "eta": 1.0}},
    },
}


def two_level_inputs(B, gen):
    q = 3 * torch.randn(B, 2, generator=gen)
    aux = {
        "goal": torch.randn(B, 2, generator=gen) * 2,
        "obstacle1_center": torch.randn(B, 2, generator=gen),
        "obstacle1_radius": 0.3 + 0.3 * torch.rand(B, 1, generator=gen),
        "obstacle2_center": torch.randn(B, 2, generator=gen) + 2,
        "obstacle2_radius": 0.3 + 0.3 * torch.rand(B, 1, generator=gen),
    }
    # keep the particle outside both obstacles
    for k in (1, 2):
        d = q - aux[f"obstacle{k}_center"]
        r = d.norm(dim=-1, keepdim=True)
        q = torch.where(
            r < aux[f"obstacle{k}_radius"] + 0.1,
            aux[f"obstacle{k}_center"] + d / r * (aux[f"obstacle{k}_radius"] + 0.3),
            q,
        )
    return q, torch.randn(B, 2, generator=gen), aux


def random_tree_spec(seed: int, dim: int) -> dict:
    rng = random.Random(seed)
    act = lambda: rng.choice(["tanh", "softplus", "elu", "silu"])
    mlp = lambda aux: {
        "type": "mlp",
        "hidden": [rng.choice([4, 8, 16])] * rng.choice([1, 2]),
        "activation": act(),
        "positivity": rng.choice(["softplus", "exp"]),
        "aux": aux,
    }
    barrier = lambda: {
        "type": "collision_avoidance",
        "r_w": rng.uniform(1.0, 3.0),
        "sigma": rng.uniform(0.3, 1.0),
        "epsilon": rng.uniform(0.05, 0.5),
        "alpha": rng.uniform(0.0, 0.5),
        "eta": rng.uniform(0.0, 1.0),
    }
    A = [[rng.uniform(-1, 1) + (1.5 if i == j else 0.0) for j in range(dim)] for i in range(dim)]
    return {
        "root": {"name": "q", "dim": dim},
        "aux": {"goal": dim, "c1": dim, "c2": dim, "c3": dim},
        "nodes": {
            "regulariser": {
                "parent": "q",
                "map": {"type": "identity"},
                "rmp": {"type": "identity_metric", "scale": 0.05},
            },
            "goal": {
                "parent": "q",
                "map": {"type": "offset", "origin": "goal"},
                "weight": mlp(["goal"]),
                "rmp": {
                    "type": "goal_attractor",
                    "w_u": rng.uniform(1, 8),
                    "w_l": rng.uniform(0.5, 2),
                    "sigma": rng.uniform(0.5, 2),
                    "gain": rng.uniform(0.5, 3),
                    "alpha": rng.uniform(0.5, 3),
                    "eta": rng.uniform(0.5, 3),
                },
            },
            "obstacles": {"parent": "q", "map": {"type": "linear", "matrix": A}, "weight": mlp(["c1", "c2"])},
            "o1": {
                "parent": "obstacles",
                "map": {"type": "sphere_distance", "center": "c1", "radius": 0.5},
                "weight": mlp(["c1"]),
                "rmp": barrier(),
            },
            "o2": {
                "parent": "obstacles",
                "map": {"type": "sphere_distance", "center": "c2", "radius": 0.4},
                "weight": {
                    "type": "logistic",
                    "low": 0.3,
                    "high": 3.0,
                    "center": "c2",
                    "steepness": -2.0,
                    "switch_distance": 0.5,
                },
                "rmp": barrier(),
            },
            "deeper": {"parent": "obstacles", "map": {"type": "identity"}, "weight": mlp(["c3"])},
            "o3": {
                "parent": "deeper",
                "map": {"type": "sphere_distance", "center": "c3", "radius": 0.3},
                "weight": mlp([]),
                "rmp": barrier(),
            },
            "damp": {
                "parent": "deeper",
                "map": {"type": "identity"},
                "weight": mlp([]),
                "rmp": {"type": "damper", "w": 0.2, "eta": rng.uniform(0.5, 2)},
            },
        },
    }


def randomise_weights(tree, seed):
    g = torch.Generator().manual_seed(seed)
    for p in tree.parameters():
        with torch.no_grad():
            p.copy_(torch.randn(p.shape, generator=g) * 0.3)


def setup(seed, dim, B):
    tree = rmpfusion.build_tree(random_tree_spec(seed, dim))
    randomise_weights(tree, seed)
    g = torch.Generator().manual_seed(seed + 1)
    q = torch.zeros(B, dim)
    q[:, 0] = -3.0
    q = q + 0.3 * torch.randn(B, dim, generator=g)
    aux = {"goal": torch.zeros(B, dim), "c1": torch.zeros(B, dim), "c2": torch.zeros(B, dim), "c3": torch.zeros(B, dim)}
    aux["goal"][:, 0] = 3.0
    aux["c1"][:, 1] = 0.6
    aux["c2"][:, 0], aux["c2"][:, 1] = 1.2, -0.7
    aux["c3"][:, 0] = -1.5
    aux = {k: v + 0.2 * torch.randn(B, dim, generator=g) for k, v in aux.items()}
    qd = 0.5 * torch.randn(B, dim, generator=g)
    return tree, q, qd, aux


def grouping_tree_spec(seed: int, dim: int = 3) -> dict:
    """A tree whose nodes group: several attractors, barriers, joint limits, dampers and distances of each kind,
    every member with its own numbers, aux entries or constants; shared and unshared neural weights, designed
    weights and unweighted edges; three levels."""
    rng = random.Random(seed)
    u = rng.uniform
    vec = lambda: [u(-1.5, 1.5) for _ in range(dim)]
    mlp = lambda aux: {"type": "mlp", "hidden": [6, 6], "activation": rng.choice(["tanh", "silu"]), "aux": aux}
    barrier = lambda: {
        "type": "collision_avoidance",
        "r_w": u(1.5, 3.0),
        "sigma": u(0.3, 1.0),
        "epsilon": u(0.05, 0.5),
        "alpha": u(0.0, 0.5),
        "eta": u(0.0, 1.0),
        "min_distance": u(1e-3, 0.1),
    }
    attractor = lambda: {
        "type": "goal_attractor",
        "w_u": u(1, 8),
        "w_l": u(0.5, 2),
        "sigma": u(0.5, 2),
        "gain": u(0.5, 3),
        "alpha": u(0.5, 3),
        "eta": u(0.5, 3),
    }
    nodes = {
        "regulariser": {
            "parent": "q",
            "map": {"type": "identity"},
            "rmp": {"type": "identity_metric", "scale": u(0.01, 0.1)},
        },
        "damper": {
            "parent": "q",
            "map": {"type": "identity"},
            "rmp": {"type": "damper", "w": u(0.1, 1), "eta": u(0.5, 2)},
        },
        "obstacles": {
            "parent": "q",
            "map": {
                "type": "linear",
                "matrix": [[u(-1, 1) + (1.5 if i == j else 0) for j in range(dim)] for i in range(dim)],
            },
            "weight": mlp(["c1"]),
        },
        "inner": {"parent": "q", "map": {"type": "identity"}, "weight": mlp([])},
    }
    for k in range(3):  # attractors: aux or constant goals, shared and own weights
        nodes[f"goal{k}"] = {
            "parent": "q",
            "map": {"type": "offset", "origin": "goal" if k < 2 else vec()},
            "weight": {"shared": "goal_weight"} if k < 2 else mlp(["goal"]),
            "rmp": attractor(),
        }
    for k in range(2):  # attractors without weights
        nodes[f"plain{k}"] = {"parent": "q", "map": {"type": "offset", "origin": vec()}, "rmp": attractor()}
    for j in range(dim):  # joint limits: one per side and joint, each its own limit
        for side in ("upper", "lower"):
            nodes[f"jl{j}_{side}"] = {
                "parent": "q",
                "rmp": {"type": "joint_limit", "r_w": u(0.2, 0.6)},
                "map": {
                    "type": "joint_limit",
                    "side": side,
                    "limit": u(2, 3) * (1 if side == "upper" else -1),
                    "joints": j,
                },
            }
    for k, c in enumerate(("c1", "c2", "c3")):  # distances to aux or constant centres, under a linear map
        nodes[f"o{k}"] = {
            "parent": "obstacles",
            "rmp": barrier(),
            "map": {"type": "sphere_distance", "center": c if k < 2 else vec(), "radius": u(0.2, 0.6)},
            "weight": {"shared": "near", "bind": {"c": c}},
        }
        nodes[f"cyl{k}"] = {
            "parent": "obstacles",
            "rmp": barrier(),
            "map": {"type": "cylinder_distance", "center": c, "radius": u(0.2, 0.6), "axis": vec()},
            "weight": {
                "type": "logistic",
                "low": u(0.3, 1),
                "high": u(2, 4),
                "center": c,
                "steepness": -2.0,
                "switch_distance": u(0.2, 0.8),
            },
        }
        nodes[f"box{k}"] = {
            "parent": "inner",
            "rmp": barrier(),
            "map": {"type": "box_distance", "center": c, "half_extents": [u(0.1, 0.4) for _ in range(dim)]},
        }
        nodes[f"deep{k}"] = {
            "parent": "inner",
            "map": {
                "type": "compose",
                "maps": [
                    {"type": "sphere_distance", "center": c, "radius": u(0.1, 0.3)},
                    {"type": "offset", "origin": [u(0, 0.1)]},
                ],
            },
            "weight": {"type": "rbf", "low": u(0.3, 1), "high": u(2, 4), "center": c, "sigma": u(0.5, 1.5)},
            "rmp": barrier(),
        }
    return {
        "root": {"name": "q", "dim": dim},
        "aux": {"goal": dim, "c": dim, "c1": dim, "c2": dim, "c3": dim},
        "shared_weights": {"goal_weight": mlp(["goal"]), "near": mlp(["c"])},
        "nodes": nodes,
    }


#: the test vector of RMPflow's reference leaves (tests/test_tree.py; tools/bench.py times it beside
#: tests/rmpflow_reference.py)
TEST_VECTOR_SPEC = {
    "root": {"name": "q", "dim": 2},
    "nodes": {
        "obstacle": {
            "parent": "q",
            "map": {"type": "sphere_distance", "center": [0, 0], "radius": 1.0, "normalized": True},
            "rmp": {"type": "rmpflow_collision_avoidance"},
        },
        "goal": {
            "parent": "q",
            "map": {"type": "offset", "origin": [-3, 3]},
            "rmp": {"type": "rmpflow_goal_attractor"},
        },
    },
}
