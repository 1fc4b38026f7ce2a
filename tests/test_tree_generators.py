"""Trees declared as a generator and its parameters (assembly/generated.py): conf/tree/franka.yaml (conf/tree/arm_reach.yaml
for the Panda of conf/robot/panda.yaml and the cylinder of conf/scene/franka_cylinder.yaml) expands to the paper's
Panda tree, and bad declarations are refused with the path of the key at fault."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest
import yaml
from pydantic import Field

import rmpfusion
from rmpfusion.assembly.errors import ConfigError
from rmpfusion.assembly.generated import expand_tree
from rmpfusion.registry import TREE_GENERATORS, Params

CONF = Path(__file__).resolve().parents[1] / "conf"
needs_panda = pytest.mark.skipif(
    importlib.util.find_spec("pybullet_data") is None, reason="the Panda URDF comes from pybullet_data"
)

# The Panda's joint limits in pybullet_data's panda.urdf, (lower, upper) per joint, rad.
PANDA_LIMITS = [
    (-2.9671, 2.9671),
    (-1.8326, 1.8326),
    (-2.9671, 2.9671),
    (-3.1416, 0.0),
    (-2.9671, 2.9671),
    (-0.0873, 3.8223),
    (-2.9671, 2.9671),
]


def declaration(scene: str = "franka_cylinder") -> dict:
    """conf/tree/arm_reach.yaml with the robot and scene experiment=franka composes into it, as experiment=franka does."""
    decl = yaml.safe_load((CONF / "tree" / "arm_reach.yaml").read_text())
    decl.update(yaml.safe_load((CONF / "tree" / "franka.yaml").read_text()))
    decl.pop("defaults")
    decl["robot"] = yaml.safe_load((CONF / "robot" / "panda.yaml").read_text())
    decl["scene"] = yaml.safe_load((CONF / "scene" / f"{scene}.yaml").read_text())
    return decl


def issues_of(spec) -> dict[str, str]:
    with pytest.raises(ConfigError) as err:
        expand_tree(spec)
    return {i.path: i.message for i in err.value.issues}


def test_the_panda_generator_is_registered_by_importing_rmpfusion():
    assert "arm_reach" in TREE_GENERATORS
    assert declaration()["generator"] == "arm_reach"


@needs_panda
def test_franka_declaration_expands_to_the_arm_reach_tree():
    tree = expand_tree(declaration())
    nodes = tree["nodes"]
    # ee + attractor, 2 limits x 7 joints, 14 control points with one obstacle each, damper, identity metric
    assert len(nodes) == 2 + 14 + 14 * 2 + 2
    assert tree["root"] == {"name": "q", "dim": 7}
    assert tree["aux"] == {
        "goal": 3,
        "obstacle1_center": 3,
        "obstacle1_radius": 1,
        "obstacle1_axis": 3,
        "obstacle1_half_height": 1,
        "obstacle_center": 3,
        "obstacle_radius": 1,
    }
    assert set(tree["shared_weights"]) == {f"cp{i}_obstacle" for i in range(1, 15)}
    assert tree["shared_weights"]["cp7_obstacle"] == {
        "type": "mlp",
        "hidden": [32, 32],
        "positivity": "exp",
        "aux": ["obstacle_center", "obstacle_radius"],
    }
    for j, (lower, upper) in enumerate(PANDA_LIMITS, start=1):
        for side, limit in (("lower", lower), ("upper", upper)):
            jl = nodes[f"jl{j}_{side}"]
            assert jl["parent"] == "q" and "weight" not in jl
            assert jl["map"] == {"type": "joint_limit", "side": side, "limit": limit, "joints": j - 1}
            assert jl["rmp"] == {
                "type": "joint_limit",
                "r_w": 0.25,
                "sigma": 0.5,
                "epsilon": 0.1,
                "alpha": 0.001,
                "eta": 0.0,
            }
    assert nodes["ee"]["map"] == {
        "type": "forward_kinematics",
        "urdf": "pkg://pybullet_data/franka_panda/panda.urdf",
        "joints": [f"panda_joint{i}" for i in range(1, 8)],
        "link": "panda_hand",
        "offset": [0.0, 0.0, 0.1034],
    }
    assert nodes["attractor"]["parent"] == "ee" and nodes["attractor"]["map"] == {"type": "offset", "origin": "goal"}
    assert nodes["attractor"]["rmp"] == {
        "type": "goal_attractor",
        "gain": 5.0,
        "alpha": 10.0,
        "eta": 5.0,
        "w_u": 1.0,
        "w_l": 1.0,
        "sigma": 1.0,
    }
    assert nodes["cp10"]["map"]["link"] == "panda_link6" and nodes["cp10"]["map"]["offset"] == [0.035, -0.011, 0.021]
    cp3 = nodes["cp3_obstacle1"]
    assert cp3["parent"] == "cp3"
    assert cp3["map"]["maps"] == [
        {"type": "cylinder_distance", "center": "obstacle1_center", "radius": "obstacle1_radius"},
        {"type": "offset", "origin": [0.095]},
    ]
    assert cp3["weight"] == {
        "shared": "cp3_obstacle",
        "bind": {"obstacle_center": "obstacle1_center", "obstacle_radius": "obstacle1_radius"},
    }
    assert cp3["rmp"] == {
        "type": "collision_avoidance",
        "r_w": 0.15,
        "sigma": 0.5,
        "epsilon": 0.2,
        "alpha": 0.01,
        "eta": 0.0,
        "min_distance": 0.005,
    }
    assert nodes["damper"]["rmp"] == {"type": "damper", "w": 1.0, "eta": 20.0}
    assert nodes["identity_metric"]["rmp"] == {"type": "identity_metric", "scale": 0.01}
    assert all("weight" not in nodes[n] for n in ("damper", "identity_metric"))


@needs_panda
def test_parameters_change_the_generated_tree():
    two = {
        "obstacles": [
            {"type": "cylinder", "center": [0.5, 0.0, 0.3], "radius": 0.05, "height": 0.6},
            {"type": "sphere", "center": [0.3, 0.4, 0.3], "radius": 0.05},
        ]
    }
    tree = expand_tree({**declaration(), "scene": two, "attractor_rmp": {"gain": 3.0}})
    assert sum(n.startswith("cp") and n.endswith("_obstacle2") for n in tree["nodes"]) == 14
    assert tree["nodes"]["cp1_obstacle2"]["map"]["maps"][0] == {
        "type": "sphere_obstacle",
        "center": "obstacle2_center",
        "radius": "obstacle2_radius",
    }
    # a partial leaf block changes its own keys only; the rest stay the tuned ones
    assert tree["nodes"]["attractor"]["rmp"] == {
        "type": "goal_attractor",
        "gain": 3.0,
        "alpha": 10.0,
        "eta": 5.0,
        "w_u": 1.0,
        "w_l": 1.0,
        "sigma": 1.0,
    }


def test_a_written_tree_passes_through_unchanged():
    spec = {"root": {"name": "q", "dim": 2}, "nodes": {"d": {"parent": "q", "rmp": {"type": "damper"}}}}
    out = expand_tree(spec)
    assert out == spec and out is not spec


def test_unknown_generator_gets_did_you_mean():
    issues = issues_of({"generator": "arm_rech", "scene": {}})
    assert list(issues) == ["tree.generator"]
    assert "unknown tree generator 'arm_rech'" in issues["tree.generator"]
    assert "did you mean 'arm_reach'" in issues["tree.generator"]


@needs_panda
def test_misspelt_parameter_names_its_key_and_the_allowed_ones():
    decl = declaration()
    decl["scen"] = decl.pop("scene")
    issues = issues_of(decl)
    assert list(issues) == ["tree.scen"]
    msg = issues["tree.scen"]
    assert "unknown key" in msg and "allowed: robot, scene" in msg and "did you mean 'scene'" in msg
    nested = issues_of({**declaration(), "attractor_rmp": {"gian": 5.0}})
    assert list(nested) == ["tree.attractor_rmp.gian"] and "gain" in nested["tree.attractor_rmp.gian"]


@needs_panda
@pytest.mark.parametrize(
    "key,value,path",
    [
        (
            "scene",
            {"obstacles": [{"type": "sphere", "center": [0.5, 0.0, 0.3], "radius": -0.1}]},
            "tree.scene.obstacles.0.sphere.radius",
        ),
        ("attractor_rmp", {"gain": -5.0}, "tree.attractor_rmp.gain"),
    ],
)
def test_out_of_range_values_are_refused_naming_the_key(key, value, path):
    issues = issues_of({**declaration(), key: value})
    assert list(issues) == [path] and "greater than" in issues[path]


@needs_panda
def test_a_control_point_on_an_unknown_link_is_refused():
    decl = declaration()
    decl["robot"]["control_points"] = [{"link": "panda_lnk3", "radius": 0.1}]
    issues = issues_of(decl)
    assert "control_points[0].link = 'panda_lnk3' is not a link of" in issues["tree.robot"]
    assert "did you mean 'panda_link3'" in issues["tree.robot"]


@needs_panda
def test_tree_keys_beside_the_parameters_adjust_the_generated_tree():
    tree = expand_tree({**declaration(), "shared_weights": {"cp2_obstacle": {"init_bias": 1.0}}})
    assert tree["shared_weights"]["cp2_obstacle"] == {
        "type": "mlp",
        "hidden": [32, 32],
        "positivity": "exp",
        "aux": ["obstacle_center", "obstacle_radius"],
        "init_bias": 1.0,
    }
    assert "init_bias" not in tree["shared_weights"]["cp1_obstacle"]
    issues = issues_of({**declaration(), "shared_weights": {"cp2_obstacel": {"init_bias": 1.0}}})
    assert "did you mean 'cp2_obstacle'" in issues["tree.shared_weights.cp2_obstacel"]


@needs_panda
def test_a_weight_of_the_generated_tree_takes_any_registered_weight():
    tree = expand_tree(
        {**declaration(), "obstacle_weight": 1.0, "attractor_weight": {"type": "constant", "value": 2.0}}
    )
    assert all(w == {"type": "constant", "value": 1.0} for n, w in tree["shared_weights"].items() if "obstacle" in n)
    assert tree["nodes"]["attractor"]["weight"] == {"type": "constant", "value": 2.0}
    # a block of the tuned type changes its own keys only
    tree = expand_tree({**declaration(), "obstacle_weight": {"hidden": [8]}})
    assert tree["shared_weights"]["cp1_obstacle"] == {
        "type": "mlp",
        "hidden": [8],
        "aux": ["obstacle_center", "obstacle_radius"],
        "positivity": "exp",
    }


@needs_panda
@pytest.mark.parametrize(
    "value,says",
    [
        ({"type": "constnt"}, "unknown weight function 'constnt'"),
        ({"type": "constant", "hidden": [32]}, "hidden: unknown key"),  # another type starts from its own defaults
        (-1.0, "must be > 0"),
        ("strong", "a weight block {type: <weight>, ...} or a number"),
    ],
)
def test_a_bad_weight_of_the_generated_tree_is_refused_naming_its_key(value, says):
    issues = issues_of({**declaration(), "obstacle_weight": value})
    assert list(issues) == ["tree.obstacle_weight"] and says in issues["tree.obstacle_weight"]


def test_a_generator_registered_from_outside_expands_the_same_way():
    """What a plugin does: register a function with its Params; the declaration needs nothing else."""

    class ChainParams(Params):
        length: int = Field(ge=1)

    @TREE_GENERATORS.register("test_damper_chain", params=ChainParams)
    def chain(p: ChainParams) -> dict:
        nodes = {f"n{i}": {"parent": f"n{i - 1}" if i else "q"} for i in range(p.length)}
        nodes[f"n{p.length - 1}"]["rmp"] = {"type": "damper"}
        return {"root": {"name": "q", "dim": 2}, "nodes": nodes}

    try:
        assert list(expand_tree({"generator": "test_damper_chain", "length": 3})["nodes"]) == ["n0", "n1", "n2"]
        assert list(issues_of({"generator": "test_damper_chain", "length": 0})) == ["tree.length"]
    finally:
        TREE_GENERATORS.unregister("test_damper_chain")


def _panda_spec(**options):

    from manipulators import robot, scene

    from rmpfusion.envs.manipulator_tree import manipulator_tree_spec

    return manipulator_tree_spec(robot("panda"), scene("franka_three_obstacles"), **options)


def test_the_arm_leaves_are_options_of_the_manipulator_tree():
    """Self-collision pairs (links far enough apart, spheres apart at home), a tool axis and a velocity cap are
    added only when asked for, each with the settings given (the rest tuned)."""
    plain = _panda_spec()
    assert not any(n.startswith("self_") or n in ("tool_axis", "velocity_limit") for n in plain["nodes"])
    spec = _panda_spec(
        self_collision={"min_separation": 3, "rmp": {"alpha": 0.2}},
        orientation={"target": "tool_direction", "axis": [0.0, 0.0, 1.0]},
        velocity_limits={},
    )
    pairs = [n for n in spec["nodes"] if n.startswith("self_")]
    assert pairs and "20 self-collision barriers" in spec["description"]
    gap = spec["nodes"][pairs[0]]
    assert gap["map"]["type"] == "link_sphere_distance" and gap["rmp"]["alpha"] == 0.2 and gap["rmp"]["r_w"] == 0.2
    assert spec["nodes"]["tool_axis"]["map"]["target"] == "tool_direction" and spec["aux"]["tool_direction"] == 3
    assert spec["nodes"]["velocity_limit"]["map"]["type"] == "velocity_scaled_joints"
    two = _panda_spec(self_collision={"min_separation": 2})
    assert "left out" in two["description"]  # the Panda's conservative spheres two joints apart overlap at home
    tree = rmpfusion.build_tree(spec)
    assert {len(g.nodes) for g in tree.plan.groups} >= {15, 14, 20}  # points, barriers per shape, gaps: one group each


def test_self_collision_pairs_leave_out_spheres_that_overlap_at_home():

    import torch
    from manipulators import robot

    from rmpfusion.envs.manipulator_tree import self_collision_pairs
    from rmpfusion.maps.kinematics import Chain
    from rmpfusion.robots.description import RobotDescription

    desc = RobotDescription.model_validate(robot("panda"))
    pairs, overlapping = self_collision_pairs(desc, 2)
    assert overlapping > 0 and pairs
    chain = Chain(desc.model(), desc.joints)
    home = torch.tensor([list(desc.home)], dtype=torch.float64)
    for i, j in pairs:
        a, b = desc.control_points[i - 1], desc.control_points[j - 1]
        pa = chain.forward_kinematics(home, [a.link])[a.link]
        pb = chain.forward_kinematics(home, [b.link])[b.link]
        ca = pa[1][0] + pa[0][0] @ torch.tensor(a.offset, dtype=torch.float64)
        cb = pb[1][0] + pb[0][0] @ torch.tensor(b.offset, dtype=torch.float64)
        assert float((ca - cb).norm()) > a.radius + b.radius
