"""The manipulator RMP-tree* of the paper (Fig. 1b, App. D.2) for any robot and scene, as a generated spec.

The tree's shape depends on the robot's control points and on the scene's obstacles: every obstacle adds one
distance node under every control point (and a ground plane one more). Generating the spec keeps those nodes
consistent, and lets a tree trained in one scene be rebuilt for another: the obstacle weight on a control point is
one entry of ``shared_weights`` used by all of that point's obstacle edges, each edge binding the generic aux names
``obstacle_center``/``obstacle_radius`` to its own obstacle. The generator is registered as ``fig1b``, so
``conf/tree/fig1b.yaml`` declares it and its parameters (``build.generated.expand_tree``); its robot and scene are
the environment's (``${env.robot}``, ``${env.scene}``), so the two cannot disagree.
"""
from __future__ import annotations

import copy
from typing import Any, Literal, Mapping

import torch
from pydantic import Field, field_validator

from ..build.weighting import tree_with_weights as with_weights  # noqa: F401  (expert configs: node or shared-weight names)
from ..registry import TREE_GENERATORS, Params
from ..rmps.gds_leaves import CollisionAvoidance, Damper, GoalAttractor, IdentityMetric, JointLimitBarrier
from ..robots import RobotField
from ..scenes import Scene, obstacle_map, scene_aux_dims
from ..weights.neural import MLPWeight

# Leaf parameters tuned for metre/radian scales of an arm; all GDSs, so Theorem 2 holds for any weights.
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
GROUND_WEIGHT = {"type": "mlp", "hidden": [32, 32], "aux": [], "positivity": "exp"}


_LEAVES: dict[str, Mapping[str, Any]] = {
    "attractor_rmp": ATTRACTOR_RMP, "obstacle_rmp": OBSTACLE_RMP, "joint_limit_rmp": JOINT_LIMIT_RMP,
    "damper_rmp": DAMPER_RMP, "identity_rmp": IDENTITY_RMP,
    "attractor_weight": ATTRACTOR_WEIGHT, "obstacle_weight": OBSTACLE_WEIGHT, "ground_weight": GROUND_WEIGHT,
}


def _tuned(field: str) -> dict[str, Any]:
    return {k: copy.deepcopy(v) for k, v in _LEAVES[field].items() if k != "type"}


def _tuned_field(model: type[Params], field: str, what: str) -> Any:
    """A leaf's (or weight's) settings, checked by that entry's own parameter model, defaulting to the tuned ones."""
    return Field(default_factory=lambda: model(**_tuned(field)),
                 description=f"{what} ({_LEAVES[field]['type']}); keys given replace the tuned values one by one")


class ManipulatorTreeParams(Params):
    """Parameters of the Fig. 1b tree: the robot and the scene (the environment's), and the leaves' settings.

    The end-effector point is the robot's (``robot.end_effector``): the environment measures reaching and success
    at that same point, so the two cannot differ.
    """

    robot: RobotField = Field(description="the robot description (conf/robot/), usually ${env.robot}")
    scene: Scene = Field(default_factory=Scene, description="the scene (conf/scene/), usually ${env.scene}: one "
                                                            "distance node per control point and obstacle")
    obstacle_maps: dict[Literal["sphere", "box", "cylinder", "capsule"], str] = Field(
        default_factory=dict, description="per shape, the map measuring it instead of the default "
                                          "(cylinder: cylinder_distance, a vertical infinite cylinder)")
    attractor_rmp: GoalAttractor.Params = _tuned_field(GoalAttractor.Params, "attractor_rmp", "end-effector attractor")
    obstacle_rmp: CollisionAvoidance.Params = _tuned_field(CollisionAvoidance.Params, "obstacle_rmp",
                                                           "barrier on every control point's obstacle distance")
    joint_limit_rmp: JointLimitBarrier.Params = _tuned_field(JointLimitBarrier.Params, "joint_limit_rmp",
                                                             "barrier on each finite joint limit")
    damper_rmp: Damper.Params = _tuned_field(Damper.Params, "damper_rmp", "damper on the root")
    identity_rmp: IdentityMetric.Params = _tuned_field(IdentityMetric.Params, "identity_rmp",
                                                       "identity metric on the root")
    attractor_weight: MLPWeight.Params = _tuned_field(MLPWeight.Params, "attractor_weight",
                                                      "learnable weight of the ee -> attractor edge")
    obstacle_weight: MLPWeight.Params = _tuned_field(MLPWeight.Params, "obstacle_weight",
                                                     "learnable weight shared by one control point's obstacle edges")
    ground_weight: MLPWeight.Params = _tuned_field(MLPWeight.Params, "ground_weight",
                                                   "learnable weight shared by every control point's ground edge")

    @field_validator(*_LEAVES, mode="before")
    @classmethod
    def _onto_tuned(cls, v: Any, info: Any) -> Any:
        # a partial block ({gain: 3}) changes those keys only, not the rest back to the entry's generic defaults
        return {**_tuned(info.field_name), **v} if isinstance(v, Mapping) else v

    @field_validator("obstacle_maps")
    @classmethod
    def _measuring_maps(cls, v: dict[str, str]) -> dict[str, str]:
        allowed = {"cylinder": ("cylinder_obstacle", "cylinder_distance")}
        for shape, name in v.items():
            options = allowed.get(shape, (f"{shape}_obstacle",))
            if name not in options:
                raise ValueError(f"obstacle_maps.{shape}: {name!r} does not measure a {shape}; one of {list(options)}")
        return v


def _entry(p: ManipulatorTreeParams, field: str) -> dict[str, Any]:
    """``{type, **settings}`` as written in a tree spec; only keys that were set, so defaults stay the entry's."""
    return {"type": _LEAVES[field]["type"], **getattr(p, field).model_dump(exclude_unset=True)}


def _point(p: ManipulatorTreeParams, link: str, offset) -> dict[str, Any]:
    """The forward-kinematics map to a point fixed in one of the robot's links."""
    r = p.robot
    return {"type": "forward_kinematics", "urdf": r.urdf, "joints": list(r.joints), "link": link,
            "offset": [float(v) for v in offset]}


def _surface(dist: dict[str, Any], radius: float) -> dict[str, Any]:
    """A distance from a control sphere's surface: the centre's distance minus the radius (0 means touching)."""
    return {"type": "compose", "maps": [dist, {"type": "offset", "origin": [float(radius)]}]}


def _control_point_nodes(p: ManipulatorTreeParams, i: int, cp) -> tuple[dict[str, Any], dict[str, Any]]:
    """Control point ``i``'s node, its obstacle (and ground) edges, and its shared obstacle weight."""
    name, scene = f"cp{i}", p.scene
    nodes: dict[str, Any] = {name: {"parent": "q", "map": _point(p, cp.link, cp.offset)}}
    shared = {f"{name}_obstacle": _entry(p, "obstacle_weight")} if scene.obstacles else {}
    for k, o in enumerate(scene.obstacles, start=1):
        dist = obstacle_map(k, o.type, o.moving, p.obstacle_maps.get(o.type))
        nodes[f"{name}_obstacle{k}"] = {
            "parent": name, "map": _surface(dist, cp.radius),
            "weight": {"shared": f"{name}_obstacle",
                       "bind": {"obstacle_center": f"obstacle{k}_center", "obstacle_radius": f"obstacle{k}_radius"}},
            "rmp": _entry(p, "obstacle_rmp"),
        }
    if scene.ground is not None:
        plane = {"type": "plane_distance", "normal": [0.0, 0.0, 1.0], "height": float(scene.ground.height)}
        nodes[f"{name}_ground"] = {"parent": name, "map": _surface(plane, cp.radius), "weight": {"shared": "ground"},
                                   "rmp": _entry(p, "obstacle_rmp")}
    if len(nodes) == 1:  # a control point without obstacles would be a leaf without an RMP
        nodes = {}
    return nodes, shared


@TREE_GENERATORS.register("fig1b", params=ManipulatorTreeParams)
def fig1b(p: ManipulatorTreeParams) -> dict[str, Any]:
    """The tree spec (docs/architecture.md §2) of paper Fig. 1b for the robot and scene, from validated parameters.

    Weighted edges (learnable, MLPs): ee→attractor, every control point→obstacle edge (shared across obstacles
    per control point) and every control point→ground edge (one shared weight). Joint limits, the damper and the
    identity metric carry no weight, as in the paper.
    """
    r = p.robot
    aux: dict[str, int] = {"goal": 3, **scene_aux_dims(p.scene)}
    if p.scene.obstacles:  # generic names the shared obstacle weights read; every edge binds them to its own obstacle
        aux["obstacle_center"] = 3
        aux["obstacle_radius"] = 1
    nodes: dict[str, Any] = {
        "ee": {"parent": "q", "map": _point(p, r.end_effector.link, r.end_effector.offset)},
        "attractor": {"parent": "ee", "map": {"type": "offset", "origin": "goal"},
                      "weight": _entry(p, "attractor_weight"), "rmp": _entry(p, "attractor_rmp")},
    }
    for j, side, lim in r.finite_limits():
        nodes[f"jl{j + 1}_{side}"] = {"parent": "q", "map": {"type": "joint_limit", "side": side, "limit": float(lim),
                                                             "joints": j}, "rmp": _entry(p, "joint_limit_rmp")}
    shared: dict[str, Any] = {"ground": _entry(p, "ground_weight")} if p.scene.ground is not None else {}
    for i, cp in enumerate(r.control_points, start=1):
        more, weights = _control_point_nodes(p, i, cp)
        nodes.update(more)
        shared.update(weights)
    nodes["damper"] = {"parent": "q", "map": {"type": "identity"}, "rmp": _entry(p, "damper_rmp")}
    nodes["identity_metric"] = {"parent": "q", "map": {"type": "identity"}, "rmp": _entry(p, "identity_rmp")}
    n_limits, n_obs = len(r.finite_limits()), len(p.scene.obstacles)
    ground = " and the ground" if p.scene.ground is not None else ""
    return {
        "description": (f"{r.name} (paper Fig. 1b): end-effector attractor, {n_limits} joint-limit barriers, "
                        f"{len(r.control_points)} control points x {n_obs} obstacle(s){ground} with weights shared "
                        f"across obstacles, damper and identity metric on the root"),
        "root": {"name": "q", "dim": len(r.joints)},
        "aux": aux,
        "shared_weights": shared,
        "nodes": nodes,
    }


def manipulator_tree_spec(robot: Mapping[str, Any], scene: Mapping[str, Any] | Scene | None = None,
                          **settings: Any) -> dict[str, Any]:
    """The tree spec for a robot description and a scene (Python callers' entry; ``settings`` are the other
    :class:`ManipulatorTreeParams` keys). Checked by the same model as ``generator: fig1b`` in YAML, so a bad
    value raises pydantic's ValidationError (a ValueError) naming the key."""
    given: dict[str, Any] = {"robot": robot, **settings}
    if scene is not None:
        given["scene"] = scene
    return fig1b(ManipulatorTreeParams.model_validate(given))


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

