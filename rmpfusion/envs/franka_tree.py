"""The Franka Panda RMP-tree* of the paper (Fig. 1b, App. D.2) as a generated spec.

The tree's shape depends on the control points and on how many obstacles are present at run time: every
obstacle adds one distance node under every control point. Generating the spec (rather than hand-writing
YAML) keeps those nodes consistent, and lets a tree trained with one obstacle be rebuilt for several: the
obstacle weight on a control point is one entry of ``shared_weights`` used by all of that point's
distance edges, each edge binding the generic aux names ``obstacle_center``/``obstacle_radius`` to its
own obstacle. ``conf/tree/franka.yaml`` is ``franka_tree_spec(DEFAULT_CONTROL_POINTS, 1)`` written out.
"""
from __future__ import annotations

import copy

import torch
from typing import Any, Mapping, Sequence

from ..maps.urdf import PANDA_ARM_JOINTS, load_panda_urdf_path, parse_urdf

from ..build.weighting import tree_with_weights as with_weights  # noqa: F401  (expert configs: node or shared-weight names)

# Spheres covering the Panda's collision meshes from link3 to the closed fingers, in each link's frame:
# a k-means fit of the mesh vertices, each radius covering its cluster (rounded up by ~5 mm).
DEFAULT_CONTROL_POINTS: list[dict[str, Any]] = [
    {"link": "panda_link3", "offset": [-0.024, -0.016, -0.076], "radius": 0.10},
    {"link": "panda_link3", "offset": [0.097, 0.074, 0.015], "radius": 0.095},
    {"link": "panda_link4", "offset": [0.014, -0.015, 0.076], "radius": 0.095},
    {"link": "panda_link4", "offset": [-0.105, 0.079, -0.015], "radius": 0.095},
    {"link": "panda_link5", "offset": [0.0, 0.099, 0.021], "radius": 0.10},
    {"link": "panda_link5", "offset": [0.0, 0.04, -0.11], "radius": 0.08},
    {"link": "panda_link5", "offset": [0.0, 0.075, -0.209], "radius": 0.085},
    {"link": "panda_link5", "offset": [-0.005, -0.035, -0.244], "radius": 0.085},
    {"link": "panda_link6", "offset": [0.089, 0.071, 0.0], "radius": 0.095},
    {"link": "panda_link6", "offset": [0.035, -0.011, 0.021], "radius": 0.11},
    {"link": "panda_link7", "offset": [0.02, 0.019, 0.083], "radius": 0.085},
    {"link": "panda_hand", "offset": [0.0, 0.089, 0.025], "radius": 0.07},
    {"link": "panda_hand", "offset": [0.0, -0.092, 0.023], "radius": 0.07},
    {"link": "panda_hand", "offset": [0.0, 0.0, 0.089], "radius": 0.095},
]

# The fingertip centre of the closed gripper, in the panda_hand frame (Franka's TCP is 0.1034 m from the flange).
EE_LINK = "panda_hand"
EE_OFFSET = [0.0, 0.0, 0.1034]

# Leaf parameters tuned for metre/radian scales of the Panda; all GDSs, so Theorem 2 holds for any weights.
# The obstacle barrier's potential gain (alpha) makes its force exceed the attractor's within ~1 cm of a control
# sphere touching an obstacle, so no weighting that keeps obstacle weights near 1 can press the arm into it
# (with 1e-4 untrained learners pushed through cylinders in pybullet; 1e-2 keeps ≥ 4 cm in the same scenes).
ATTRACTOR_RMP = {"type": "goal_attractor", "gain": 5.0, "alpha": 10.0, "eta": 5.0, "w_u": 1.0, "w_l": 1.0, "sigma": 1.0}
OBSTACLE_RMP = {"type": "collision_avoidance", "r_w": 0.15, "sigma": 0.5, "epsilon": 0.2, "alpha": 1e-2, "eta": 0.0,
                "min_distance": 0.005}
JOINT_LIMIT_RMP = {"type": "joint_limit", "r_w": 0.25, "sigma": 0.5, "epsilon": 0.1, "alpha": 1e-3, "eta": 0.0}
DAMPER_RMP = {"type": "damper", "w": 1.0, "eta": 20.0}
IDENTITY_RMP = {"type": "identity_metric", "scale": 0.01}

# The learner's weight functions: positive MLPs of the parent configuration and the relevant aux state, randomly
# initialised (learner-0 is the paper's untrained tree). w = floor + exp(MLP): the expert's weights span 1 to 200,
# which an exponential reaches in a few hundred ADAM steps where softplus needs its output to grow linearly
# (validation loss after 1500 iterations 0.12 with exp vs 1.69 with softplus, 20 held-out demonstrations).
ATTRACTOR_WEIGHT = {"type": "mlp", "hidden": [32, 32], "aux": ["goal"], "positivity": "exp"}
OBSTACLE_WEIGHT = {"type": "mlp", "hidden": [32, 32], "aux": ["obstacle_center", "obstacle_radius"], "positivity": "exp"}


def _cp_fields(cp: Mapping[str, Any], i: int) -> tuple[str, list[float], float]:
    if "link" not in cp:
        raise ValueError(f"control point {i} needs a 'link' (got keys {sorted(cp)})")
    extra = set(cp) - {"link", "offset", "radius"}
    if extra:
        raise ValueError(f"control point {i} has unknown keys {sorted(extra)}; allowed: link, offset, radius")
    offset = [float(v) for v in cp.get("offset", [0.0, 0.0, 0.0])]
    if len(offset) != 3:
        raise ValueError(f"control point {i}: offset needs 3 numbers, got {offset}")
    radius = float(cp.get("radius", 0.0))
    if radius < 0:
        raise ValueError(f"control point {i}: radius must be ≥ 0, got {radius}")
    return str(cp["link"]), offset, radius


def franka_tree_spec(
    control_points: Sequence[Mapping[str, Any]] | None = None,
    n_obstacles: int = 1,
    obstacle_distance: str = "cylinder_distance",
) -> dict[str, Any]:
    """The Panda tree spec (docs/architecture.md §2) for these control points and this many obstacles.

    Weighted edges (learnable, MLPs): ee→attractor and every control point→distance edge, the latter
    shared across obstacles per control point. Joint limits, the damper and the identity metric carry
    no weight, as in the paper. ``obstacle_distance`` is ``cylinder_distance`` (vertical, infinite:
    conservative for a standing cylinder) or ``sphere_distance``.
    """
    if control_points is None:
        control_points = DEFAULT_CONTROL_POINTS
    if n_obstacles < 0:
        raise ValueError(f"n_obstacles must be ≥ 0, got {n_obstacles}")
    if obstacle_distance not in ("cylinder_distance", "sphere_distance"):
        raise ValueError(f"obstacle_distance must be cylinder_distance or sphere_distance, got {obstacle_distance!r}")
    lower, upper = (t.tolist() for t in _panda_limits())
    aux: dict[str, int] = {"goal": 3}
    for k in range(1, n_obstacles + 1):
        aux[f"obstacle{k}_center"] = 3
        aux[f"obstacle{k}_radius"] = 1
    # generic names the shared obstacle weights read; every edge binds them to its own obstacle
    aux["obstacle_center"] = 3
    aux["obstacle_radius"] = 1

    nodes: dict[str, Any] = {
        "ee": {"parent": "q", "map": {"type": "forward_kinematics", "robot": "panda", "link": EE_LINK,
                                      "offset": list(EE_OFFSET)}},
        "attractor": {"parent": "ee", "map": {"type": "offset", "origin": "goal"},
                      "weight": copy.deepcopy(ATTRACTOR_WEIGHT), "rmp": dict(ATTRACTOR_RMP)},
    }
    for j in range(7):
        for side, lim in (("upper", upper[j]), ("lower", lower[j])):
            nodes[f"jl{j + 1}_{side}"] = {
                "parent": "q", "map": {"type": "joint_limit", "side": side, "limit": float(lim), "joints": j},
                "rmp": dict(JOINT_LIMIT_RMP),
            }
    shared: dict[str, Any] = {}
    for i, cp in enumerate(control_points, start=1):
        link, offset, radius = _cp_fields(cp, i)
        cp_name = f"cp{i}"
        nodes[cp_name] = {"parent": "q", "map": {"type": "forward_kinematics", "robot": "panda", "link": link,
                                                  "offset": offset}}
        if n_obstacles:
            shared[f"{cp_name}_obstacle"] = copy.deepcopy(OBSTACLE_WEIGHT)
        for k in range(1, n_obstacles + 1):
            dist = {"type": obstacle_distance, "center": f"obstacle{k}_center", "radius": f"obstacle{k}_radius"}
            nodes[f"{cp_name}_obstacle{k}"] = {
                "parent": cp_name,
                # the control point is a sphere: subtract its radius so 0 means touching
                "map": {"type": "compose", "maps": [dist, {"type": "offset", "origin": [radius]}]},
                "weight": {"shared": f"{cp_name}_obstacle",
                           "bind": {"obstacle_center": f"obstacle{k}_center", "obstacle_radius": f"obstacle{k}_radius"}},
                "rmp": dict(OBSTACLE_RMP),
            }
        if not n_obstacles:  # a control point without obstacles would be a leaf without an RMP
            del nodes[cp_name]
    nodes["damper"] = {"parent": "q", "map": {"type": "identity"}, "rmp": dict(DAMPER_RMP)}
    nodes["identity_metric"] = {"parent": "q", "map": {"type": "identity"}, "rmp": dict(IDENTITY_RMP)}
    return {
        "description": (f"Franka Panda (paper Fig. 1b): end-effector attractor, 14 joint-limit barriers, "
                        f"{len(control_points)} control points x {n_obstacles} obstacle(s) with weights shared "
                        f"across obstacles, damper and identity metric on the root"),
        "root": {"name": "q", "dim": 7},
        "aux": aux,
        "shared_weights": shared,
        "nodes": nodes,
    }


def _panda_limits():
    from ..maps.kinematics import Chain

    return Chain(parse_urdf(load_panda_urdf_path()), PANDA_ARM_JOINTS).joint_limits()


def copy_weights(src: torch.nn.Module, dst: torch.nn.Module) -> list[str]:
    """Copy weight-function parameters from tree ``src`` into tree ``dst`` by node / shared-weight name.

    A tree trained with one obstacle thus runs with several: ``dst``'s extra obstacle edges use the same
    shared modules. Returns the names copied; weights present in ``dst`` but not in ``src`` are left as
    they are, and a name in both with different shapes is an error.
    """
    copied = []
    for name, mod in src.shared.items():
        if name in dst.shared:
            dst.shared[name].load_state_dict(mod.state_dict())
            copied.append(name)
    for name, bw in src.weights.items():
        if name in dst.weights and not any(bw.fn is s for s in src.shared.values()):
            dst.weights[name].fn.load_state_dict(bw.fn.state_dict())
            copied.append(name)
    return copied


def write_default_yaml(path: str) -> None:
    """Write ``franka_tree_spec(DEFAULT_CONTROL_POINTS, 1)`` as the YAML tree config."""
    import yaml

    header = ("# Generated by rmpfusion.envs.franka_tree.write_default_yaml: franka_tree_spec(DEFAULT_CONTROL_POINTS, 1).\n"
              "# Edit the generator (or call it with other control points / obstacle counts), not this file;\n"
              "# tests/test_franka.py checks the two agree.\n")
    with open(path, "w", encoding="utf-8") as f:
        f.write(header)
        yaml.safe_dump(franka_tree_spec(DEFAULT_CONTROL_POINTS, 1), f, sort_keys=False, default_flow_style=None, width=120)
