"""Task maps from the joint space to directions fixed in a robot link: the coordinates of orientation attractors.

A unit vector ``a`` fixed in a link points along ``u = R(q) a`` in the world (``R`` the link's rotation, from
``Chain.path_frames``). Only revolute joints turn it: with ``z_i`` the world axis of path joint ``i`` and
``ω = Σ_i q̇_i z_i`` the link's angular velocity,

    J_i = z_i × u,      u̇ = J q̇ = ω × u,      J̇q̇ = α × u + ω × (ω × u),      α = Σ_i ω_i⁻ × q̇_i z_i,

where ``ω_i⁻ = Σ_{j<i} q̇_j z_j`` is the angular velocity of joint ``i``'s parent (``ż_i = ω_i⁻ × z_i``), so
``α`` is the part of the link's angular acceleration that ``q̇`` alone produces. docs/math.md §4 has the derivation;
tests/test_registry_derivatives.py checks both maps against finite differences and autodiff.

``link_orientation`` stacks several such axes and subtracts their target directions, taken from a target rotation
(a quaternion or a matrix) or given as directions; ``link_axis`` is the one-axis case. Their output is the error
``e = (R a_k − d_k)_k``, zero at the target, so a leaf at the origin (``orientation_attractor``) pulls towards it:
for unit vectors ``½|R a − d|² = 1 − cos θ``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Literal

import torch
from pydantic import Field, field_validator
from torch import Tensor

from ..core.auxstate import AuxOrValue, AuxParam, constant
from ..core.taskmap import TaskMap
from ..examples import AuxInput, Example
from ..registry import TASK_MAPS, numbers_repr
from .kinematics import joint_limit_states, path_joints, robot_chain
from .robot_files import IIWA, PANDA
from .robot_params import RobotParams, Vector3

TargetFormat = Literal["quaternion_xyzw", "quaternion_wxyz", "matrix", "axes"]
TARGET_DIMS = {
    "quaternion_xyzw": lambda k: 4,
    "quaternion_wxyz": lambda k: 4,
    "matrix": lambda k: 9,
    "axes": lambda k: 3 * k,
}
AXES_XYZ = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]


def check_direction(v: Sequence[float], what: str) -> None:
    if not any(float(a) != 0.0 for a in v):
        raise ValueError(f"{what} must be a non-zero vector (it is a direction in the link frame); given {list(v)}")


def quaternion_matrix(quat: Tensor, scalar_last: bool = True) -> Tensor:
    """(B, 4) quaternions, normalised here, to (B, 3, 3) rotation matrices; (x, y, z, w) when ``scalar_last``."""
    quat = quat / quat.norm(dim=-1, keepdim=True)
    x, y, z, w = quat.unbind(-1) if scalar_last else (quat[..., 1], quat[..., 2], quat[..., 3], quat[..., 0])
    rows = [
        1 - 2 * (y * y + z * z),
        2 * (x * y - z * w),
        2 * (x * z + y * w),
        2 * (x * y + z * w),
        1 - 2 * (x * x + z * z),
        2 * (y * z - x * w),
        2 * (x * z - y * w),
        2 * (y * z + x * w),
        1 - 2 * (x * x + y * y),
    ]
    return torch.stack(rows, -1).reshape(*quat.shape[:-1], 3, 3)


def rotating_vectors(U: Tensor, Z: Tensor, revolute: Tensor, qd: Tensor) -> tuple[Tensor, Tensor]:
    """Jacobian columns (B, k, m, 3) and J̇q̇ (B, k, 3) of k vectors U (B, k, 3) fixed in a link whose path has m
    actuated joints with world axes Z (B, m, 3) and velocities qd (B, m); prismatic joints do not turn them."""
    rev = revolute[:, None]
    w = torch.where(rev, qd.unsqueeze(-1) * Z, torch.zeros_like(Z))  # angular velocity each joint adds
    omega = w.sum(1)  # (B, 3)
    alpha = torch.linalg.cross(torch.cumsum(w, 1) - w, w).sum(1)  # Σ_i ω_i⁻ × w_i
    cols = torch.linalg.cross(Z.unsqueeze(1), U.unsqueeze(2))  # z_i × u_k
    cols = torch.where(rev[None, :, :], cols, torch.zeros_like(cols))
    omega_k = omega.unsqueeze(1).expand_as(U)
    c = torch.linalg.cross(alpha.unsqueeze(1).expand_as(U), U) + torch.linalg.cross(
        omega_k, torch.linalg.cross(omega_k, U)
    )
    return cols, c


class _Orientation(RobotParams):
    link: str
    target: AuxOrValue | None = Field(
        None,
        description="the target rotation or directions (see target_format), an "
        "aux name or constant; none: the map gives the axes themselves",
    )


@TASK_MAPS.register(
    "link_orientation",
    examples=[
        Example(PANDA(link="panda_hand", target=[0.0, 1.0, 0.0, 0.0]), 7, joint_limit_states(PANDA)),
        Example(
            PANDA(
                link="panda_hand",
                target="quaternion",
                target_format="quaternion_wxyz",
                axes=[[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]],
            ),
            7,
            joint_limit_states(PANDA),
            aux={"quaternion": AuxInput.normal(4)},
        ),
        Example(
            IIWA(
                link="lbr_iiwa_link_6",
                target="directions",
                target_format="axes",
                axes=[[0.0, 1.0, 0.0], [1.0, 1.0, 0.0]],
            ),
            7,
            joint_limit_states(IIWA),
            aux={"directions": AuxInput.normal(6)},
        ),
        Example(
            IIWA(link="lbr_iiwa_link_7", target=[0.0, -1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0], target_format="matrix"),
            7,
            joint_limit_states(IIWA),
        ),
    ],
)
class LinkOrientation(TaskMap):
    """y = (R(q) a_k − R* a_k)_k for the link axes ``axes`` (default x, y, z: dimension 9) and a target rotation R*.

    ``target_format``: ``quaternion_xyzw`` (pybullet's and scipy's order) or ``quaternion_wxyz`` (4 numbers,
    normalised here), ``matrix`` (R*, 9 numbers row by row), or ``axes`` (the k target directions themselves,
    3k numbers, each normalised here). Two axes that are not parallel pin the orientation. Without ``target`` the
    output is the world axes (R a_k)_k. J and J̇ẋ are analytic (module docstring).
    """

    what = "link_orientation"
    path_q: Tensor  # buffers: the configuration index of each actuated joint on the link's path,
    revolute: Tensor  # whether it turns (bool),
    axes: Tensor  # and the link's unit axes (k, 3)

    class Params(_Orientation):
        axes: list[Vector3] = Field(
            default_factory=lambda: [list(a) for a in AXES_XYZ],
            min_length=1,
            max_length=3,
            description="directions fixed in the link (normalised here), no two parallel",
        )
        target_format: TargetFormat = "quaternion_xyzw"

        @field_validator("axes")
        @classmethod
        def _distinct_directions(cls, v: list[list[float]]) -> list[list[float]]:
            for i, a in enumerate(v):
                check_direction(a, f"axes[{i}]")
            unit = [constant(a) / constant(a).norm() for a in v]
            for i in range(len(v)):
                for j in range(i):
                    if float(torch.linalg.cross(unit[i], unit[j]).norm()) < 1e-9:
                        raise ValueError(
                            f"axes[{j}] and axes[{i}] are parallel: they pin the same direction twice; "
                            f"give directions that are not parallel; given {v}"
                        )
            return v

    def __init__(self, params: Params, in_dim: int, aux_dims: Mapping[str, int] | None = None):
        super().__init__(in_dim, aux_dims)
        self.chain = robot_chain(params, in_dim, self.what)
        self.link = params.link
        self.chain.check_link(self.link)  # raises on an unknown link, with the links it has
        q_index, revolute = path_joints(self.chain, self.link)
        self.register_buffer("path_q", torch.tensor(q_index, dtype=torch.long), persistent=False)
        self.register_buffer("revolute", torch.tensor(revolute, dtype=torch.bool), persistent=False)
        axes = constant(params.axes)
        self.register_buffer("axes", axes / axes.norm(dim=-1, keepdim=True))  # (k, 3)
        self.target_format = params.target_format
        self.target = None if params.target is None else self._target_param(params.target)
        self.out_dim = 3 * axes.shape[0]

    def _target_param(self, value: AuxOrValue) -> AuxParam:
        k, fmt = self.axes.shape[0], self.target_format
        target = AuxParam(value, self.aux_dims, f"{self.what}.target")
        want = TARGET_DIMS[fmt](k)
        if target.dim != want:
            raise ValueError(
                f"{self.what}.target has dimension {target.dim} but target_format '{fmt}' with {k} "
                f"ax{'is' if k == 1 else 'es'} needs {want}; declare the aux entry with {want} numbers or "
                f"change target_format"
            )
        if target.const is not None:  # a constant (None: an aux entry)
            _check_constant_target(target.const, fmt, k, self.what)
        return target

    def target_directions(self, aux, batch: int, like: Tensor) -> Tensor:
        """The k target directions (B, k, 3): R* a_k for a rotation, the given directions normalised for ``axes``."""
        assert self.target is not None, "only a map given a target has target directions"
        t = self.target(aux).to(like)
        t = t.expand(batch, -1) if t.dim() == 1 else t
        if self.target_format == "axes":
            d = t.reshape(batch, -1, 3)
            return d / d.norm(dim=-1, keepdim=True)
        if self.target_format == "matrix":
            R_target = t.reshape(batch, 3, 3)
        else:
            R_target = quaternion_matrix(t, scalar_last=self.target_format == "quaternion_xyzw")
        return torch.einsum("bij,kj->bki", R_target, self.axes.to(like))

    def _world_axes(self, x: Tensor) -> tuple[Tensor, Tensor]:
        """(U (B, k, 3) the link's axes in the world, Z (B, m, 3) the world axes of its path's actuated joints)."""
        (R, _), _, _, Z = self.chain.path_frames(x, self.link)
        return torch.einsum("bij,kj->bki", R, self.axes.to(x)), Z

    def _output(self, U: Tensor, x: Tensor, aux) -> Tensor:
        y = U if self.target is None else U - self.target_directions(aux, x.shape[0], x)
        return y.reshape(x.shape[0], self.out_dim)

    def psi(self, x, aux):
        return self._output(self._world_axes(x)[0], x, aux)

    def forward(self, x, xd, aux=None):
        U, Z = self._world_axes(x)
        cols, c = rotating_vectors(U, Z, self.revolute, xd[:, self.path_q])
        B, k, m = cols.shape[:3]
        J = cols.new_zeros(B, self.out_dim, self.in_dim)
        J = J.index_copy(-1, self.path_q, cols.permute(0, 1, 3, 2).reshape(B, 3 * k, m))
        yd = (J @ xd.unsqueeze(-1)).squeeze(-1)
        return self._output(U, x, aux), yd, J, c.reshape(B, self.out_dim)

    def jacobian(self, x, aux=None):
        return self.forward(x, torch.zeros_like(x), aux)[2]

    def curvature(self, x, xd, aux=None, J=None):
        return self.forward(x, xd, aux)[3]

    def extra_repr(self) -> str:
        return numbers_repr(
            {
                "in_dim": self.in_dim,
                "out_dim": self.out_dim,
                "link": self.link,
                "axes": self.axes,
                "target_format": self.target_format,
            }
        )


def _check_constant_target(t: Tensor, fmt: str, k: int, what: str) -> None:
    """A constant target must describe a rotation or directions: refuse what it cannot mean, naming it."""
    if fmt.startswith("quaternion") and float(t.norm()) == 0.0:
        raise ValueError(f"{what}.target: a quaternion of norm 0 is no rotation; given {t.tolist()}")
    if fmt == "axes":
        for i, d in enumerate(t.reshape(k, 3)):
            check_direction(d.tolist(), f"{what}.target direction {i}")
    if fmt == "matrix":
        R = t.reshape(3, 3)
        err = float((R @ R.T - torch.eye(3, dtype=R.dtype)).abs().max())
        if err > 1e-6 or float(torch.linalg.det(R)) < 0:
            raise ValueError(
                f"{what}.target: {t.tolist()} is not a rotation matrix (rows orthonormal, determinant "
                f"+1; |R Rᵀ − I| = {err:.2g}); give the 9 entries of a rotation, row by row"
            )


@TASK_MAPS.register(
    "link_axis",
    examples=[
        Example(PANDA(link="panda_hand", axis=[0.0, 0.0, 1.0]), 7, joint_limit_states(PANDA)),
        Example(
            PANDA(link="panda_link5", axis=[1.0, -2.0, 0.5], target=[0.0, 0.0, -1.0]),
            7,
            joint_limit_states(PANDA),
        ),
        Example(
            IIWA(link="lbr_iiwa_link_7", target="c3"),
            7,
            joint_limit_states(IIWA),
            aux={"c3": AuxInput.normal(3)},
        ),
    ],
)
class LinkAxis(LinkOrientation):
    """y = R(q) a − d: a direction ``axis`` fixed in ``link`` (e.g. a tool axis), minus its target direction ``target``
    (3 numbers or an aux name, normalised here; none: y = R a). ``link_orientation`` with one axis."""

    what = "link_axis"

    class Params(_Orientation):
        axis: Vector3 = Field(default_factory=lambda: [0.0, 0.0, 1.0], description="direction in the link frame")
        target: AuxOrValue | None = Field(
            None,
            description="the target direction (3 numbers, normalised here) or an "
            "aux name; none: the map gives the axis itself",
        )

        @field_validator("axis")
        @classmethod
        def _direction(cls, v: list[float]) -> list[float]:
            check_direction(v, "axis")
            return v

    def __init__(self, params: Params, in_dim: int, aux_dims: Mapping[str, int] | None = None):
        fields = params.model_dump(include=set(_Orientation.model_fields), exclude_unset=True)
        orientation = LinkOrientation.Params(**fields, axes=[params.axis], target_format="axes")
        super().__init__(orientation, in_dim, aux_dims)
