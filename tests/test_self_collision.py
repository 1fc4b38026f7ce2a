"""Self-collision: which link pairs are listed, the sphere gap against pybullet, the shared kinematics pass, and
the collision_avoidance barrier (conf/rmp/self_collision.yaml) keeping the Panda's hand off its upper arm on a
rollout, with Theorem 2. (J and J̇ẋ against finite differences: tests/test_registry_derivatives.py.)"""

from pathlib import Path

import pybullet
import pytest
import torch
import yaml
from conftest import assert_energy_identity, assert_lyapunov_non_increasing, rk4_rollout
from manipulators import IIWA_URDF as IIWA
from manipulators import PANDA_ARM_JOINTS, PANDA_HOME, load_panda_urdf_path, pybullet_robot
from manipulators import robot as robot_description
from reference_tree import node_by_node

import rmpfusion
from rmpfusion.maps import build_map
from rmpfusion.maps.kinematics import Chain
from rmpfusion.maps.self_collision import non_adjacent_link_pairs
from rmpfusion.maps.urdf import parse_urdf

ROOT = Path(__file__).resolve().parents[1]
PANDA = load_panda_urdf_path()
HOME = PANDA_HOME[None]


def sphere(k: int) -> dict:
    """The Panda tree's control sphere k (0-based): 0-1 on link3, 2-3 on link4, 10 on link7, 11-13 on the hand."""
    cp = robot_description("panda")["control_points"][k]
    return {"link": cp["link"], "offset": list(cp["offset"]), "radius": cp["radius"]}


# ------------------------------------------------------------------------------------------------ which pairs
def test_panda_pairs_skip_neighbours_and_links_that_move_together():
    chain = Chain(parse_urdf(PANDA), PANDA_ARM_JOINTS)
    # the arm is serial: link k hangs from joint k; link8, the hand, the fingers (frozen) and the grasp target are
    # fixed to link7; so two links are one joint apart when their bodies differ by one
    body = {f"panda_link{k}": k for k in range(8)}
    body.update(
        {n: 7 for n in ("panda_link8", "panda_hand", "panda_leftfinger", "panda_rightfinger", "panda_grasptarget")}
    )
    links = chain.link_names()
    for separation in (1, 2, 3):
        expect = [(a, b) for i, a in enumerate(links) for b in links[i + 1 :] if abs(body[a] - body[b]) >= separation]
        assert non_adjacent_link_pairs(chain, min_separation=separation) == expect
    pairs = non_adjacent_link_pairs(chain)
    assert ("panda_link5", "panda_hand") in pairs and ("panda_link6", "panda_hand") not in pairs
    assert ("panda_link7", "panda_hand") not in pairs and ("panda_link3", "panda_link5") in pairs


def test_a_branching_chain_counts_joints_through_the_common_link():
    """With the fingers actuated (the second follows the first, URDF <mimic>), the two fingers are two joints apart
    (through the hand), each one from the hand."""
    chain = Chain(parse_urdf(PANDA), [*PANDA_ARM_JOINTS, "panda_finger_joint1"])
    pairs = non_adjacent_link_pairs(chain, ["panda_link6", "panda_hand", "panda_leftfinger", "panda_rightfinger"])
    assert pairs == [
        ("panda_link6", "panda_leftfinger"),
        ("panda_link6", "panda_rightfinger"),
        ("panda_leftfinger", "panda_rightfinger"),
    ]


def test_kuka_iiwa_pairs_and_bad_arguments():
    chain = Chain(parse_urdf(IIWA))
    links = [f"lbr_iiwa_link_{k}" for k in range(8)]
    assert chain.link_names() == links
    assert non_adjacent_link_pairs(chain) == [(links[i], links[j]) for i in range(8) for j in range(i + 2, 8)]
    with pytest.raises(ValueError, match="has no link 'lbr_iiwa_link_9'"):
        non_adjacent_link_pairs(chain, ["lbr_iiwa_link_1", "lbr_iiwa_link_9"])
    with pytest.raises(ValueError, match="min_separation must be ≥ 1"):
        non_adjacent_link_pairs(chain, min_separation=0)


# ------------------------------------------------------------------------------------------------ the gap
@pytest.mark.parametrize(
    "urdf,joints,a,b",
    [
        (PANDA, list(PANDA_ARM_JOINTS), sphere(0), sphere(13)),
        (
            IIWA,
            None,
            {"link": "lbr_iiwa_link_2", "offset": [0.0, 0.03, 0.1], "radius": 0.07},
            {"link": "lbr_iiwa_link_6", "offset": [0.0, 0.05, 0.0], "radius": 0.08},
        ),
    ],
    ids=["panda", "iiwa"],
)
def test_the_gap_is_the_distance_of_sphere_centres_placed_by_pybullet(urdf, joints, a, b, gen):
    m = build_map({"type": "link_sphere_distance", "urdf": urdf, "joints": joints, "a": a, "b": b}, 7, {})
    lo, hi = m.chain.joint_limits()
    q = lo + (hi - lo) * torch.rand(5, 7, generator=gen)
    gap = m.psi(q, None)[:, 0]
    with pybullet_robot(urdf) as (cid, body, index, joint_of):
        moving = [i for name, i in joint_of.items() if name in m.chain.actuated]

        def centre(s):
            pos, orn = pybullet.getLinkState(
                body, index[s["link"]], computeForwardKinematics=True, physicsClientId=cid
            )[4:6]
            R = torch.tensor(pybullet.getMatrixFromQuaternion(orn)).reshape(3, 3)
            return torch.tensor(pos) + R @ torch.tensor(s["offset"])

        for k in range(5):
            for i, v in zip(moving, q[k].tolist()):
                pybullet.resetJointState(body, i, v, physicsClientId=cid)
            expect = (centre(a) - centre(b)).norm() - a["radius"] - b["radius"]
            torch.testing.assert_close(gap[k], expect, rtol=0, atol=1e-6)


def test_sibling_gaps_evaluate_as_one_group_equal_to_each_gap_alone(gen):
    """Gaps on one robot under one parent form one group (2G centres from one pass of the chain); the tree equals
    the node-by-node computation, and the group's rows equal each gap evaluated on its own."""
    pairs = [(0, 13), (2, 12), (3, 10)]
    spec = {
        "root": {"name": "q", "dim": 7},
        "nodes": {
            **{
                f"gap{i}_{j}": {
                    "parent": "q",
                    "map": {
                        "type": "link_sphere_distance",
                        "urdf": PANDA,
                        "joints": list(PANDA_ARM_JOINTS),
                        "a": sphere(i),
                        "b": sphere(j),
                    },
                    "weight": {"type": "mlp", "hidden": [4]},
                    "rmp": {"type": "collision_avoidance", "r_w": 0.5, "alpha": 0.1, "eta": 0.5},
                }
                for i, j in pairs
            },
            "regulariser": {"parent": "q", "map": {"type": "identity"}, "rmp": {"type": "identity_metric"}},
        },
    }
    torch.manual_seed(0)
    tree = rmpfusion.build_tree(spec)
    assert sorted(len(g.nodes) for g in tree.plan.groups) == [1, 3]
    q = HOME + 0.5 * torch.randn(6, 7, generator=gen)
    qd = torch.randn(6, 7, generator=gen)
    out, ref = tree(q, qd), node_by_node(tree, q, qd)
    for field in ("qdd", "f", "M", "V"):
        torch.testing.assert_close(getattr(out, field), ref[field], rtol=1e-12, atol=1e-12)
    gaps = [tree.maps[f"gap{i}_{j}"] for i, j in pairs]
    group = type(gaps[0]).stacked(gaps, q)
    for rows in (group(q[None], qd[None]), group(q.expand(3, 6, 7), qd.expand(3, 6, 7))):  # one parent row, or G
        for g, m in enumerate(gaps):
            for a, b in zip((t[g] for t in rows), m(q, qd)):
                torch.testing.assert_close(a, b, rtol=1e-13, atol=1e-13)


# ------------------------------------------------------------------------------------------------ on a rollout
# A configuration (found by sampling the joint limits) where the hand's front sphere overlaps the upper arm's by
# 3 cm; the joint-space attractor below pulls the arm there from HOME.
FOLDED = [0.0237, -0.3819, 0.6408, -3.0443, -0.3475, 0.0678, 0.8042]
PAIRS = [(0, 12), (0, 13), (2, 13), (3, 13)]  # link3/link4 spheres against hand spheres: non-adjacent links


def folding_tree(self_collision: bool):
    preset = yaml.safe_load((ROOT / "conf" / "rmp" / "self_collision.yaml").read_text())
    nodes = {
        "goal": {
            "parent": "q",
            "map": {"type": "offset", "origin": FOLDED},
            "rmp": {"type": "goal_attractor", "gain": 10.0, "alpha": 5.0, "eta": 3.0},
        },
        "damper": {"parent": "q", "map": {"type": "identity"}, "rmp": {"type": "damper", "w": 0.1, "eta": 2.0}},
        "regulariser": {"parent": "q", "map": {"type": "identity"}, "rmp": {"type": "identity_metric"}},
    }
    for i, j in PAIRS if self_collision else []:
        nodes[f"self_{i}_{j}"] = {
            "parent": "q",
            "map": {
                "type": "link_sphere_distance",
                "urdf": PANDA,
                "joints": list(PANDA_ARM_JOINTS),
                "a": sphere(i),
                "b": sphere(j),
            },
            "rmp": preset,
        }
    return rmpfusion.build_tree({"root": {"name": "q", "dim": 7}, "nodes": nodes})


def test_the_barrier_keeps_the_hand_off_the_upper_arm_and_theorem_2_holds():
    gaps = [
        build_map(
            {
                "type": "link_sphere_distance",
                "urdf": PANDA,
                "joints": list(PANDA_ARM_JOINTS),
                "a": sphere(i),
                "b": sphere(j),
            },
            7,
            {},
        )
        for i, j in PAIRS
    ]
    closest = lambda q: torch.cat([m.psi(q, None) for m in gaps], 1).min(1).values
    assert float(closest(HOME)) > 0.2 and float(closest(torch.tensor([FOLDED]))) < -0.025
    free = rk4_rollout(folding_tree(False), HOME, torch.zeros(1, 7), {}, dt=0.01, steps=200)
    tree = folding_tree(True)
    guarded = rk4_rollout(tree, HOME, torch.zeros(1, 7), {}, dt=0.01, steps=200)
    assert float(closest(free["q"][-1])) < -0.02  # without the leaves the arm folds into itself
    gap = torch.stack([closest(q) for q in guarded["q"]])
    assert float(gap.min()) > 0.003, f"the spheres came within {float(gap.min()):.4f} m"  # 4.9 mm
    assert_lyapunov_non_increasing(guarded)
    near = gap[:, 0] < 0.1  # states where the barriers act
    assert_energy_identity(tree, guarded["q"][near, 0], guarded["qd"][near, 0], {})
