"""Batched forward kinematics of URDF chains in torch, and a task map to a point on a robot link.

Everything is plain torch so FK composes with autograd and torch.func; the task map nevertheless supplies
the geometric Jacobian and J̇ẋ analytically because they are cheap and exact, while autodiff of a deep
chain of 3×3 products costs one pass per joint.
"""
from __future__ import annotations

import difflib
import math
from typing import Mapping, Sequence

import torch
from pydantic import Field, model_validator
from torch import Tensor, nn

from ..core.algebra import matmul_small, matvec
from ..core.taskmap import TaskMap
from ..registry import TASK_MAPS, Params
from .urdf import URDFModel, parse_urdf, resolve_urdf_path

FIXED, REVOLUTE, PRISMATIC = 0, 1, 2
Pose = tuple[Tensor, Tensor]


def rpy_matrix(rpy: Sequence[float]) -> Tensor:
    """URDF fixed-axis roll-pitch-yaw, R = Rz(y) Ry(p) Rx(r), in float64 so constants lose nothing."""
    r, p, y = (float(v) for v in rpy)
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
    return torch.tensor(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ],
        dtype=torch.float64,
    )


def _skew(v: Tensor) -> Tensor:
    x, y, z = v.tolist()
    return torch.tensor([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]], dtype=torch.float64)


def _suggest(name: str, options: Sequence[str]) -> str:
    close = difflib.get_close_matches(name, list(options), n=3, cutoff=0.5)
    return f"did you mean {', '.join(repr(c) for c in close)}? " if close else ""


class Chain(nn.Module):
    """Forward kinematics of a URDF tree for a chosen set of actuated joints.

    Movable joints that are not actuated (e.g. the Panda fingers for the 7-DOF arm) are frozen at 0. The
    root link frame is the world frame. Constants are float64 buffers cast to the input's dtype on use, so
    float64 inputs get full precision whatever the default dtype was at construction.
    """

    def __init__(self, model: URDFModel, actuated: Sequence[str] | None = None):
        super().__init__()
        self.model = model
        movable = model.movable_joint_names()
        actuated = list(movable if actuated is None else actuated)
        for name in actuated:
            if name not in movable:
                what = "is fixed" if name in [j.name for j in model.joints] else "does not exist"
                raise ValueError(f"actuated joint '{name}' {what} in URDF '{model.name}'; "
                                 f"{_suggest(name, movable)}movable joints: {', '.join(movable)}")
        if len(set(actuated)) != len(actuated):
            raise ValueError(f"actuated joints contain duplicates: {actuated}")
        self.actuated: tuple[str, ...] = tuple(actuated)
        self.dof = len(actuated)
        self._links: tuple[str, ...] = tuple(model.link_names())  # root, then joint k's child at k + 1
        self._link_index = {n: i for i, n in enumerate(self._links)}
        self._parent = [self._link_index[j.parent] for j in model.joints]
        self._qidx, self._kind = [], []
        for j in model.joints:
            act = j.name in actuated
            self._qidx.append(actuated.index(j.name) if act else -1)
            kind = FIXED if not act else (PRISMATIC if j.type == "prismatic" else REVOLUTE)
            self._kind.append(kind)
        K = len(model.joints)
        R0 = torch.stack([rpy_matrix(j.rpy) for j in model.joints]) if K else torch.zeros(0, 3, 3, dtype=torch.float64)
        p0 = torch.tensor([j.xyz for j in model.joints], dtype=torch.float64).reshape(K, 3)
        axis = torch.tensor([j.axis for j in model.joints], dtype=torch.float64).reshape(K, 3)
        # Rodrigues folded into the origin: R0·Rot(a, q) = R0 + sin q·R0[a]× + (1 − cos q)·R0[a]×²
        Ks = torch.stack([_skew(a) for a in axis]) if K else torch.zeros(0, 3, 3, dtype=torch.float64)
        self.register_buffer("origin_R", R0)
        self.register_buffer("origin_p", p0)
        self.register_buffer("origin_axis", (R0 @ axis.unsqueeze(-1)).squeeze(-1))  # axis in the parent frame
        self.register_buffer("rot_sin", R0 @ Ks)
        self.register_buffer("rot_cos", R0 @ Ks @ Ks)
        joints = [model.joint(n) for n in actuated]
        self.register_buffer("lower", torch.tensor([j.lower for j in joints], dtype=torch.float64))
        self.register_buffer("upper", torch.tensor([j.upper for j in joints], dtype=torch.float64))
        self.register_buffer("velocity_limit", torch.tensor([j.velocity for j in joints], dtype=torch.float64))

    # -- queries -----------------------------------------------------------------------------------
    def link_names(self) -> list[str]:
        return list(self._links)

    def joint_limits(self) -> tuple[Tensor, Tensor]:
        """(lower, upper) of the actuated joints, in their order; ±inf for continuous joints."""
        return self.lower.clone(), self.upper.clone()

    def check_link(self, link: str) -> int:
        if link not in self._link_index:
            raise ValueError(f"URDF '{self.model.name}' has no link '{link}'; {_suggest(link, self._links)}"
                             f"links: {', '.join(self._links)}")
        return self._link_index[link]

    def path_joints(self, link: str) -> list[int]:
        """Indices (into the URDF joint list) of the joints from the root to ``link``."""
        i, path = self.check_link(link), []
        while i > 0:
            path.append(i - 1)
            i = self._parent[i - 1]
        return path[::-1]

    # -- kinematics --------------------------------------------------------------------------------
    def _check_q(self, q: Tensor) -> None:
        if q.dim() != 2 or q.shape[1] != self.dof:
            raise ValueError(f"q must be (B, {self.dof}) for actuated joints {list(self.actuated)}, got {tuple(q.shape)}")

    def _step(self, k: int, parent: Pose, q: Tensor) -> tuple[Pose, Tensor, Tensor]:
        """Child pose of joint k, plus the joint's world origin and world axis (before its own motion)."""
        Rp, pp = parent
        c = lambda name: getattr(self, name)[k].to(q)  # noqa: E731
        o = pp + matvec(Rp, c("origin_p"))
        z = matvec(Rp, c("origin_axis"))
        kind, qi = self._kind[k], self._qidx[k]
        if kind == REVOLUTE:
            s, cq = torch.sin(q[:, qi]), torch.cos(q[:, qi])
            Rl = c("origin_R") + s[:, None, None] * c("rot_sin") + (1 - cq)[:, None, None] * c("rot_cos")
            return (matmul_small(Rp, Rl), o), o, z
        if kind == PRISMATIC:
            return (matmul_small(Rp, c("origin_R")), o + z * q[:, qi, None]), o, z
        return (matmul_small(Rp, c("origin_R")), o), o, z

    def _root(self, q: Tensor) -> Pose:
        B = q.shape[0]
        return torch.eye(3, dtype=q.dtype, device=q.device).expand(B, 3, 3), q.new_zeros(B, 3)

    def forward_kinematics(self, q: Tensor, links: Sequence[str] | None = None) -> dict[str, Pose]:
        """World poses {link: (R (B,3,3), p (B,3))} of ``links`` (default all); only their ancestors are computed."""
        self._check_q(q)
        wanted = list(self._links) if links is None else list(links)
        need = set()
        for name in wanted:
            need.update(self.path_joints(name))
        poses: dict[int, Pose] = {0: self._root(q)}
        for k in sorted(need):
            poses[k + 1] = self._step(k, poses[self._parent[k]], q)[0]
        return {name: poses[self._link_index[name]] for name in wanted}

    def path_frames(self, q: Tensor, link: str) -> tuple[Pose, list[int], Tensor, Tensor]:
        """Pose of ``link`` and, for the actuated joints on its path, (q indices, world origins O (B,k,3),
        world axes Z (B,k,3)): everything the geometric Jacobian needs, in one pass."""
        self._check_q(q)
        pose, qs, Os, Zs = self._root(q), [], [], []
        for k in self.path_joints(link):
            pose, o, z = self._step(k, pose, q)
            if self._kind[k] != FIXED:
                qs.append(self._qidx[k])
                Os.append(o)
                Zs.append(z)
        B = q.shape[0]
        empty = q.new_zeros(B, 0, 3)
        O = torch.stack(Os, 1) if Os else empty
        Z = torch.stack(Zs, 1) if Zs else empty
        return pose, qs, O, Z

    def all_frames(self, q: Tensor) -> tuple[list[Pose], Tensor, Tensor]:
        """Every link's world pose (by link index) and every joint's world origin and axis, (B, K, 3) each:
        one pass that serves the Jacobians of points on any links."""
        self._check_q(q)
        poses: list[Pose] = [self._root(q)]
        Os, Zs = [], []
        for k in range(len(self._parent)):
            pose, o, z = self._step(k, poses[self._parent[k]], q)
            poses.append(pose)
            Os.append(o)
            Zs.append(z)
        B = q.shape[0]
        O = torch.stack(Os, 1) if Os else q.new_zeros(B, 0, 3)
        Z = torch.stack(Zs, 1) if Zs else q.new_zeros(B, 0, 3)
        return poses, O, Z

    def forward(self, q: Tensor) -> dict[str, Pose]:
        return self.forward_kinematics(q)


@TASK_MAPS.register("forward_kinematics")
class ForwardKinematics(TaskMap):
    """y = world position of a point fixed in a robot link; x = the actuated joint angles.

    ``urdf`` is the robot's URDF (a path, or ``pkg://<package>/<path>`` inside an installed package), ``joints``
    the actuated joints in configuration order (default: every movable joint; the others are frozen at 0). A
    robot description (conf/robot/) names both, and the manipulator tree writes them into every such map. J is the
    geometric Jacobian and J̇ẋ is analytic (no J̇ is formed).
    """

    class Params(Params):
        urdf: str = Field(description="the URDF: a file path, or pkg://<package>/<path> inside an installed package")
        link: str
        offset: list[float] = Field(default_factory=lambda: [0.0, 0.0, 0.0], min_length=3, max_length=3)
        joints: list[str] | None = None
        robot: str | None = Field(None, description="retired: a robot is named by its urdf and joints")

        @model_validator(mode="after")
        def _no_robot_names(self):
            if self.robot is not None:
                raise ValueError(f"forward_kinematics.robot ({self.robot!r}) was retired: robots are described in "
                                 f"conf/robot/<name>.yaml; write that file's urdf and joints here instead "
                                 f"(urdf: <its urdf>, joints: [<its joints>])")
            return self

    def __init__(self, params: Params, in_dim: int, aux_dims: Mapping[str, int] | None = None):
        super().__init__(in_dim, aux_dims)
        path = resolve_urdf_path(params.urdf)
        joints = params.joints
        self.chain = Chain(parse_urdf(path), joints)
        source = f"URDF '{params.urdf}'"
        if self.in_dim != self.chain.dof:
            raise ValueError(
                f"forward_kinematics: the parent space has dimension {self.in_dim} but {source} has "
                f"{self.chain.dof} actuated joints ({', '.join(self.chain.actuated)}); the parent must be "
                f"the joint space"
            )
        self.link = params.link
        path_joints = self.chain.path_joints(self.link)  # raises on an unknown link
        qs = [self.chain._qidx[k] for k in path_joints if self.chain._kind[k] != FIXED]
        revolute = [self.chain._kind[k] == REVOLUTE for k in path_joints if self.chain._kind[k] != FIXED]
        S = torch.zeros(len(qs), self.in_dim, dtype=torch.float64)  # path joint -> configuration index
        if qs:
            S[torch.arange(len(qs)), torch.tensor(qs)] = 1.0
        self.register_buffer("select", S)
        self.register_buffer("path_q", torch.tensor(qs, dtype=torch.long), persistent=False)
        moving = [k for k in path_joints if self.chain._kind[k] != FIXED]
        self.register_buffer("path_index", torch.tensor(moving, dtype=torch.long), persistent=False)
        self.link_index = self.chain.check_link(self.link)
        self.shared_key = ("forward_kinematics", str(path), tuple(self.chain.actuated))
        self.register_buffer("revolute", torch.tensor(revolute, dtype=torch.bool))
        self.register_buffer("offset", torch.tensor(params.offset, dtype=torch.float64))
        self.out_dim = 3

    def link_names(self) -> list[str]:
        return self.chain.link_names()

    def joint_limits(self) -> tuple[Tensor, Tensor]:
        return self.chain.joint_limits()

    def _point(self, pose: Pose, x: Tensor) -> Tensor:
        R, p = pose
        return p + matvec(R, self.offset.to(x))

    def psi(self, x, aux=None):
        R, p = self.chain.forward_kinematics(x, [self.link])[self.link]
        return self._point((R, p), x)

    def _columns(self, y: Tensor, O: Tensor, Z: Tensor) -> Tensor:
        """(B,k,3): z × (y − o) for revolute joints, z for prismatic ones."""
        rev = self.revolute[:, None]
        return torch.where(rev, torch.linalg.cross(Z, y.unsqueeze(1) - O), Z)

    def _full(self, cols: Tensor, x: Tensor) -> Tensor:
        """(B, 3, dof): the path joints' columns in their configuration slots, zeros elsewhere."""
        return cols.new_zeros(cols.shape[0], 3, self.in_dim).index_copy(-1, self.path_q, cols.transpose(1, 2))

    def jacobian(self, x, aux=None):
        pose, _, O, Z = self.chain.path_frames(x, self.link)
        return self._full(self._columns(self._point(pose, x), O, Z), x)

    def curvature(self, x, xd, aux=None, J=None):
        return self.forward(x, xd, aux)[3]

    def forward(self, x, xd, aux=None):
        pose, _, O, Z = self.chain.path_frames(x, self.link)
        return self._outputs(pose, O, Z, x, xd)

    def prepare(self, x, xd, aux=None):
        return self.chain.all_frames(x)

    def adopt_shared(self, other: "ForwardKinematics") -> None:
        self.chain = other.chain  # one set of robot constants per tree

    def from_prepared(self, prepared, x, xd, aux=None):
        poses, O, Z = prepared
        return self._outputs(poses[self.link_index], O[:, self.path_index], Z[:, self.path_index], x, xd)

    def _outputs(self, pose: Pose, O: Tensor, Z: Tensor, x: Tensor, xd: Tensor):
        y = self._point(pose, x)
        cols = self._columns(y, O, Z)
        J = self._full(cols, x)
        yd = matvec(J, xd)
        c = self._jdot_qdot(y, yd, O, Z, xd[:, self.path_q])
        return y, yd, J, c

    def _jdot_qdot(self, y: Tensor, yd: Tensor, O: Tensor, Z: Tensor, qd: Tensor) -> Tensor:
        """J̇q̇ = Σ_i q̇_i d/dt col_i, with ż_i = ω_i⁻ × z_i (ω_i⁻: angular velocity of joint i's parent) and
        ȯ_i = ω_i⁻ × o_i − Σ_{j<i} q̇_j z_j × o_j + Σ_{j<i, prismatic} q̇_j z_j (o_i moves with the parent)."""
        if Z.shape[1] == 0:
            return torch.zeros_like(y)
        rev = self.revolute[:, None]
        zero = torch.zeros_like(Z)
        w = torch.where(rev, qd.unsqueeze(-1) * Z, zero)  # angular velocity added by each joint
        lin = torch.where(rev, zero, qd.unsqueeze(-1) * Z)  # linear velocity added by each prismatic joint
        excl = lambda t: torch.cumsum(t, 1) - t  # noqa: E731  (sum over j < i)
        w_before = excl(w)
        od = torch.linalg.cross(w_before, O) - excl(torch.linalg.cross(w, O)) + excl(lin)
        zd = torch.linalg.cross(w_before, Z)
        dcol_rev = torch.linalg.cross(zd, y.unsqueeze(1) - O) + torch.linalg.cross(Z, yd.unsqueeze(1) - od)
        dcol = torch.where(rev, dcol_rev, zd)
        return (qd.unsqueeze(-1) * dcol).sum(1)
