"""The joint-velocity cap: velocity_scaled_joints reads the URDF's limits, and the velocity_limit leaf keeps every
joint below its limit on rollouts (Panda, KUKA iiwa) with Theorem 2 and the energy bound of docs/math.md §8.
(M and f against the GDS definitions by finite differences: tests/test_registry_derivatives.py.)"""

from pathlib import Path

import pybullet_data
import pytest
import torch
from conftest import assert_energy_identity, assert_lyapunov_non_increasing, rk4_rollout

import rmpfusion
from rmpfusion.maps import build_map
from rmpfusion.rmps.velocity_limit import band_metric

IIWA = str(Path(pybullet_data.getDataPath()) / "kuka_iiwa" / "model.urdf")
HOME = torch.tensor([[0.0, -0.3, 0.0, -2.2, 0.0, 2.0, 0.8]])
PANDA = {"urdf": "pkg://pybullet_data/franka_panda/panda.urdf", "joints": [f"panda_joint{i}" for i in range(1, 8)]}
PANDA_LIMITS = torch.tensor([2.175, 2.175, 2.175, 2.175, 2.61, 2.61, 2.61])  # rad/s, franka_panda/panda.urdf


def test_velocity_scaled_joints_divides_by_the_urdfs_limits_or_the_given_ones(gen):
    q, qd = torch.randn(3, 7, generator=gen), torch.randn(3, 7, generator=gen)
    panda = build_map({"type": "velocity_scaled_joints", **PANDA}, 7, {})
    y, yd, _J, c = panda(q, qd)
    torch.testing.assert_close(yd, qd / PANDA_LIMITS)
    torch.testing.assert_close(y, q / PANDA_LIMITS)
    assert float(c.abs().max()) == 0.0
    iiwa = build_map({"type": "velocity_scaled_joints", "urdf": IIWA}, 7, {})
    torch.testing.assert_close(iiwa(q, qd)[1], qd / 10.0)  # kuka_iiwa/model.urdf: velocity="10" on every joint
    given = [1.0, 2.0, 1.5, 1.0, 3.0, 2.0, 2.5]
    iiwa = build_map({"type": "velocity_scaled_joints", "urdf": IIWA, "velocity_limit": given}, 7, {})
    torch.testing.assert_close(iiwa(q, qd)[1], qd / torch.tensor(given))
    with pytest.raises(ValueError, match="has 2 values for the 7 actuated joints"):
        build_map({"type": "velocity_scaled_joints", **PANDA, "velocity_limit": [1.0, 2.0]}, 7, {})


def joint_goal_tree(gain: float, target, cap: dict | None):
    """A strong joint-space attractor (it alone drives joints past their limits), optionally with the cap."""
    nodes = {
        "goal": {
            "parent": "q",
            "map": {"type": "offset", "origin": target},
            "rmp": {"type": "goal_attractor", "gain": gain, "alpha": 5.0, "eta": 1.0},
        },
        "regulariser": {"parent": "q", "map": {"type": "identity"}, "rmp": {"type": "identity_metric"}},
    }
    if cap is not None:
        nodes["cap"] = {"parent": "q", "map": cap, "rmp": {"type": "velocity_limit"}}
    return rmpfusion.build_tree({"root": {"name": "q", "dim": 7}, "nodes": nodes})


def test_the_cap_keeps_every_panda_joint_below_its_urdf_limit():
    target = (HOME[0] + torch.tensor([1.5, 0.8, -1.5, 1.2, 1.5, -1.0, 1.5])).tolist()
    free = rk4_rollout(joint_goal_tree(12.0, target, None), HOME, torch.zeros(1, 7), {}, dt=0.01, steps=250)
    tree = joint_goal_tree(12.0, target, {"type": "velocity_scaled_joints", **PANDA})
    capped = rk4_rollout(tree, HOME, torch.zeros(1, 7), {}, dt=0.01, steps=250)
    ratio = lambda rec: (rec["qd"][:, 0].abs() / PANDA_LIMITS).max()
    assert float(ratio(free)) > 1.3  # the attractor alone exceeds the limits by 30 %
    assert float(ratio(capped)) < 1.0
    assert_lyapunov_non_increasing(capped)
    assert_energy_identity(tree, capped["q"][::25, 0], capped["qd"][::25, 0], {})
    # docs/math.md §8: every joint's share of the cap's energy, ½·g(ẏ_i)·ẏ_i², stays below V_r(0), and V_r(0) is
    # below ½·w·φ(1)·L² (L = 1 in the scaled space), which is what keeps ẏ_i below the limit
    leaf = tree.rmps["cap"]
    yd = capped["qd"][:, 0] / PANDA_LIMITS
    share = 0.5 * torch.diagonal(leaf.metric(yd, yd), dim1=1, dim2=2) * yd**2
    V0 = float(capped["V"][0, 0])
    assert float(share.max()) <= V0
    phi_at_limit = float(band_metric(torch.tensor(1.0), leaf.linear_from)[0])
    assert V0 < 0.5 * leaf.w * phi_at_limit


def test_kuka_iiwa_from_beyond_its_limits_is_braked_back_and_stays_stable():
    """Given limits (overriding the URDF's 10 rad/s), a start at 1.5 times them: the metric is finite there, the
    joints slow down monotonically towards their limits, and V_r never increases."""
    limits = [1.0, 1.0, 1.2, 1.2, 1.5, 1.5, 2.0]
    tree = joint_goal_tree(3.0, [1.0] * 7, {"type": "velocity_scaled_joints", "urdf": IIWA, "velocity_limit": limits})
    L = torch.tensor(limits)
    qd0 = 1.5 * L * torch.tensor([[1.0, -1.0, 1.0, -1.0, 1.0, -1.0, 1.0]])
    rec = rk4_rollout(tree, torch.zeros(1, 7), qd0, {}, dt=0.01, steps=150)
    worst = (rec["qd"][:, 0].abs() / L).max(1).values
    assert torch.isfinite(rec["V"]).all() and (worst[1:] <= worst[:-1]).all() and float(worst[-1]) < 1.1
    assert_lyapunov_non_increasing(rec)
    assert_energy_identity(tree, rec["q"][::30, 0], rec["qd"][::30, 0], {})
