"""The manipulator RMP-tree* of the paper (Fig. 1b, App. D.2) for any robot and scene, as a generated spec.

The tree's shape depends on the robot's control points and on the scene's obstacles: every obstacle adds one
distance node under every control point (and a ground plane one more, for every control point some joint can
raise or lower: a sphere at a fixed height, on a shoulder that only spins, gets none, nor does a sphere beside a
shoulder axis that reaches below the ground in every configuration). Generating the spec keeps those nodes
consistent, and lets a tree trained in one scene be rebuilt for another: the obstacle weight on a control point is
one entry of ``shared_weights`` used by all of that point's obstacle edges, each edge binding the generic aux names
``obstacle_center``/``obstacle_radius`` to its own obstacle. The generator is registered as ``arm_reach``, so
``conf/tree/arm_reach.yaml`` declares it and its parameters (``build.generated.expand_tree``); its robot and scene are
the environment's (``${env.robot}``, ``${env.scene}``), so the two cannot disagree.
"""

from __future__ import annotations

import copy
import re
from collections.abc import Mapping
from typing import Annotated, Any, Literal

import torch
from pydantic import BeforeValidator, Field, field_validator
from pydantic_core import PydanticCustomError

from ..assembly.spec import check_typed
from ..assembly.weighting import tree_with_weights as with_weights  # noqa: F401  (expert configs: node or shared-weight names)
from ..core.auxstate import AuxOrValue
from ..core.tree import RMPTree
from ..core.weight import BoundWeight
from ..maps.kinematics import Chain
from ..maps.orientation import check_direction
from ..maps.robot_params import Vector3
from ..maps.self_collision import non_adjacent_link_pairs
from ..registry import TREE_GENERATORS, WEIGHTS, Params
from ..rmps.gds_leaves import CollisionAvoidance, Damper, GoalAttractor, IdentityMetric, JointLimitBarrier
from ..rmps.orientation import OrientationAttractor
from ..rmps.velocity_limit import VelocityLimit
from ..robots import RobotField
from ..robots.home import spheres_without_ground_edge
from ..robots.robot import build_robot
from ..scenes import ObstacleSet, Scene, obstacle_map, scene_aux_dims, set_dims, sets_read

# Leaf parameters tuned for metre/radian scales of an arm; all GDSs, so Theorem 2 holds for any weights.
# The obstacle barrier's potential gain (alpha) makes its force exceed the attractor's within ~1 cm of a control
# sphere touching an obstacle, so no weighting that keeps obstacle weights near 1 can press the arm into it
# (with 1e-4 untrained learners pushed through cylinders in pybullet; 1e-2 keeps ≥ 4 cm in the same scenes).
ATTRACTOR_RMP = {"type": "goal_attractor", "gain": 5.0, "alpha": 10.0, "eta": 5.0, "w_u": 1.0, "w_l": 1.0, "sigma": 1.0}
OBSTACLE_RMP = {
    "type": "collision_avoidance",
    "r_w": 0.15,
    "sigma": 0.5,
    "epsilon": 0.2,
    "alpha": 1e-2,
    "eta": 0.0,
    "min_distance": 0.005,
}
JOINT_LIMIT_RMP = {"type": "joint_limit", "r_w": 0.25, "sigma": 0.5, "epsilon": 0.1, "alpha": 1e-3, "eta": 0.0}
DAMPER_RMP = {"type": "damper", "w": 1.0, "eta": 20.0}
IDENTITY_RMP = {"type": "identity_metric", "scale": 0.01}
# The optional leaves' settings (conf/rmp/ presets of the same names): all ours, the paper's tree has none of them.
SELF_COLLISION_RMP = {
    "type": "collision_avoidance",
    "r_w": 0.2,
    "sigma": 0.5,
    "epsilon": 0.2,
    "alpha": 0.1,
    "eta": 0.0,
    "min_distance": 0.005,
}
ORIENTATION_RMP = {"type": "orientation_attractor", "gain": 1.0, "eta": 2.0, "w_u": 1.0, "w_l": 1.0, "sigma": 0.5}
VELOCITY_LIMIT_RMP = {"type": "velocity_limit", "limit": 1.0, "onset": 0.8, "w": 1.0, "eta": 1.0, "linear_from": 0.99}
# A joint-space attractor onto a posture: weak beside the end effector's (a tenth of its metric), enough to fix the
# joints an end-effector attractor leaves free on a redundant arm, no potential well deep enough to fight it.
POSTURE_RMP = {"type": "goal_attractor", "gain": 1.0, "alpha": 10.0, "eta": 2.0, "w_u": 0.1, "w_l": 0.1, "sigma": 1.0}

# The learner's weight functions: positive MLPs of the parent configuration and the relevant aux state, randomly
# initialised (learner-0 is the paper's untrained tree). w = floor + exp(MLP): the expert's weights span 1 to 200,
# which an exponential reaches in a few hundred ADAM steps where softplus needs its output to grow linearly
# (validation loss after 1500 iterations 0.12 with exp vs 1.69 with softplus, 20 held-out demonstrations).
ATTRACTOR_WEIGHT = {"type": "mlp", "hidden": [32, 32], "aux": ["goal"], "positivity": "exp"}
OBSTACLE_WEIGHT = {
    "type": "mlp",
    "hidden": [32, 32],
    "aux": ["obstacle_center", "obstacle_radius"],
    "positivity": "exp",
}
GROUND_WEIGHT = {"type": "mlp", "hidden": [32, 32], "aux": [], "positivity": "exp"}


_LEAVES: dict[str, Mapping[str, Any]] = {
    "attractor_rmp": ATTRACTOR_RMP,
    "obstacle_rmp": OBSTACLE_RMP,
    "joint_limit_rmp": JOINT_LIMIT_RMP,
    "damper_rmp": DAMPER_RMP,
    "identity_rmp": IDENTITY_RMP,
    "attractor_weight": ATTRACTOR_WEIGHT,
    "obstacle_weight": OBSTACLE_WEIGHT,
    "ground_weight": GROUND_WEIGHT,
    "self_collision_rmp": SELF_COLLISION_RMP,
    "orientation_rmp": ORIENTATION_RMP,
    "velocity_limit_rmp": VELOCITY_LIMIT_RMP,
    "posture_rmp": POSTURE_RMP,
}


def _tuned(field: str) -> dict[str, Any]:
    return {k: copy.deepcopy(v) for k, v in _LEAVES[field].items() if k != "type"}


def _onto_tuned(field: str, v: Any) -> Any:
    """A partial block ({gain: 3}) changes those keys of the tuned settings only, not the rest back to the entry's
    generic defaults."""
    return {**_tuned(field), **v} if isinstance(v, Mapping) else v


def _rmp_onto_tuned(field: str) -> Any:
    """The validator of an option block's ``rmp``: what is given laid onto the tuned settings ``field``."""
    return field_validator("rmp", mode="before")(lambda v: _onto_tuned(field, v))


def _tuned_field(model: type[Params], field: str, what: str) -> Any:
    """A leaf's (or weight's) settings, checked by that entry's own parameter model, defaulting to the tuned ones."""
    return Field(
        default_factory=lambda: model(**_tuned(field)),
        description=f"{what} ({_LEAVES[field]['type']}); keys given replace the tuned values one by one",
    )


def _weight_block(field: str) -> Any:
    """A weight field's validator: a block of any registered weight. Without ``type`` (or with the tuned one) the
    keys given change the tuned settings one by one; another type starts from its own defaults (``{type: constant}``
    fixes the weight at 1: nothing of it is learned); a bare positive number is that constant."""
    tuned_type = _LEAVES[field]["type"]

    def check(value: Any) -> dict[str, Any]:
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            value = {"type": "constant", "value": float(value)}
        if not isinstance(value, Mapping):
            raise PydanticCustomError(
                "weight",
                "{message}",
                {"message": f"a weight block {{type: <weight>, ...}} or a number, given {value!r}"},
            )
        kind = value.get("type", tuned_type)
        block = {**(_onto_tuned(field, value) if kind == tuned_type else value), "type": kind}
        _, issues = check_typed(block, WEIGHTS, field)
        if issues:
            message = "; ".join(f"{i.path.removeprefix(field).lstrip('.') or 'type'}: {i.message}" for i in issues)
            raise PydanticCustomError("weight", "{message}", {"message": message})
        return block

    return BeforeValidator(check)


def _weight_field(field: str, what: str) -> Any:
    """A weight of the generated tree: the tuned block by default, any registered weight when given."""
    return Field(
        default_factory=lambda: {"type": _LEAVES[field]["type"], **_tuned(field)},
        description=f"{what} ({_LEAVES[field]['type']}, tuned; or any registered weight, e.g. {{type: constant}} "
        "to learn nothing there)",
    )


class SelfCollision(Params):
    """Barriers between the robot's control spheres on links at least ``min_separation`` actuated joints apart."""

    min_separation: int = Field(
        2, ge=1, description="actuated joints between two links for their spheres to be paired (2: not neighbours)"
    )
    rmp: CollisionAvoidance.Params = _tuned_field(
        CollisionAvoidance.Params, "self_collision_rmp", "barrier on each pair's gap"
    )

    _rmp_tuned = _rmp_onto_tuned("self_collision_rmp")


class Orientation(Params):
    """An attractor of a direction fixed in a link (a tool axis) onto a target direction."""

    link: str | None = Field(None, description="the link (default: the end effector's)")
    axis: Vector3 = Field(default_factory=lambda: [0.0, 0.0, 1.0], description="the direction in the link frame")
    target: AuxOrValue = Field(description="the target direction (3 numbers, normalised) or an aux name")
    rmp: OrientationAttractor.Params = _tuned_field(
        OrientationAttractor.Params, "orientation_rmp", "attractor on the axis's error"
    )

    @field_validator("axis")
    @classmethod
    def _direction(cls, v: list[float]) -> list[float]:
        check_direction(v, "axis")  # link_axis's own check
        return v

    _rmp_tuned = _rmp_onto_tuned("orientation_rmp")


class VelocityLimits(Params):
    """A cap keeping every actuated joint below its velocity limit (the robot's, from its URDF or description)."""

    rmp: VelocityLimit.Params = _tuned_field(
        VelocityLimit.Params, "velocity_limit_rmp", "cap on the velocity-scaled joints (limit 1: the joint's own)"
    )

    _rmp_tuned = _rmp_onto_tuned("velocity_limit_rmp")


class EndEffectorMap(Params):
    """A learned map between the end effector and its attractor: the offset from the goal, divided by ``scale``
    (the leaves' numbers suit coordinates of order one), through ``map`` (e.g. a diffeomorphism of R^3 fixing the
    origin: it bends the straight path to the goal into the demonstrations' shape and, being onto R^3, adds no
    equilibrium; docs/math.md §12). The attractor and its weight then act in the map's latent space."""

    scale: float = Field(0.1, gt=0, le=10, description="metres per unit of the normalised offset")
    map: dict[str, Any] = Field(
        description="the learned map's block, e.g. {type: diffeomorphism, layers: 4, hidden: [32, 32], "
        "origin: [0, 0, 0]}: any registered map from R^3 to R^3 that keeps the origin"
    )


class Posture(Params):
    """An attractor of the joints onto the aux configuration ``posture`` (the environment's ``posture_goal``):
    an end-effector attractor alone leaves a redundant arm's null space free, so a posture fixes where it rests."""

    rmp: GoalAttractor.Params = _tuned_field(GoalAttractor.Params, "posture_rmp", "attractor on q - posture")

    _rmp_tuned = _rmp_onto_tuned("posture_rmp")


class ManipulatorTreeParams(Params):
    """Parameters of the Fig. 1b tree: the robot and the scene (the environment's), and the leaves' settings.

    The end-effector point is the robot's (``robot.end_effector``): the environment measures reaching and success
    at that same point, so the two cannot differ.
    """

    robot: RobotField = Field(description="the robot description (conf/robot/), usually ${env.robot}")
    scene: Scene = Field(
        default_factory=Scene,
        description="the scene (conf/scene/), usually ${env.scene}: one distance node per control point and obstacle",
    )
    obstacle_maps: dict[Literal["sphere", "box", "cylinder", "capsule"], str] = Field(
        default_factory=dict,
        description="per shape, the map measuring it instead of the default "
        "(cylinder: cylinder_distance, a vertical infinite cylinder)",
    )
    attractor_rmp: GoalAttractor.Params = _tuned_field(GoalAttractor.Params, "attractor_rmp", "end-effector attractor")
    obstacle_rmp: CollisionAvoidance.Params = _tuned_field(
        CollisionAvoidance.Params, "obstacle_rmp", "barrier on every control point's obstacle distance"
    )
    joint_limit_rmp: JointLimitBarrier.Params = _tuned_field(
        JointLimitBarrier.Params, "joint_limit_rmp", "barrier on each finite joint limit"
    )
    damper_rmp: Damper.Params = _tuned_field(Damper.Params, "damper_rmp", "damper on the root")
    identity_rmp: IdentityMetric.Params = _tuned_field(
        IdentityMetric.Params, "identity_rmp", "identity metric on the root"
    )
    attractor_weight: Annotated[dict[str, Any], _weight_block("attractor_weight")] = _weight_field(
        "attractor_weight", "learnable weight of the ee -> attractor edge"
    )
    obstacle_weight: Annotated[dict[str, Any], _weight_block("obstacle_weight")] = _weight_field(
        "obstacle_weight", "learnable weight shared by one control point's obstacle edges"
    )
    ground_weight: Annotated[dict[str, Any], _weight_block("ground_weight")] = _weight_field(
        "ground_weight", "learnable weight shared by every control point's ground edge"
    )
    obstacle_sets: list[ObstacleSet] = Field(
        default_factory=list,
        description="obstacles that come and go at run time: per set of one shape, n_max members "
        "present or absent call by call (scenes/sets.py; a World fills them), beside "
        "the scene's fixed obstacles, under the same shared obstacle weights",
    )
    self_collision: SelfCollision | None = Field(
        None, description="barriers between control spheres on links far enough apart (none: no self-collision leaves)"
    )
    orientation: Orientation | None = Field(None, description="a tool-axis attractor (none: position only)")
    velocity_limits: VelocityLimits | None = Field(None, description="a joint velocity cap (none: uncapped)")
    end_effector_map: EndEffectorMap | None = Field(
        None,
        description="a learned map between the end effector's goal offset and its attractor (none: the offset itself)",
    )
    posture: Posture | None = Field(None, description="a joint-space attractor onto the aux posture (none: no posture)")

    @field_validator(
        *(
            f
            for f in _LEAVES
            if f.endswith("_rmp")
            and f not in ("self_collision_rmp", "orientation_rmp", "velocity_limit_rmp", "posture_rmp")
        ),
        mode="before",
    )
    @classmethod
    def _leaf_onto_tuned(cls, v: Any, info: Any) -> Any:
        return _onto_tuned(info.field_name, v)

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
    value = getattr(p, field)
    if isinstance(value, Mapping):  # a weight block, already {type, **settings}
        return copy.deepcopy(dict(value))
    return {"type": _LEAVES[field]["type"], **value.model_dump(exclude_unset=True)}


def _point(p: ManipulatorTreeParams, link: str, offset) -> dict[str, Any]:
    """The forward-kinematics map to a point fixed in one of the robot's links."""
    return _robot_map(p, "forward_kinematics", link=link, offset=[float(v) for v in offset])


def _surface(dist: dict[str, Any], radius: float) -> dict[str, Any]:
    """A distance from a control sphere's surface: the centre's distance minus the radius (0 means touching)."""
    return {"type": "compose", "maps": [dist, {"type": "offset", "origin": [float(radius)]}]}


def _control_point_nodes(p: ManipulatorTreeParams, i: int, cp, ground: bool) -> tuple[dict[str, Any], dict[str, Any]]:
    """Control point ``i``'s node, its obstacle (and, with ``ground``, ground) edges, and its shared obstacle
    weight."""
    name, scene = f"cp{i}", p.scene
    nodes: dict[str, Any] = {name: {"parent": "q", "map": _point(p, cp.link, cp.offset)}}
    shared = {f"{name}_obstacle": _entry(p, "obstacle_weight")} if has_obstacles(p) else {}
    for s in (o.for_control_point(i) for o in p.obstacle_sets):  # one slot per member: masked, so an absent
        for j in range(1, s.n_max + 1):  # member contributes exactly nothing
            nodes[f"{name}_{s.prefix}{j}"] = {
                "parent": name,
                "map": _surface(s.slot_map(j), cp.radius),
                "weight": {"shared": f"{name}_obstacle", "bind": s.weight_bind(j)},
                "rmp": _entry(p, "obstacle_rmp"),
            }
    for k, o in enumerate(scene.obstacles, start=1):
        dist = obstacle_map(k, o.type, o.moving, p.obstacle_maps.get(o.type))
        nodes[f"{name}_obstacle{k}"] = {
            "parent": name,
            "map": _surface(dist, cp.radius),
            "weight": {
                "shared": f"{name}_obstacle",
                "bind": {"obstacle_center": f"obstacle{k}_center", "obstacle_radius": f"obstacle{k}_radius"},
            },
            "rmp": _entry(p, "obstacle_rmp"),
        }
    if scene.ground is not None and ground:
        plane = {"type": "plane_distance", "normal": [0.0, 0.0, 1.0], "height": float(scene.ground.height)}
        nodes[f"{name}_ground"] = {
            "parent": name,
            "map": _surface(plane, cp.radius),
            "weight": {"shared": "ground"},
            "rmp": _entry(p, "obstacle_rmp"),
        }
    if len(nodes) == 1:  # a control point without obstacles would be a leaf without an RMP
        nodes = {}
    return nodes, shared


@TREE_GENERATORS.register("arm_reach", params=ManipulatorTreeParams)
def arm_reach(p: ManipulatorTreeParams) -> dict[str, Any]:
    """The tree spec (docs/architecture.md §2) of paper Fig. 1b for the robot and scene, from validated parameters.

    Weighted edges (learnable, MLPs): ee→attractor, every control point→obstacle edge (shared across obstacles
    per control point) and every control point→ground edge (one shared weight). Joint limits, the damper and the
    identity metric carry no weight, as in the paper.
    """
    r = p.robot
    aux: dict[str, int] = {
        "goal": 3,
        **scene_aux_dims(p.scene),
        **set_dims(sets_read(p.obstacle_sets, len(r.control_points))),
    }
    if has_obstacles(p):  # generic names the shared obstacle weights read; every edge binds them to its own obstacle
        aux["obstacle_center"] = 3
        aux["obstacle_radius"] = 1
    nodes: dict[str, Any] = {
        "ee": {"parent": "q", "map": _point(p, r.end_effector.link, r.end_effector.offset)},
        **_attractor_nodes(p),
    }
    for j, side, lim in r.finite_limits():
        nodes[f"jl{j + 1}_{side}"] = {
            "parent": "q",
            "map": {"type": "joint_limit", "side": side, "limit": float(lim), "joints": j},
            "rmp": _entry(p, "joint_limit_rmp"),
        }
    shared: dict[str, Any] = {"ground": _entry(p, "ground_weight")} if p.scene.ground is not None else {}
    # no ground edge where it could never act (no joint lowers the sphere) or would always act at full strength
    # (the sphere is below the ground in every configuration): robots/home.py samples both
    no_ground = spheres_without_ground_edge(r, float(p.scene.ground.height)) if p.scene.ground is not None else set()
    for i, cp in enumerate(r.control_points, start=1):
        more, weights = _control_point_nodes(p, i, cp, ground=i - 1 not in no_ground)
        nodes.update(more)
        shared.update(weights)
    nodes["damper"] = {"parent": "q", "map": {"type": "identity"}, "rmp": _entry(p, "damper_rmp")}
    nodes["identity_metric"] = {"parent": "q", "map": {"type": "identity"}, "rmp": _entry(p, "identity_rmp")}
    extras = _optional_leaves(p, nodes, aux)
    n_limits, n_obs = len(r.finite_limits()), len(p.scene.obstacles)
    ground = " and the ground" if p.scene.ground is not None else ""
    if p.obstacle_sets:
        ground += (
            " and run-time obstacle sets ("
            + ", ".join(f"{s.prefix}: {s.n_max}{' per control point' * s.per_control_point}" for s in p.obstacle_sets)
            + ")"
        )
    return {
        "description": (
            f"{r.name} (paper Fig. 1b): end-effector attractor, {n_limits} joint-limit barriers, "
            f"{len(r.control_points)} control points x {n_obs} obstacle(s){ground} with weights shared "
            f"across obstacles, damper and identity metric on the root{extras}"
        ),
        "root": {"name": "q", "dim": len(r.joints)},
        "aux": aux,
        "shared_weights": shared,
        "nodes": nodes,
        "roles": weight_roles(r, p.scene, has_obstacles(p)),
    }


def _attractor_nodes(p: ManipulatorTreeParams) -> dict[str, Any]:
    """The end effector's attractor on its offset from the goal, or, with ``end_effector_map``, on that offset
    normalised and through the learned map (ee -> ee_offset -> ee_normalised -> ee_latent -> attractor)."""
    leaf = {"weight": _entry(p, "attractor_weight"), "rmp": _entry(p, "attractor_rmp")}
    m = p.end_effector_map
    if m is None:
        return {"attractor": {"parent": "ee", "map": {"type": "offset", "origin": "goal"}, **leaf}}
    return {
        "ee_offset": {"parent": "ee", "map": {"type": "offset", "origin": "goal"}},
        "ee_normalised": {"parent": "ee_offset", "map": {"type": "normalize", "scale": m.scale}},
        "ee_latent": {"parent": "ee_normalised", "map": copy.deepcopy(m.map)},
        "attractor": {"parent": "ee_latent", "map": {"type": "identity"}, **leaf},
    }


def has_obstacles(p: ManipulatorTreeParams) -> bool:
    """Whether the tree has obstacle edges: the scene's fixed obstacles or run-time sets."""
    return bool(p.scene.obstacles or p.obstacle_sets)


def weight_roles(robot, scene: Scene, obstacles: bool) -> dict[str, list[str]]:
    """The tree's weighted entries by role, what an expert names to weight any robot's tree (``conf/expert/reach.yaml``):
    ``attractor`` (the ee → attractor edge), ``ground`` (the shared weight of every control point's ground edge, when
    the scene has a ground) and ``obstacle`` (each control point's shared obstacle weight, when the tree has
    ``obstacles``: the scene's or run-time sets)."""
    obstacle = [f"cp{i}_obstacle" for i in range(1, len(robot.control_points) + 1)] if obstacles else []
    return {"attractor": ["attractor"], "ground": ["ground"] if scene.ground is not None else [], "obstacle": obstacle}


def _robot_map(p: ManipulatorTreeParams, kind: str, **keys: Any) -> dict[str, Any]:
    """A joint-space map of ``kind`` on the robot (its urdf, joints and mount written in)."""
    r = p.robot
    mount = {} if r.mount is None or r.mount.is_identity() else {"mount": r.mount.model_dump(mode="json")}
    return {"type": kind, "urdf": r.urdf, "joints": list(r.joints), **mount, **keys}


def _optional_leaves(p: ManipulatorTreeParams, nodes: dict[str, Any], aux: dict[str, int]) -> str:
    """The leaves the paper's tree does not have, when asked for: self-collision barriers, a tool-axis attractor,
    a joint velocity cap (unweighted edges on the root). Returns what they add to the tree's description."""
    said = []
    if p.self_collision is not None:
        pairs, overlapping = self_collision_pairs(p.robot, p.self_collision.min_separation)
        for i, j in pairs:
            a, b = (p.robot.control_points[k - 1] for k in (i, j))
            sphere = lambda cp: {"link": cp.link, "offset": [float(v) for v in cp.offset], "radius": float(cp.radius)}
            nodes[f"self_cp{i}_cp{j}"] = {
                "parent": "q",
                "map": _robot_map(p, "link_sphere_distance", a=sphere(a), b=sphere(b)),
                "rmp": {"type": "collision_avoidance", **p.self_collision.rmp.model_dump(exclude_unset=True)},
            }
        said.append(
            f"{len(pairs)} self-collision barriers"
            + (f" ({overlapping} sphere pairs overlapping at home left out)" if overlapping else "")
        )
    if p.orientation is not None:
        o = p.orientation
        if isinstance(o.target, str):
            aux.setdefault(o.target, 3)
        nodes["tool_axis"] = {
            "parent": "q",
            "map": _robot_map(
                p, "link_axis", link=o.link or p.robot.end_effector.link, axis=list(o.axis), target=o.target
            ),
            "rmp": {"type": "orientation_attractor", **o.rmp.model_dump(exclude_unset=True)},
        }
        said.append("a tool-axis attractor")
    if p.velocity_limits is not None:
        nodes["velocity_limit"] = {
            "parent": "q",
            "map": _robot_map(p, "velocity_scaled_joints"),
            "rmp": {"type": "velocity_limit", **p.velocity_limits.rmp.model_dump(exclude_unset=True)},
        }
        said.append("a joint velocity cap")
    if p.posture is not None:
        aux["posture"] = len(p.robot.joints)
        nodes["posture"] = {
            "parent": "q",
            "map": {"type": "offset", "origin": "posture"},
            "rmp": {"type": "goal_attractor", **p.posture.rmp.model_dump(exclude_unset=True)},
        }
        said.append("a posture attractor")
    if p.end_effector_map is not None:
        said.append(f"a learned {p.end_effector_map.map.get('type', 'map')} between the end effector and its attractor")
    return "; " + ", ".join(said) if said else ""


def self_collision_pairs(robot, min_separation: int) -> tuple[list[tuple[int, int]], int]:
    """Pairs (i, j) of control points (numbered from 1) on links ``min_separation`` or more actuated joints apart,
    and how many such pairs were left out because their spheres already overlap at the robot's home configuration
    (conservative spheres on links two joints apart can: a barrier there would push the arm from its own home).
    Link pairs the robot's SRDF exempts (``<disable_collisions>``) are never paired."""
    chain = Chain(robot.model(), list(robot.joints))
    far = set(non_adjacent_link_pairs(chain, min_separation=min_separation)) - robot.disabled_collisions()
    cps = robot.control_points
    centre = build_robot(robot).sphere_centres(torch.tensor([list(robot.home)], dtype=torch.float64))[0]
    pairs, overlapping = [], 0
    for i in range(len(cps)):
        for j in range(i + 1, len(cps)):
            if (cps[i].link, cps[j].link) not in far and (cps[j].link, cps[i].link) not in far:
                continue
            if float((centre[i] - centre[j]).norm()) <= cps[i].radius + cps[j].radius:
                overlapping += 1
                continue
            pairs.append((i + 1, j + 1))
    return pairs, overlapping


def manipulator_tree_spec(
    robot: Mapping[str, Any], scene: Mapping[str, Any] | Scene | None = None, **settings: Any
) -> dict[str, Any]:
    """The tree spec for a robot description and a scene (Python callers' entry; ``settings`` are the other
    :class:`ManipulatorTreeParams` keys). Checked by the same model as ``generator: arm_reach`` in YAML, so a bad
    value raises pydantic's ValidationError (a ValueError) naming the key."""
    given: dict[str, Any] = {"robot": robot, **settings}
    if scene is not None:
        given["scene"] = scene
    return arm_reach(ManipulatorTreeParams.model_validate(given))


def copy_weights(src: RMPTree, dst: RMPTree) -> list[str]:
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
        assert isinstance(bw, BoundWeight)  # the assembly binds every edge's weight function
        if name in dst.weights and not any(bw.fn is s for s in src.shared.values()):
            into = dst.weights[name]
            assert isinstance(into, BoundWeight)
            into.fn.load_state_dict(bw.fn.state_dict())
            copied.append(name)
    return copied


#: a control point's edge to a scene's fixed obstacle, in a tree the Fig. 1b generator made
_OBSTACLE_EDGE = re.compile(r"^cp(\d+)_obstacle(\d+)$")


def with_obstacle_sets(spec: Mapping[str, Any], sets: list[ObstacleSet]) -> dict[str, Any]:
    """A Fig. 1b tree spec whose fixed-obstacle edges give way to run-time obstacle sets: every control point's edges
    to the scene's obstacles (``cp<i>_obstacle<k>``) are replaced by one edge per member of each set (its own members
    for a per-control-point set), each with the same leaf RMP, control-sphere radius and shared weight (bound to the
    member), and the aux the fixed obstacles were read from is dropped. A learner trained among fixed obstacles so
    serves a world that changes at run time: its shared weights keep their names."""
    out = copy.deepcopy(dict(spec))
    nodes: dict[str, Any] = out["nodes"]
    edges: dict[int, list[str]] = {}
    for name in nodes:
        if (m := _OBSTACLE_EDGE.match(name)) is not None:
            edges.setdefault(int(m.group(1)), []).append(name)
    if not edges:
        raise ValueError("the tree has no control point → obstacle edges (cp<i>_obstacle<k>) to replace by sets")
    n_points = sum(1 for n in nodes if re.fullmatch(r"cp\d+", n))
    for i, names in sorted(edges.items()):
        template = nodes[names[0]]
        radius = float(template["map"]["maps"][1]["origin"][0])  # _surface: the distance, then minus the radius
        for name in names:
            del nodes[name]
        for s in (o.for_control_point(i) for o in sets):
            for j in range(1, s.n_max + 1):
                nodes[f"cp{i}_{s.prefix}{j}"] = {
                    "parent": f"cp{i}",
                    "map": _surface(s.slot_map(j), radius),
                    "weight": {"shared": template["weight"]["shared"], "bind": s.weight_bind(j)},
                    "rmp": copy.deepcopy(template["rmp"]),
                }
    aux = {k: v for k, v in out["aux"].items() if not re.match(r"^obstacle\d+_", k)}
    out["aux"] = {**aux, **set_dims(sets_read(sets, n_points))}
    listed = ", ".join(f"{s.prefix}: {s.n_max}{' per control point' * s.per_control_point}" for s in sets)
    out["description"] = f"{out.get('description', '')}; fixed obstacles replaced by run-time obstacle sets ({listed})"
    return out
