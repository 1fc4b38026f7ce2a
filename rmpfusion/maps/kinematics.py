"""Batched forward kinematics of URDF chains in torch, and a task map to a point on a robot link.

Everything is plain torch so FK composes with autograd and torch.func; the task map nevertheless supplies
the geometric Jacobian and J̇ẋ analytically because they are cheap and exact, while autodiff of a deep
chain of 3×3 products costs one pass per joint.
"""

from __future__ import annotations

import difflib
import math
from collections.abc import Mapping, Sequence
from typing import Any

import torch
from pydantic import Field
from torch import Tensor, nn

from ..core.algebra import matmul_small, matvec
from ..core.taskmap import TaskMap
from ..examples import Example, StateSampler
from ..registry import TASK_MAPS, Params, numbers_repr
from .robot_files import PANDA
from .robot_params import RobotParams
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

    A joint that mimics another (URDF ``<mimic>``) follows its leader, q = multiplier · q_leader + offset, so every
    Jacobian column of an actuated joint sums the columns of the joints it drives. Other movable joints that are not
    actuated (e.g. the Panda fingers for the 7-DOF arm) are frozen at 0. The root link sits at ``mount`` (a 4×4
    pose; default the world origin). Constants are float64 buffers cast to the input's dtype on use, so
    float64 inputs get full precision whatever the default dtype was at construction.

    One pass (``frames``) computes every link's pose as a homogeneous transform, every joint's world origin and
    axis: the local transforms of all joints at once (rotations by Rodrigues' formula folded into the origin),
    then one product per joint down the tree. Every kinematic point of a robot reads that one pass.
    """

    # buffers (float64 unless said), registered in __init__: the joints' origins and rotation terms (K joints) ...
    origin_R: Tensor
    origin_p: Tensor
    origin_axis: Tensor
    rot_sin: Tensor
    rot_cos: Tensor
    # ... the actuated joints' limits, in their order ...
    lower: Tensor
    upper: Tensor
    velocity_limit: Tensor
    # ... and what one pass (``frames``) reads
    mount: Tensor
    gain: Tensor
    bias: Tensor
    mix: Tensor | None  # None unless some joint follows another (mimic)
    axis_local: Tensor
    T0: Tensor
    T_sin: Tensor
    T_cos: Tensor
    T_slide: Tensor
    q_of_joint: Tensor  # long
    turns: Tensor
    slides: Tensor
    actuated_joints: Tensor  # long
    actuated_turns: Tensor  # bool
    actuated_q: Tensor  # long
    columns: Tensor | None  # long; None when the URDF's order is the configuration's

    def __init__(self, model: URDFModel, actuated: Sequence[str] | None = None, mount: Tensor | None = None):
        super().__init__()
        self.model = model
        movable = model.movable_joint_names()
        if actuated is None:  # every joint that moves of its own accord: mimic joints follow their leaders
            actuated = [j.name for j in model.joints if j.movable and j.mimic is None]
        actuated = list(actuated)
        for name in actuated:
            if name not in movable:
                what = "is fixed" if name in [j.name for j in model.joints] else "does not exist"
                raise ValueError(
                    f"actuated joint '{name}' {what} in URDF '{model.name}'; "
                    f"{_suggest(name, movable)}movable joints: {', '.join(movable)}"
                )
        if len(set(actuated)) != len(actuated):
            raise ValueError(f"actuated joints contain duplicates: {actuated}")
        for name in actuated:
            mimic = model.joint(name).mimic
            if mimic is not None:
                raise ValueError(
                    f"joint '{name}' of URDF '{model.name}' mimics '{mimic.leader}' (it follows that "
                    f"joint): list '{mimic.leader}' among the actuated joints instead of '{name}'"
                )
        self.actuated: tuple[str, ...] = tuple(actuated)
        self.dof = len(actuated)
        self._links: tuple[str, ...] = tuple(model.link_names())  # root, then joint k's child at k + 1
        self._link_index = {n: i for i, n in enumerate(self._links)}
        self._parent = [self._link_index[j.parent] for j in model.joints]
        self._qidx, self._kind, self._gain, self._bias = [], [], [], []
        for j in model.joints:
            leader, gain, bias = _driver(model, j, actuated)
            self._qidx.append(actuated.index(leader) if leader is not None else -1)
            kind = FIXED if leader is None else (PRISMATIC if j.type == "prismatic" else REVOLUTE)
            self._kind.append(kind)
            self._gain.append(gain if leader is not None else 0.0)
            self._bias.append(bias)  # a frozen joint's constant value (a mimic's offset), folded into its origin
        #: movable joints that follow an actuated joint (URDF <mimic>): q_j = gain · q_leader + bias
        self.followers: tuple[str, ...] = tuple(
            j.name for j, k in zip(model.joints, self._kind) if k != FIXED and j.name not in actuated
        )
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
        self._frame_constants(axis)
        self._fold_constant_values()
        M = torch.eye(4, dtype=torch.float64) if mount is None else torch.as_tensor(mount, dtype=torch.float64)
        if tuple(M.shape) != (4, 4):
            raise ValueError(f"mount must be a 4×4 homogeneous transform, got shape {tuple(M.shape)}")
        self.register_buffer("mount", M, persistent=False)  # the root link's pose in the world

    def _fold_constant_values(self) -> None:
        """Frozen joints whose value is not 0 (a mimic offset of a frozen leader) turned into their origins, and the
        gains and biases of the driven joints, read only when some joint follows another."""
        for k, (kind, c) in enumerate(zip(self._kind, self._bias)):
            if kind == FIXED and c != 0.0:
                if self.model.joints[k].type == "prismatic":
                    self.T0[k, :3, 3] += c * self.origin_axis[k]
                else:
                    self.T0[k] += math.sin(c) * self.T_sin[k] + (1 - math.cos(c)) * self.T_cos[k]
        self.has_mimic = bool(self.followers)
        self.register_buffer("gain", torch.tensor(self._gain, dtype=torch.float64), persistent=False)
        self.register_buffer(
            "bias",
            torch.tensor([b if k != FIXED else 0.0 for k, b in zip(self._kind, self._bias)], dtype=torch.float64),
            persistent=False,
        )
        act = self.actuated_joints.tolist()
        mix = torch.zeros(len(act), self.dof, dtype=torch.float64)  # moving joint (URDF order) <- configuration
        for a, k in enumerate(act):
            mix[a, self._qidx[k]] = self._gain[k]
        self.register_buffer("mix", mix if self.has_mimic else None, persistent=False)

    def _frame_constants(self, axis: Tensor) -> None:
        """What ``frames`` reads besides the origins: each joint's axis in its own frame, which configuration
        coordinate moves it (and whether it turns or slides), and the actuated joints in URDF order."""
        K = len(self._kind)
        act = [k for k in range(K) if self._kind[k] != FIXED]
        self.register_buffer("axis_local", axis, persistent=False)
        # the local transforms as 4×4 blocks: T(q) = T0 + sin q·S + (1 − cos q)·C + slide·P (only the rotation block
        # of S and C, only the translation column of P are non-zero), one product and sum for every joint at once
        K = len(self._kind)
        T0 = torch.eye(4, dtype=torch.float64).repeat(K, 1, 1)
        T0[:, :3, :3], T0[:, :3, 3] = self.origin_R, self.origin_p
        S, C, P = (torch.zeros(K, 4, 4, dtype=torch.float64) for _ in range(3))
        S[:, :3, :3], C[:, :3, :3], P[:, :3, 3] = self.rot_sin, self.rot_cos, self.origin_axis
        for name, t in (("T0", T0), ("T_sin", S), ("T_cos", C), ("T_slide", P)):
            self.register_buffer(name, t, persistent=False)
        self.register_buffer(
            "q_of_joint", torch.tensor([max(i, 0) for i in self._qidx], dtype=torch.long), persistent=False
        )
        kinds = torch.tensor(self._kind, dtype=torch.long)
        self.register_buffer("turns", (kinds == REVOLUTE).to(torch.float64), persistent=False)
        self.register_buffer("slides", (kinds == PRISMATIC).to(torch.float64), persistent=False)
        self.register_buffer("actuated_joints", torch.tensor(act, dtype=torch.long), persistent=False)
        self.register_buffer("actuated_turns", torch.tensor([self._kind[k] == REVOLUTE for k in act]), persistent=False)
        self.has_slides = PRISMATIC in self._kind  # an arm of turning joints skips the sliding terms
        q_of_act = [self._qidx[k] for k in act]
        self.register_buffer("actuated_q", torch.tensor(q_of_act, dtype=torch.long), persistent=False)
        # the actuated joints' columns in configuration order (None: URDF order is the configuration's)
        order = sorted(range(len(act)), key=lambda i: q_of_act[i])
        self.register_buffer(
            "columns", None if order == list(range(len(act))) else torch.tensor(order), persistent=False
        )

    # -- queries -----------------------------------------------------------------------------------
    def link_names(self) -> list[str]:
        return list(self._links)

    def joint_limits(self) -> tuple[Tensor, Tensor]:
        """(lower, upper) of the actuated joints, in their order; ±inf for continuous joints."""
        return self.lower.clone(), self.upper.clone()

    def check_link(self, link: str) -> int:
        if link not in self._link_index:
            raise ValueError(
                f"URDF '{self.model.name}' has no link '{link}'; {_suggest(link, self._links)}"
                f"links: {', '.join(self._links)}"
            )
        return self._link_index[link]

    def path_joints(self, link: str) -> list[int]:
        """Indices (into the URDF joint list) of the joints from the root to ``link``."""
        i, path = self.check_link(link), []
        while i > 0:
            path.append(i - 1)
            i = self._parent[i - 1]
        return path[::-1]

    def moves(self, link: str) -> Tensor:
        """(A,) 1.0 for each actuated joint (in URDF order) on the path to ``link``, else 0.0."""
        on_path = set(self.path_joints(link))
        return torch.tensor([float(k in on_path) for k in self.actuated_joints.tolist()], dtype=torch.float64)

    # -- kinematics --------------------------------------------------------------------------------
    def _check_q(self, q: Tensor) -> None:
        if q.dim() < 2 or q.shape[-1] != self.dof:
            raise ValueError(
                f"q must be (B, {self.dof}) for actuated joints {list(self.actuated)}, got {tuple(q.shape)}"
            )

    _CONSTANTS = ("T0", "T_sin", "T_cos", "T_slide", "turns", "slides", "axis_local")

    def _constants(self, like: Tensor) -> dict[str, Tensor]:
        """The pass's constants in ``like``'s dtype and device (cast only when they differ: a tree's chain is
        already in the tree's dtype)."""
        return {n: _as(getattr(self, n), like) for n in self._CONSTANTS}

    def _local(self, q: Tensor) -> tuple[Tensor, Tensor]:
        """Every joint's transform from its parent link at ``q``: (..., K, 4, 4), and each joint's slide (..., K)."""
        c = self._constants(q)
        qj = q.index_select(-1, self.q_of_joint) if len(self._kind) else q[..., :0]
        if self.has_mimic:
            qj = qj * _as(self.gain, q) + _as(self.bias, q)
        turn, slide = qj * c["turns"], qj * c["slides"]  # 0 for fixed and frozen joints: their origins exactly
        sin, cos = torch.sin(turn)[..., None, None], (1 - torch.cos(turn))[..., None, None]
        T = c["T0"] + sin * c["T_sin"] + cos * c["T_cos"]
        if self.has_slides:
            T = T + slide[..., None, None] * c["T_slide"]
        return T, slide

    def frames(self, q: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """One pass: every link's world pose (..., L, 4, 4) (link order of ``link_names``), and every joint's
        world origin O and axis Z (..., K, 3) (O: where the joint sits before its own motion)."""
        self._check_q(q)
        local, slide = self._local(q)
        world = [_as(self.mount, q).expand(*q.shape[:-1], 4, 4)]
        for parent, joint in zip(self._parent, local.unbind(-3)):
            world.append(matmul_small(world[parent], joint))
        T = torch.stack(world, -3)
        children = T[..., 1:, :, :]
        Z = (children[..., :3, :3] * self._constants(q)["axis_local"][..., None, :]).sum(-1)
        O = children[..., :3, 3] - Z * slide[..., None] if self.has_slides else children[..., :3, 3]
        return T, O, Z

    def forward_kinematics(self, q: Tensor, links: Sequence[str] | None = None) -> dict[str, Pose]:
        """World poses {link: (R (B,3,3), p (B,3))} of ``links`` (default all)."""
        wanted = list(self._links) if links is None else list(links)
        index = [self.check_link(n) for n in wanted]
        T = self.frames(q)[0]
        return {n: (T[..., i, :3, :3], T[..., i, :3, 3]) for n, i in zip(wanted, index)}

    def path_frames(self, q: Tensor, link: str) -> tuple[Pose, list[int], Tensor, Tensor]:
        """Pose of ``link`` and, for the actuated joints on its path, (q indices, world origins O (B,k,3),
        world axes Z (B,k,3))."""
        T, O, Z = self.frames(q)
        i = self.check_link(link)
        moving = [k for k in self.path_joints(link) if self._kind[k] != FIXED]
        return (
            (T[..., i, :3, :3], T[..., i, :3, 3]),
            [self._qidx[k] for k in moving],
            O[..., moving, :],
            Z[..., moving, :],
        )

    def forward(self, q: Tensor) -> dict[str, Pose]:
        return self.forward_kinematics(q)

    def extra_repr(self) -> str:
        return numbers_repr({"robot": self.model.name, "dof": self.dof, "links": len(self._links)})


def path_joints(chain: Chain, link: str) -> tuple[list[int], list[bool]]:
    """The actuated joints from the root to ``link``, root first: (their coordinates in q, whether each is revolute).

    The same joints, in the same order, as the world axes ``Chain.path_frames`` returns for ``link``.
    """
    q_index, revolute = [], []
    for joint in chain.model.path_to(link):
        if joint.name in chain.followers:
            raise ValueError(
                f"link '{link}' is moved by joint '{joint.name}', which follows another (URDF <mimic>); "
                f"orientation maps do not follow mimic joints: choose a link above it"
            )
        if joint.name in chain.actuated:
            q_index.append(chain.actuated.index(joint.name))
            revolute.append(joint.type != "prismatic")
    return q_index, revolute


def rigid_body_of(chain: Chain) -> dict[str, int]:
    """Link -> the rigid body it belongs to (numbered from the root's, 0): links joined by fixed joints or by
    movable joints that no actuated joint drives (frozen by the chain) move as one body."""
    body = {chain.model.root: 0}
    count = 1
    for joint in chain.model.joints:  # parents before children
        if joint.name in chain.actuated or joint.name in chain.followers:
            body[joint.child] = count
            count += 1
        else:
            body[joint.child] = body[joint.parent]
    return body


def _driver(model: URDFModel, joint, actuated: Sequence[str]) -> tuple[str | None, float, float]:
    """(the actuated joint that moves ``joint`` or None, gain, bias): ``joint``'s value is gain · q_leader + bias,
    following mimic links to the joint at their head; a joint no actuated joint drives is frozen at ``bias`` (0 but
    for a mimic's offset)."""
    gain, bias, j = 1.0, 0.0, joint
    while j.movable and j.name not in actuated and j.mimic is not None:
        bias, gain = bias + gain * j.mimic.offset, gain * j.mimic.multiplier
        j = model.joint(j.mimic.leader)
    return (j.name if j.movable and j.name in actuated else None), gain, bias


def mount_matrix(xyz: Sequence[float], rpy: Sequence[float]) -> Tensor:
    """The 4×4 pose of a robot's base in the world from a URDF-style origin (xyz, fixed-axis roll-pitch-yaw)."""
    M = torch.eye(4, dtype=torch.float64)
    M[:3, :3], M[:3, 3] = rpy_matrix(rpy), torch.tensor([float(v) for v in xyz], dtype=torch.float64)
    return M


def robot_chain(p: RobotParams, in_dim: int, what: str) -> Chain:
    """The kinematic chain ``p`` names, checked to be the parent space (one coordinate per actuated joint)."""
    mount = None if p.mount is None else mount_matrix(p.mount.xyz, p.mount.rpy)
    chain = Chain(parse_urdf(resolve_urdf_path(p.urdf)), p.joints, mount)
    if in_dim != chain.dof:
        raise ValueError(
            f"{what}: the parent space has dimension {in_dim} but {p.source()} has {chain.dof} actuated "
            f"joints ({', '.join(chain.actuated)}); the parent must be the joint space"
        )
    return chain


def joint_limit_states(robot: Mapping[str, Any]) -> StateSampler:
    """Examples' states of a robot (``{"urdf": ..., "joints": ...}``, a ``robot_files.RobotFile``): q uniform inside its
    joint limits, q̇ ~ N(0, I). The robot is read when states are drawn, never when the example is declared (at
    import)."""

    def states(gen: torch.Generator, n: int, dim: int) -> tuple[Tensor, Tensor]:
        lo, hi = Chain(parse_urdf(robot["urdf"]), robot.get("joints")).joint_limits()
        return lo + torch.rand(n, dim, generator=gen) * (hi - lo), torch.randn(n, dim, generator=gen)

    return states


@TASK_MAPS.register(
    "forward_kinematics",
    examples=[
        Example(PANDA(link="panda_hand", offset=[0.05, -0.01, 0.02]), 7, joint_limit_states(PANDA)),
        Example(PANDA(link="panda_link4"), 7, joint_limit_states(PANDA)),
    ],
)
class ForwardKinematics(TaskMap):
    """y = world position of a point fixed in a robot link; x = the actuated joint angles.

    ``urdf`` is the robot's URDF (a path, or ``pkg://<package>/<path>`` inside an installed package), ``joints``
    the actuated joints in configuration order (default: every movable joint that mimics none; mimic joints follow their leaders, the others are frozen
    at 0). A
    robot description (conf/robot/) names both, and the manipulator tree writes them into every such map. J is the
    geometric Jacobian and J̇ẋ is analytic (no J̇ is formed).

    Points on one robot stack (``core/stacking.py``): a group of them reads one pass of the chain (``Chain.frames``)
    and evaluates every point's position, Jacobian and J̇ẋ at once, each with its own link, offset and the mask of
    the joints that move it.
    """

    stack_fields = ("link_mask", "offset", "moved_by")
    select: Tensor  # buffers: path joint -> configuration index (one-hot rows),
    revolute: Tensor  # whether each path joint turns (bool),
    offset: Tensor  # the point in the link frame (3,),
    link_mask: Tensor  # the link among every link (one-hot),
    moved_by: Tensor  # and the actuated joints (URDF order) that move it (1.0 or 0.0)

    class Params(RobotParams):
        link: str
        offset: list[float] = Field(default_factory=lambda: [0.0, 0.0, 0.0], min_length=3, max_length=3)

    def __init__(self, params: Params, in_dim: int, aux_dims: Mapping[str, int] | None = None):
        super().__init__(in_dim, aux_dims)
        self.chain = robot_chain(params, in_dim, "forward_kinematics")
        self.link = params.link
        path_joints = self.chain.path_joints(self.link)  # raises on an unknown link
        qs = [self.chain._qidx[k] for k in path_joints if self.chain._kind[k] != FIXED]
        revolute = [self.chain._kind[k] == REVOLUTE for k in path_joints if self.chain._kind[k] != FIXED]
        S = torch.zeros(len(qs), self.in_dim, dtype=torch.float64)  # path joint -> configuration index
        if qs:
            S[torch.arange(len(qs)), torch.tensor(qs)] = 1.0
        self.register_buffer("select", S)
        self.register_buffer("revolute", torch.tensor(revolute, dtype=torch.bool))
        self.register_buffer("offset", torch.tensor(params.offset, dtype=torch.float64))
        one_hot = torch.zeros(len(self.chain.link_names()), dtype=torch.float64)
        one_hot[self.chain.check_link(self.link)] = 1.0
        self.register_buffer("link_mask", one_hot, persistent=False)  # picks the link's pose out of every link's
        self.register_buffer("moved_by", self.chain.moves(self.link), persistent=False)
        mount = None if params.mount is None else (tuple(params.mount.xyz), tuple(params.mount.rpy))
        self.source = (resolve_urdf_path(params.urdf), tuple(self.chain.actuated), mount)
        self.out_dim = 3

    def stack_settings(self) -> tuple:
        return self.source  # points on one robot model

    def link_names(self) -> list[str]:
        return self.chain.link_names()

    def extra_repr(self) -> str:
        return numbers_repr({"in_dim": self.in_dim, "out_dim": self.out_dim, "link": self.link, "offset": self.offset})

    def joint_limits(self) -> tuple[Tensor, Tensor]:
        return self.chain.joint_limits()

    def psi(self, x, aux=None):
        return self.forward(x, x, aux)[0]

    def jacobian(self, x, aux=None):
        return self.forward(x, x, aux)[2]

    def curvature(self, x, xd, aux=None, J=None):
        return self.forward(x, xd, aux)[3]

    def forward(self, x, xd, aux=None):
        """(y, ẏ, J, J̇ẋ) of the point(s): the geometric Jacobian's columns z × (y − o) (turning joints) and z
        (sliding joints), masked to the joints that move the point, placed in their configuration slots."""
        chain = self.chain
        T, O, Z = chain.frames(x)
        O, Z = O[..., chain.actuated_joints, :], Z[..., chain.actuated_joints, :]  # (..., A, 3), URDF order
        pose = _take(T, _as(self.link_mask, x))
        y = pose[..., :3, 3] + matvec(pose[..., :3, :3], _as(self.offset, x))
        moved = _as(self.moved_by, x)[..., None]
        turning = torch.linalg.cross(Z, y[..., None, :] - O)
        cols = moved * (torch.where(chain.actuated_turns[:, None], turning, Z) if chain.has_slides else turning)
        J = cols.transpose(-1, -2)
        qd = xd
        if chain.mix is not None:  # joints that follow others (mimic): each configuration column sums its joints'
            mix = _as(chain.mix, x)
            J, qd = J @ mix, matvec(mix, xd)  # qd: every moving joint's rate, in URDF order
        elif chain.columns is not None:  # actuated joints listed in another order than the URDF's
            J = J.index_select(-1, chain.columns)
            qd = xd.index_select(-1, chain.actuated_q)  # (..., A) in URDF order
        yd = matvec(J, xd)
        return y, yd, J, _jdot_qdot(y, yd, O, Z, moved * qd[..., None], chain.actuated_turns[:, None], chain.has_slides)


def _as(t: Tensor, like: Tensor) -> Tensor:
    return t if t.dtype == like.dtype and t.device == like.device else t.to(like)


def _take(T: Tensor, one_hot: Tensor) -> Tensor:
    """Link poses (..., 4, 4) picked from every link's (..., L, 4, 4) by a one-hot (L,) over the links ((G, 1, L) for
    a group): a product and a sum, exact, and free of the batch size (so it exports for any batch)."""
    return (one_hot[..., None, None] * T).sum(-3)


def _jdot_qdot(y: Tensor, yd: Tensor, O: Tensor, Z: Tensor, rate: Tensor, turns: Tensor, slides: bool) -> Tensor:
    """J̇q̇ = Σ_i q̇_i d/dt col_i over the joints that move the point (``rate``: q̇_i for them, 0 for the others, (..., A, 1)),
    with ż_i = ω_i⁻ × z_i (ω_i⁻: angular velocity of joint i's parent) and ȯ_i = ω_i⁻ × o_i − Σ_{j<i} q̇_j z_j × o_j +
    Σ_{j<i, sliding} q̇_j z_j (o_i moves with the parent). Joints off the point's path have rate 0, so sums over j < i
    run over its ancestors. ``slides``: the chain has sliding joints (else their terms are left out, being 0)."""
    if Z.shape[-2] == 0:
        return torch.zeros_like(y)
    excl = lambda t: torch.cumsum(t, -2) - t
    moving = rate * Z
    w = torch.where(turns, moving, 0.0) if slides else moving  # angular velocity added by each joint
    w_before = excl(w)
    od = torch.linalg.cross(w_before, O) - excl(torch.linalg.cross(w, O))
    if slides:
        od = od + excl(torch.where(turns, 0.0, moving))  # linear velocity added by each sliding joint
    zd = torch.linalg.cross(w_before, Z)
    dcol = torch.linalg.cross(zd, y[..., None, :] - O) + torch.linalg.cross(Z, yd[..., None, :] - od)
    if slides:
        dcol = torch.where(turns, dcol, zd)
    return (rate * dcol).sum(-2)
