"""The orientation maps and the orientation attractor: link axes against pybullet, the potential against the
rotation angle, Theorem 2 on rollouts (Panda tool axis, KUKA iiwa full orientation), and that they align.
(J and J̇ẋ against finite differences: tests/test_registry_derivatives.py.)"""

import pybullet
import pytest
import torch
from conftest import assert_energy_identity, assert_lyapunov_non_increasing, rk4_rollout
from manipulators import IIWA_URDF as IIWA
from manipulators import PANDA_ARM_JOINTS, load_panda_urdf_path, pybullet_robot
from manipulators import PANDA_HOME as HOME

import rmpfusion
from rmpfusion.maps.kinematics import Chain
from rmpfusion.maps.orientation import quaternion_matrix
from rmpfusion.maps.urdf import parse_urdf
from rmpfusion.registry import TASK_MAPS

PANDA = load_panda_urdf_path()


def build_map(params: dict, aux_dims=None):
    entry = TASK_MAPS.get(params.pop("type"))
    return entry.obj(entry.validate(params), 7, aux_dims or {})


def rotation_angle(R, R_target):
    """The angle of the rotation from R_target to R, in radians, from the trace."""
    c = ((R_target.transpose(1, 2) @ R).diagonal(dim1=1, dim2=2).sum(-1) - 1) / 2
    return torch.acos(c.clamp(-1, 1))


def test_quaternions_become_pybullets_rotation_matrices(gen):
    quat = torch.randn(5, 4, generator=gen)
    R = quaternion_matrix(quat)  # normalised inside
    R_wxyz = quaternion_matrix(quat[:, [3, 0, 1, 2]], scalar_last=False)
    for b in range(5):
        unit = (quat[b] / quat[b].norm()).tolist()
        expect = torch.tensor(pybullet.getMatrixFromQuaternion(unit)).reshape(3, 3)
        torch.testing.assert_close(R[b], expect, rtol=0, atol=1e-12)
        torch.testing.assert_close(R_wxyz[b], expect, rtol=0, atol=1e-12)


@pytest.mark.parametrize(
    "urdf,joints,link",
    [(PANDA, PANDA_ARM_JOINTS, "panda_hand"), (IIWA, None, "lbr_iiwa_link_7"), (IIWA, None, "lbr_iiwa_link_4")],
    ids=["panda_hand", "iiwa_link_7", "iiwa_link_4"],
)
def test_link_axes_are_the_columns_of_pybullets_link_orientation(urdf, joints, link, gen):
    m = build_map({"type": "link_orientation", "urdf": urdf, "joints": joints, "link": link})
    lo, hi = m.chain.joint_limits()
    q = lo + (hi - lo) * torch.rand(4, 7, generator=gen)
    axes = m.psi(q, None).reshape(4, 3, 3)  # row k: the link's axis k in the world
    with pybullet_robot(urdf) as (cid, body, index, joint_of):
        joint_index = [i for name, i in joint_of.items() if name in m.chain.actuated]
        for b in range(4):
            for i, v in zip(joint_index, q[b].tolist()):
                pybullet.resetJointState(body, i, v, physicsClientId=cid)
            orn = pybullet.getLinkState(body, index[link], computeForwardKinematics=True, physicsClientId=cid)[5]
            R = torch.tensor(pybullet.getMatrixFromQuaternion(orn)).reshape(3, 3)
            torch.testing.assert_close(axes[b], R.T, rtol=0, atol=1e-6)


def test_the_potential_measures_the_angle_to_the_target(gen):
    """½|e|² = 1 − cos θ for one axis; with the three axes of the frame, 2(1 − cos φ) with φ the rotation angle."""
    q = HOME + 0.5 * torch.randn(6, 7, generator=gen)
    quat = torch.randn(6, 4, generator=gen)
    frame = build_map(
        {
            "type": "link_orientation",
            "urdf": PANDA,
            "joints": list(PANDA_ARM_JOINTS),
            "link": "panda_hand",
            "target": "target",
        },
        {"target": 4},
    )
    e = frame.psi(q, {"target": quat})
    R, _ = frame.chain.forward_kinematics(q, ["panda_hand"])["panda_hand"]
    phi = rotation_angle(R, quaternion_matrix(quat))
    torch.testing.assert_close(0.5 * (e * e).sum(-1), 2 * (1 - torch.cos(phi)))
    direction = torch.randn(6, 3, generator=gen)
    tool = build_map(
        {
            "type": "link_axis",
            "urdf": PANDA,
            "joints": list(PANDA_ARM_JOINTS),
            "link": "panda_hand",
            "axis": [0, 0, 2.0],
            "target": "d",
        },
        {"d": 3},
    )
    e = tool.psi(q, {"d": direction})
    cos_theta = (R[:, :, 2] * direction).sum(-1) / direction.norm(dim=-1)
    torch.testing.assert_close(0.5 * (e * e).sum(-1), 1 - cos_theta)


def panda_tool_tree():
    """The end effector to a goal position with the hand's z axis (the tool axis) along a target direction; the
    orientation edge carries a random positive neural weight, so pullback*'s h terms take part."""
    return rmpfusion.build_tree(
        {
            "root": {"name": "q", "dim": 7},
            "aux": {"goal": 3, "tool_direction": 3},
            "nodes": {
                "ee": {
                    "parent": "q",
                    "map": {
                        "type": "forward_kinematics",
                        "urdf": PANDA,
                        "joints": list(PANDA_ARM_JOINTS),
                        "link": "panda_hand",
                        "offset": [0, 0, 0.1034],
                    },
                },
                "reach": {
                    "parent": "ee",
                    "map": {"type": "offset", "origin": "goal"},
                    "rmp": {"type": "goal_attractor", "gain": 5.0, "alpha": 10.0, "eta": 5.0},
                },
                "tool": {
                    "parent": "q",
                    "map": {
                        "type": "link_axis",
                        "urdf": PANDA,
                        "joints": list(PANDA_ARM_JOINTS),
                        "link": "panda_hand",
                        "target": "tool_direction",
                    },
                    "weight": {"type": "mlp", "hidden": [16], "aux": ["tool_direction"]},
                    "rmp": {"type": "orientation_attractor", "gain": 10.0, "eta": 5.0, "w_u": 3.0, "sigma": 0.3},
                },
                "damper": {"parent": "q", "map": {"type": "identity"}, "rmp": {"type": "damper", "w": 0.1, "eta": 5.0}},
                "regulariser": {"parent": "q", "map": {"type": "identity"}, "rmp": {"type": "identity_metric"}},
            },
        }
    )


def test_theorem_2_and_alignment_on_panda_tool_axis_rollouts():
    torch.manual_seed(0)
    tree = panda_tool_tree()
    g = torch.Generator().manual_seed(0)
    q0 = HOME + 0.3 * torch.randn(4, 7, generator=g)
    q_target = HOME + 0.5 * torch.randn(4, 7, generator=g)  # a reachable pose: position and tool axis of q_target
    R, p = tree.maps["ee"].chain.forward_kinematics(q_target, ["panda_hand"])["panda_hand"]
    aux = {"goal": p + 0.1034 * R[:, :, 2], "tool_direction": R[:, :, 2]}
    rec = rk4_rollout(tree, q0, torch.zeros(4, 7), aux, dt=0.01, steps=300)
    assert_lyapunov_non_increasing(rec)
    assert_energy_identity(
        tree, rec["q"][::50].flatten(0, 1), rec["qd"][::50].flatten(0, 1), {k: v.repeat(7, 1) for k, v in aux.items()}
    )
    angle = lambda q: torch.acos(
        (tree.maps["tool"].psi(q, aux) + aux["tool_direction"]).mul(aux["tool_direction"]).sum(-1).clamp(-1, 1)
    )
    start, end = angle(rec["q"][0]), angle(rec["q"][-1])
    assert float(start.min()) > 0.5 and float(end.max()) < 0.15, (start, end)  # from 30-75° to within 9°


def test_kuka_iiwa_reaches_a_target_orientation_given_as_a_quaternion():
    """Full orientation on a second robot: from up to 165° away, within 3° of the target quaternion in 3 s, with
    V_r non-increasing on the way."""
    tree = rmpfusion.build_tree(
        {
            "root": {"name": "q", "dim": 7},
            "aux": {"target": 4},
            "nodes": {
                "frame": {
                    "parent": "q",
                    "map": {"type": "link_orientation", "urdf": IIWA, "link": "lbr_iiwa_link_7", "target": "target"},
                    "rmp": {"type": "orientation_attractor", "gain": 10.0, "eta": 3.0},
                },
                "damper": {
                    "parent": "q",
                    "map": {"type": "identity"},
                    "rmp": {"type": "damper", "w": 0.01, "eta": 1.0},
                },
                "regulariser": {"parent": "q", "map": {"type": "identity"}, "rmp": {"type": "identity_metric"}},
            },
        }
    )
    g = torch.Generator().manual_seed(0)
    q0 = 0.5 * torch.randn(4, 7, generator=g)
    quat = torch.randn(4, 4, generator=g)
    rec = rk4_rollout(tree, q0, torch.zeros(4, 7), {"target": quat}, dt=0.01, steps=300)
    assert_lyapunov_non_increasing(rec)
    assert_energy_identity(
        tree, rec["q"][::50].flatten(0, 1), rec["qd"][::50].flatten(0, 1), {"target": quat.repeat(7, 1)}
    )
    chain = Chain(parse_urdf(IIWA))
    angle = lambda q: rotation_angle(
        chain.forward_kinematics(q, ["lbr_iiwa_link_7"])["lbr_iiwa_link_7"][0],
        quaternion_matrix(quat),
    )
    assert float(angle(rec["q"][0]).max()) > 2.5
    assert float(angle(rec["q"][-1]).max()) < torch.deg2rad(torch.tensor(3.0))
