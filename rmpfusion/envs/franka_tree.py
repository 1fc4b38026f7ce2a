"""The Franka Panda RMP-tree* of the paper (Fig. 1b, App. D.2) as a generated spec.

The tree's shape depends on the control points and on how many obstacles are present at run time: every
obstacle adds one distance node under every control point. Generating the spec (rather than hand-writing
YAML) keeps those nodes consistent, and lets a tree trained with one obstacle be rebuilt for several: the
obstacle weight on a control point is one entry of ``shared_weights`` used by all of that point's
distance edges, each edge binding the generic aux names ``obstacle_center``/``obstacle_radius`` to its
own obstacle. The generator is registered as the tree generator ``franka_fig1b``, so
``conf/tree/franka.yaml`` declares it and its parameters (``build.generated.expand_tree``) instead of
holding ~400 lines of its output that would have to be kept in step with it.
"""
from __future__ import annotations

import copy
import difflib
import functools
from typing import Any, Literal, Mapping, Sequence

import torch
from pydantic import Field, field_validator

from ..build.weighting import tree_with_weights as with_weights  # noqa: F401  (expert configs: node or shared-weight names)
from ..maps.urdf import PANDA_ARM_JOINTS, load_panda_urdf_path, parse_urdf
from ..registry import TREE_GENERATORS, Params
from ..rmps.gds_leaves import CollisionAvoidance, Damper, GoalAttractor, IdentityMetric, JointLimitBarrier
from ..weights.neural import MLPWeight
from ..maps.kinematics import Chain

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


_LEAVES: dict[str, Mapping[str, Any]] = {
    "attractor_rmp": ATTRACTOR_RMP, "obstacle_rmp": OBSTACLE_RMP, "joint_limit_rmp": JOINT_LIMIT_RMP,
    "damper_rmp": DAMPER_RMP, "identity_rmp": IDENTITY_RMP,
    "attractor_weight": ATTRACTOR_WEIGHT, "obstacle_weight": OBSTACLE_WEIGHT,
}


def _tuned(field: str) -> dict[str, Any]:
    return {k: copy.deepcopy(v) for k, v in _LEAVES[field].items() if k != "type"}


def _tuned_field(model: type[Params], field: str, what: str) -> Any:
    """A leaf's (or weight's) settings, checked by that entry's own parameter model, defaulting to the tuned ones."""
    return Field(default_factory=lambda: model(**_tuned(field)),
                 description=f"{what} ({_LEAVES[field]['type']}); keys given replace the tuned values one by one")


@functools.lru_cache(maxsize=1)
def _panda_links() -> tuple[str, ...]:
    return tuple(parse_urdf(load_panda_urdf_path()).link_names())


class ControlPoint(Params):
    """A sphere fixed to a Panda link; its surface is what the obstacle barriers keep away from obstacles."""

    link: str
    offset: tuple[float, float, float] = Field((0.0, 0.0, 0.0), description="sphere centre in the link frame (m)")
    radius: float = Field(gt=0, description="sphere radius (m): distances to obstacles are taken from its surface")

    @field_validator("link")
    @classmethod
    def _a_panda_link(cls, v: str) -> str:
        links = _panda_links()
        if v not in links:
            close = difflib.get_close_matches(v, links, n=3, cutoff=0.5)
            hint = f"did you mean {', '.join(map(repr, close))}? " if close else ""
            raise ValueError(f"the Panda has no link {v!r}; {hint}links: {', '.join(links)}")
        return v


class FrankaTreeParams(Params):
    """Parameters of the Fig. 1b Panda tree; the defaults are the tree of the paper's experiment.

    The end-effector point (``EE_LINK``/``EE_OFFSET``) is not a parameter: the environment measures
    reaching and success at that same point, so the two cannot be allowed to differ.
    """

    control_points: list[ControlPoint] = Field(
        default_factory=lambda: [ControlPoint(**cp) for cp in DEFAULT_CONTROL_POINTS],
        description="spheres approximating the arm; each gets one distance node per obstacle")
    n_obstacles: int = Field(1, ge=0, description="obstacles present at run time (aux obstacle<k>_center/_radius)")
    obstacle_distance: Literal["cylinder_distance", "sphere_distance"] = Field(
        "cylinder_distance", description="vertical infinite cylinder (conservative for a standing one) or sphere")
    attractor_rmp: GoalAttractor.Params = _tuned_field(GoalAttractor.Params, "attractor_rmp", "end-effector attractor")
    obstacle_rmp: CollisionAvoidance.Params = _tuned_field(CollisionAvoidance.Params, "obstacle_rmp",
                                                           "barrier on every control point's obstacle distance")
    joint_limit_rmp: JointLimitBarrier.Params = _tuned_field(JointLimitBarrier.Params, "joint_limit_rmp",
                                                             "barrier on each of the 14 joint limits")
    damper_rmp: Damper.Params = _tuned_field(Damper.Params, "damper_rmp", "damper on the root")
    identity_rmp: IdentityMetric.Params = _tuned_field(IdentityMetric.Params, "identity_rmp",
                                                       "identity metric on the root")
    attractor_weight: MLPWeight.Params = _tuned_field(MLPWeight.Params, "attractor_weight",
                                                      "learnable weight of the ee -> attractor edge")
    obstacle_weight: MLPWeight.Params = _tuned_field(MLPWeight.Params, "obstacle_weight",
                                                     "learnable weight shared by one control point's obstacle edges")

    @field_validator(*_LEAVES, mode="before")
    @classmethod
    def _onto_tuned(cls, v: Any, info: Any) -> Any:
        # a partial block ({gain: 3}) changes those keys only, not the rest back to the entry's generic defaults
        return {**_tuned(info.field_name), **v} if isinstance(v, Mapping) else v


def _entry(p: FrankaTreeParams, field: str) -> dict[str, Any]:
    """``{type, **settings}`` as written in a tree spec; only keys that were set, so defaults stay the entry's."""
    return {"type": _LEAVES[field]["type"], **getattr(p, field).model_dump(exclude_unset=True)}


@TREE_GENERATORS.register("franka_fig1b", params=FrankaTreeParams)
def franka_fig1b(p: FrankaTreeParams) -> dict[str, Any]:
    """The Panda tree spec (docs/architecture.md §2) of paper Fig. 1b, from validated parameters.

    Weighted edges (learnable, MLPs): ee→attractor and every control point→distance edge, the latter
    shared across obstacles per control point. Joint limits, the damper and the identity metric carry
    no weight, as in the paper.
    """
    n_obstacles = p.n_obstacles
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
                      "weight": _entry(p, "attractor_weight"), "rmp": _entry(p, "attractor_rmp")},
    }
    for j in range(7):
        for side, lim in (("upper", upper[j]), ("lower", lower[j])):
            nodes[f"jl{j + 1}_{side}"] = {
                "parent": "q", "map": {"type": "joint_limit", "side": side, "limit": float(lim), "joints": j},
                "rmp": _entry(p, "joint_limit_rmp"),
            }
    shared: dict[str, Any] = {}
    for i, cp in enumerate(p.control_points, start=1):
        cp_name = f"cp{i}"
        nodes[cp_name] = {"parent": "q", "map": {"type": "forward_kinematics", "robot": "panda", "link": cp.link,
                                                  "offset": [float(v) for v in cp.offset]}}
        if n_obstacles:
            shared[f"{cp_name}_obstacle"] = _entry(p, "obstacle_weight")
        for k in range(1, n_obstacles + 1):
            dist = {"type": p.obstacle_distance, "center": f"obstacle{k}_center", "radius": f"obstacle{k}_radius"}
            nodes[f"{cp_name}_obstacle{k}"] = {
                "parent": cp_name,
                # the control point is a sphere: subtract its radius so 0 means touching
                "map": {"type": "compose", "maps": [dist, {"type": "offset", "origin": [float(cp.radius)]}]},
                "weight": {"shared": f"{cp_name}_obstacle",
                           "bind": {"obstacle_center": f"obstacle{k}_center", "obstacle_radius": f"obstacle{k}_radius"}},
                "rmp": _entry(p, "obstacle_rmp"),
            }
        if not n_obstacles:  # a control point without obstacles would be a leaf without an RMP
            del nodes[cp_name]
    nodes["damper"] = {"parent": "q", "map": {"type": "identity"}, "rmp": _entry(p, "damper_rmp")}
    nodes["identity_metric"] = {"parent": "q", "map": {"type": "identity"}, "rmp": _entry(p, "identity_rmp")}
    return {
        "description": (f"Franka Panda (paper Fig. 1b): end-effector attractor, 14 joint-limit barriers, "
                        f"{len(p.control_points)} control points x {n_obstacles} obstacle(s) with weights shared "
                        f"across obstacles, damper and identity metric on the root"),
        "root": {"name": "q", "dim": 7},
        "aux": aux,
        "shared_weights": shared,
        "nodes": nodes,
    }


def franka_tree_spec(
    control_points: Sequence[Mapping[str, Any] | ControlPoint] | None = None,
    n_obstacles: int = 1,
    obstacle_distance: str = "cylinder_distance",
    **settings: Any,
) -> dict[str, Any]:
    """The Panda tree spec for these control points and this many obstacles (Python callers' entry).

    ``settings`` are the other :class:`FrankaTreeParams` keys (``attractor_rmp``, ``obstacle_weight``, ...).
    Everything is checked by the same model as ``generator: franka_fig1b`` in YAML, so a bad value raises
    pydantic's ValidationError (a ValueError) naming the key.
    """
    given: dict[str, Any] = {"n_obstacles": n_obstacles, "obstacle_distance": obstacle_distance, **settings}
    if control_points is not None:
        given["control_points"] = list(control_points)
    return franka_fig1b(FrankaTreeParams.model_validate(given))


def _panda_limits():

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

