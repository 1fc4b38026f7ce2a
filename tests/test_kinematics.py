"""Panda forward kinematics against pybullet, and the analytic J and J̇ẋ against finite differences / autodiff."""

import re

import numpy as np
import pytest
import torch
from conftest import fd_directional, fd_jacobian
from manipulators import PANDA_ARM_JOINTS, PANDA_URDF, load_panda_urdf_path, pybullet_robot

import rmpfusion.maps.kinematics  # noqa: F401  (registers forward_kinematics)
from rmpfusion.maps.kinematics import Chain, ForwardKinematics, rpy_matrix
from rmpfusion.maps.urdf import parse_urdf, parse_urdf_string
from rmpfusion.registry import TASK_MAPS

pybullet = pytest.importorskip("pybullet")

LINKS = [f"panda_link{i}" for i in range(1, 9)] + ["panda_hand", "panda_grasptarget", "panda_leftfinger"]
DT = torch.float64


@pytest.fixture(scope="module")
def model():
    return parse_urdf(load_panda_urdf_path())


@pytest.fixture(scope="module")
def chain(model):
    return Chain(model, PANDA_ARM_JOINTS)


@pytest.fixture(scope="module")
def bullet():
    """(client, body id, {link name: pybullet link index}); a fixed base at the origin like our root frame."""
    with pybullet_robot(load_panda_urdf_path()) as (cid, body, links, _):
        yield cid, body, links


def random_q(chain, n, seed=0):
    lo, hi = chain.joint_limits()
    g = torch.Generator().manual_seed(seed)
    return lo + torch.rand(n, lo.numel(), generator=g, dtype=DT) * (hi - lo)


def make_map(link="panda_hand", offset=(0.0, 0.0, 0.0), **kw):
    in_dim = kw.pop("in_dim", 7)
    entry = TASK_MAPS.get("forward_kinematics")
    kw.setdefault("urdf", PANDA_URDF)
    kw.setdefault("joints", list(PANDA_ARM_JOINTS) if in_dim in (6, 7) else None)
    return entry.obj(entry.validate({"link": link, "offset": list(offset), **kw}), in_dim, {})


# -- URDF parsing ------------------------------------------------------------------------------------


def test_parse_panda(model, chain):
    assert model.root == "panda_link0"
    assert [j.name for j in model.joints if j.movable] == list(PANDA_ARM_JOINTS) + [
        "panda_finger_joint1",
        "panda_finger_joint2",
    ]
    j2 = model.joint("panda_joint2")
    assert (j2.type, j2.parent, j2.child, j2.rpy[0], j2.axis) == (
        "revolute",
        "panda_link1",
        "panda_link2",
        -1.57079632679,
        (0, 0, 1),
    )
    assert model.joint("panda_hand_joint").type == "fixed"
    lo, hi = chain.joint_limits()
    assert torch.allclose(lo, torch.tensor([-2.9671, -1.8326, -2.9671, -3.1416, -2.9671, -0.0873, -2.9671], dtype=DT))
    assert torch.allclose(hi, torch.tensor([2.9671, 1.8326, 2.9671, 0.0, 2.9671, 3.8223, 2.9671], dtype=DT))
    assert chain.link_names()[0] == "panda_link0" and "panda_hand" in chain.link_names()
    assert [j.name for j in model.path_to("panda_hand")][-2:] == ["panda_joint8", "panda_hand_joint"]


def test_parse_errors():
    with pytest.raises(ValueError, match="root"):
        parse_urdf_string('<robot name="r"><link name="a"/><link name="b"/></robot>')
    with pytest.raises(ValueError, match="not supported"):
        parse_urdf_string(
            '<robot name="r"><link name="a"/><link name="b"/>'
            '<joint name="j" type="floating"><parent link="a"/><child link="b"/></joint></robot>'
        )


@pytest.mark.parametrize(
    "link_a, joint, parent, child, message",
    [
        ("<link/>", 'name="j"', 'link="a"', 'link="b"', 'URDF <link> has no name="..."'),
        ('<link name="a"/>', "", 'link="a"', 'link="b"', 'URDF <joint> has no name="..."'),
        ('<link name="a"/>', 'name="j"', "", 'link="b"', "URDF joint 'j' <parent> has no link=\"...\""),
        ('<link name="a"/>', 'name="j"', 'link="a"', "", "URDF joint 'j' <child> has no link=\"...\""),
    ],
)
def test_a_link_or_joint_without_the_name_urdf_requires_is_refused_naming_the_element(
    link_a, joint, parent, child, message
):
    """A joint or link without its name, or a joint's parent or child without the link it names, means nothing:
    the file is refused naming the element, never read with a name of None."""
    text = (
        f'<robot name="r">{link_a}<link name="b"/>'
        f'<joint {joint} type="revolute"><parent {parent}/><child {child}/><axis xyz="0 0 1"/>'
        '<limit lower="-1" upper="1" effort="1" velocity="1"/></joint></robot>'
    )
    with pytest.raises(ValueError, match=re.escape(message)):
        parse_urdf_string(text)


def test_rpy_matches_pybullet():
    rpy = [0.3, -1.1, 2.5]
    R = np.array(pybullet.getMatrixFromQuaternion(pybullet.getQuaternionFromEuler(rpy))).reshape(3, 3)
    assert np.abs(rpy_matrix(rpy).numpy() - R).max() < 1e-7  # pybullet's quaternion API is float32-rounded


# -- forward kinematics vs pybullet -----------------------------------------------------------------


def test_fk_matches_pybullet(chain, bullet):
    cid, body, index = bullet
    q = random_q(chain, 20, seed=1)
    fk = chain.forward_kinematics(q, LINKS)
    err_p = err_R = 0.0
    for b in range(q.shape[0]):
        for i, v in enumerate(q[b].tolist()):
            pybullet.resetJointState(body, i, v, physicsClientId=cid)
        for link in LINKS:
            st = pybullet.getLinkState(body, index[link], computeForwardKinematics=True, physicsClientId=cid)
            p_ref = np.array(st[4])  # URDF link frame, not the inertial frame at st[0]
            R_ref = np.array(pybullet.getMatrixFromQuaternion(st[5])).reshape(3, 3)
            R, p = fk[link]
            err_p = max(err_p, np.abs(p[b].numpy() - p_ref).max())
            err_R = max(err_R, np.abs(R[b].numpy() - R_ref).max())
    print(f"max |Δp| = {err_p:.2e}, max |ΔR| = {err_R:.2e}")
    # getLinkState reports float32-rounded poses, so ~1e-7 is the floor of this comparison
    assert err_p < 1e-6 and err_R < 1e-6


def test_fk_root_and_orthonormal(chain):
    q = random_q(chain, 5, seed=2)
    fk = chain.forward_kinematics(q)
    R0, p0 = fk["panda_link0"]
    assert torch.equal(R0, torch.eye(3, dtype=DT).expand(5, 3, 3)) and torch.equal(p0, torch.zeros(5, 3, dtype=DT))
    for R, _ in fk.values():
        assert torch.allclose(R.transpose(-1, -2) @ R, torch.eye(3, dtype=DT).expand_as(R), atol=1e-13)
        assert torch.allclose(torch.linalg.det(R), torch.ones(5, dtype=DT), atol=1e-13)


# -- Jacobian ------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "link,offset",
    [("panda_link3", (0.01, -0.02, 0.05)), ("panda_link8", (0.0, 0.0, 0.0)), ("panda_hand", (0.02, 0.03, 0.1))],
)
def test_jacobian_matches_pybullet(chain, model, bullet, link, offset):
    """calculateJacobian runs in double, so this checks J and the world joint axes to ~1e-12.

    Its localPosition is the point relative to the link-frame origin expressed in the inertial frame's
    orientation (not relative to the COM as the docs suggest; bullet3 issue #4668), hence the conversion.
    """
    cid, body, index = bullet
    fkm = make_map(link, offset)
    q = random_q(chain, 20, seed=3)
    J = fkm.jacobian(q)
    _, _, _O, Z = fkm.chain.path_frames(q, link)
    Jw = torch.einsum("bki,kn->bin", Z, fkm.select)  # angular Jacobian: world axes of the path joints
    R_in = rpy_matrix(model.link(link).inertial_rpy)
    local = (R_in.T @ torch.tensor(offset, dtype=DT)).tolist()
    err = 0.0
    for b in range(q.shape[0]):
        qq = q[b].tolist() + [0.0, 0.0]  # the two finger joints are DoFs too in pybullet
        Jt, Jr = pybullet.calculateJacobian(body, index[link], local, qq, [0.0] * 9, [0.0] * 9, physicsClientId=cid)
        Jt, Jr = np.array(Jt), np.array(Jr)
        assert np.abs(Jt[:, 7:]).max() == 0.0
        err = max(err, np.abs(J[b].numpy() - Jt[:, :7]).max(), np.abs(Jw[b].numpy() - Jr[:, :7]).max())
    print(f"{link}: max |J − J_pybullet| = {err:.2e}")
    assert err < 1e-10


@pytest.mark.parametrize("link", ["panda_link4", "panda_link7", "panda_hand", "panda_grasptarget"])
def test_jacobian_vs_fd_and_autodiff(chain, link):
    fkm = make_map(link, (0.05, -0.01, 0.02))
    q = random_q(chain, 6, seed=4)
    J = fkm.jacobian(q)
    f = lambda z: fkm.psi(z, None)
    assert torch.allclose(J, fd_jacobian(f, q), atol=1e-8)
    qg = q.clone().requires_grad_(True)
    y = f(qg)
    J_ad = torch.stack([torch.autograd.grad(y[:, i].sum(), qg, retain_graph=True)[0] for i in range(3)], 1)
    assert torch.allclose(J, J_ad, atol=1e-13)  # reverse mode through psi: exact, unlike fd


# -- J̇ẋ ------------------------------------------------------------------------------------------------


def _second_directional_reverse(f, q, qd):
    """d²f[q̇, q̇] by double backward: exact, and avoids torch.func's one-off warm-up cost in this file."""
    qg = q.clone().requires_grad_(True)
    y = f(qg)
    out = []
    for i in range(y.shape[1]):
        g = torch.autograd.grad(y[:, i].sum(), qg, create_graph=True)[0]
        h = torch.autograd.grad((g * qd).sum(), qg, retain_graph=True)[0]
        out.append((h * qd).sum(-1))
    return torch.stack(out, -1)


def _check_curvature(fkm, q, qd):
    y, yd, J, c = fkm(q, qd)
    Jv = lambda z: (fkm.jacobian(z) @ qd.unsqueeze(-1)).squeeze(-1)
    c_fd = fd_directional(Jv, q, qd, eps=1e-5)
    scale = c_fd.abs().max()
    assert (c - c_fd).abs().max() < 1e-6 * scale
    assert torch.allclose(c, _second_directional_reverse(lambda z: fkm.psi(z, None), q, qd), atol=1e-12)
    assert torch.allclose(y, fkm.psi(q, None), atol=0) and torch.allclose(yd, (J @ qd.unsqueeze(-1)).squeeze(-1))
    assert torch.allclose(fkm.curvature(q, qd, None, J), c, atol=0)
    return (c - c_fd).abs().max() / scale


@pytest.mark.parametrize("link", ["panda_link2", "panda_link5", "panda_hand"])
def test_curvature_vs_fd(chain, link):
    fkm = make_map(link, (0.03, 0.02, -0.04))
    q = random_q(chain, 8, seed=5)
    qd = torch.randn(8, 7, generator=torch.Generator().manual_seed(6), dtype=DT)
    print(f"{link}: relative |J̇ẋ − fd| = {_check_curvature(fkm, q, qd):.2e}")


def test_prismatic_jacobian_and_curvature(chain):
    """The fingers as extra actuated joints exercise the prismatic columns and their J̇ẋ term."""
    joints = list(PANDA_ARM_JOINTS) + ["panda_finger_joint1"]
    fkm = make_map("panda_leftfinger", (0.0, 0.01, 0.02), urdf=load_panda_urdf_path(), joints=joints, in_dim=8)
    q = torch.cat([random_q(chain, 5, seed=7), torch.rand(5, 1, dtype=DT) * 0.04], 1)
    qd = torch.randn(5, 8, generator=torch.Generator().manual_seed(8), dtype=DT)
    assert torch.allclose(fkm.jacobian(q), fd_jacobian(lambda z: fkm.psi(z, None), q), atol=1e-8)
    _check_curvature(fkm, q, qd)


def test_root_link_is_constant():
    fkm = make_map("panda_link0", (0.1, 0.0, 0.0))
    q = torch.zeros(2, 7, dtype=DT)
    y, yd, J, c = fkm(q, torch.ones(2, 7, dtype=DT))
    assert torch.allclose(y, torch.tensor([[0.1, 0.0, 0.0]] * 2, dtype=DT))
    assert J.shape == (2, 3, 7) and not J.any() and not yd.any() and not c.any()


# -- batching, gradients, dtypes -----------------------------------------------------------------------


def test_batch_consistency(chain):
    fkm = make_map("panda_hand", (0.0, 0.0, 0.1))
    q = random_q(chain, 7, seed=9)
    qd = torch.randn(7, 7, generator=torch.Generator().manual_seed(10), dtype=DT)
    batched = fkm(q, qd)
    for b in range(q.shape[0]):
        single = fkm(q[b : b + 1], qd[b : b + 1])
        for full, one in zip(batched, single):
            assert torch.allclose(full[b : b + 1], one, atol=1e-15, rtol=0)


def test_gradcheck_psi(chain):
    fkm = make_map("panda_link8", (0.01, 0.02, 0.03))
    q = random_q(chain, 3, seed=11).requires_grad_(True)
    assert torch.autograd.gradcheck(lambda z: fkm.psi(z, None), (q,))
    # the analytic J and J̇ẋ are differentiable too (a learned metric may back-propagate through them)
    qd = torch.randn(3, 7, dtype=DT)
    assert torch.autograd.gradcheck(lambda z: fkm(z, qd)[3], (q,))


def test_float32_inputs(chain):
    fkm = make_map("panda_hand")
    q = random_q(chain, 4, seed=12)
    y32 = fkm.psi(q.float(), None)
    assert y32.dtype == torch.float32
    assert torch.allclose(y32.double(), fkm.psi(q, None), atol=1e-5)


# -- task-map spec --------------------------------------------------------------------------------------


def test_map_spec_and_errors():
    fkm = make_map("panda_hand")
    assert isinstance(fkm, ForwardKinematics) and fkm.out_dim == 3 and fkm.in_dim == 7
    assert "panda_hand" in fkm.link_names()
    assert torch.equal(fkm.joint_limits()[0], Chain(parse_urdf(load_panda_urdf_path()), PANDA_ARM_JOINTS).lower)
    with pytest.raises(ValueError, match="dimension 6 .* 7 actuated joints"):
        make_map("panda_hand", in_dim=6)  # the 7 arm joints under a 6-D parent
    with pytest.raises(ValueError, match="no link 'panda_hnad'.*panda_hand"):
        make_map("panda_hnad")
    with pytest.raises(
        ValueError,
        match=r"robot \('panda'\) was retired: robots are described in "
        r"conf/robot/<name>.yaml; write that file's urdf and joints here",
    ):
        make_map("panda_hand", robot="panda")
    with pytest.raises(ValueError, match="is fixed"):
        make_map("panda_hand", joints=["panda_joint8"], in_dim=1)
    # by default every movable joint is actuated but the second finger, which follows the first (URDF <mimic>)
    assert make_map("panda_hand", in_dim=8).chain.dof == 8
