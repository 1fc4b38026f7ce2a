"""Affine task maps and composition. All have analytic J and J̇ẋ, and all stack (``core/stacking.py``): their
constants broadcast against the samples, so maps of one type under one parent group evaluate as one batch."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, Literal, TypeVar

import torch
from pydantic import Field, field_validator
from torch import Tensor

from ..core.algebra import matvec
from ..core.auxstate import CONSTANT_DTYPE, AuxOrValue, AuxParam, constant
from ..core.stacking import shallow_clone
from ..core.taskmap import TaskMap
from ..examples import AuxInput, Example
from ..registry import TASK_MAPS, Params, numbers_repr


def _eye(n: int, x: Tensor) -> Tensor:
    """The identity for every sample of x: (..., n, n)."""
    return torch.eye(n, dtype=x.dtype, device=x.device).expand(*x.shape[:-1], n, n)


Coordinates = TypeVar("Coordinates", bound=int | list[int])


def _coordinates(v: Coordinates, key: str) -> Coordinates:
    """Refuse negative coordinate numbers: a config means the parent's coordinate k, never Python's x[-k]."""
    bad = [i for i in ([v] if isinstance(v, int) else v) if i < 0]
    if bad:
        raise ValueError(
            f"{key} must be ≥ 0 (the parent's coordinates are numbered from 0; negative numbers do not "
            f"count from the end); given {v!r}"
        )
    return v


@TASK_MAPS.register("identity", examples=[Example({}, 2, scale=3.0)])
class Identity(TaskMap):
    """y = x: attach several RMPs to the same space, or weight a whole subtree."""

    identity_jacobian = True
    bijective = True
    stack_fields = ()

    class Params(Params):
        pass

    def __init__(self, params: Params, in_dim: int, aux_dims: Mapping[str, int] | None = None):
        super().__init__(in_dim, aux_dims)
        self.out_dim = self.in_dim

    def forward(self, x, xd, aux=None):
        return x, xd, _eye(self.in_dim, x), torch.zeros_like(x)

    def psi(self, x, aux):
        return x

    def extra_repr(self) -> str:
        return numbers_repr({"in_dim": self.in_dim, "out_dim": self.out_dim})


@TASK_MAPS.register(
    "offset",
    examples=[
        Example({"origin": [-3.0, 3.0]}, 2, scale=3.0),
        Example({"origin": "c"}, 2, scale=3.0, aux={"c": AuxInput.normal(2)}),
    ],
)
class Offset(TaskMap):
    """y = x − origin: an attractor space with the goal at 0 (origin may be aux state)."""

    identity_jacobian = True
    bijective = True
    stack_fields = ("origin",)

    class Params(Params):
        origin: AuxOrValue

    def __init__(self, params: Params, in_dim: int, aux_dims: Mapping[str, int] | None = None):
        super().__init__(in_dim, aux_dims)
        self.origin = AuxParam(params.origin, self.aux_dims, "offset.origin")
        if self.origin.dim != self.in_dim:
            raise ValueError(f"offset.origin has dimension {self.origin.dim} but the parent space has {self.in_dim}")
        self.out_dim = self.in_dim

    def psi(self, x, aux):
        return x - self.origin(aux)

    def forward(self, x, xd, aux=None):
        return self.psi(x, aux), xd, _eye(self.in_dim, x), torch.zeros_like(x)

    def extra_repr(self) -> str:
        return numbers_repr({"in_dim": self.in_dim, "out_dim": self.out_dim})


class _Affine(TaskMap):
    """y = A x + b with constant A (n, m) and b (n,): J = A, J̇ẋ = 0."""

    stack_fields = ("A", "b")
    A: Tensor  # buffers: the matrix (n, m)
    b: Tensor  # and the bias (n,)

    def _set(self, A: Tensor, b: Tensor, persistent: bool = True) -> None:
        self.out_dim = A.shape[0]
        self.register_buffer("A", A, persistent=persistent)
        self.register_buffer("b", b, persistent=persistent)

    def psi(self, x, aux):
        return matvec(self.A, x) + self.b

    def forward(self, x, xd, aux=None):
        y = self.psi(x, aux)
        J = self.A.expand(*y.shape[:-1], *self.A.shape[-2:])
        return y, matvec(self.A, xd), J, torch.zeros_like(y)

    def extra_repr(self) -> str:
        return numbers_repr({"in_dim": self.in_dim, "out_dim": self.out_dim, "matrix": self.A, "bias": self.b})


@TASK_MAPS.register(
    "linear",
    examples=[Example({"matrix": [[1.0, 2.0], [0.5, -1.0], [3.0, 0.0]], "bias": [1.0, 0.0, -1.0]}, 2, scale=3.0)],
)
class Linear(_Affine):
    """y = A x + b."""

    class Params(Params):
        matrix: list[list[float]]
        bias: list[float] | None = None

    def __init__(self, params: Params, in_dim: int, aux_dims: Mapping[str, int] | None = None):
        super().__init__(in_dim, aux_dims)
        A = constant(params.matrix)
        if A.dim() != 2 or A.shape[1] != self.in_dim:
            raise ValueError(f"linear.matrix must be (n, {self.in_dim}) for this parent, got {tuple(A.shape)}")
        b = torch.zeros(A.shape[0], dtype=CONSTANT_DTYPE) if params.bias is None else constant(params.bias)
        if b.numel() != A.shape[0]:
            raise ValueError(f"linear.bias must have {A.shape[0]} entries, got {b.numel()}")
        self._set(A, b)

    @property
    def bijective(self) -> bool:  # type: ignore[override]
        """A square matrix of full rank: y = A x + b is then a diffeomorphism of ℝⁿ onto itself."""
        n, m = self.A.shape[-2:]
        return n == m and int(torch.linalg.matrix_rank(self.A.double())) == n


@TASK_MAPS.register("select", examples=[Example({"indices": [2, 0]}, 3, scale=3.0)])
class Select(Linear):
    """y = x[indices]: a joint, or a sub-vector of the configuration."""

    class Params(Params):
        indices: list[int] = Field(min_length=1, description="coordinates of the parent, from 0")

        @field_validator("indices")
        @classmethod
        def _from_zero(cls, v: list[int]) -> list[int]:
            return _coordinates(v, "indices")

    def __init__(self, params: Params, in_dim: int, aux_dims: Mapping[str, int] | None = None):
        bad = [i for i in params.indices if not 0 <= i < in_dim]
        if bad:
            raise ValueError(f"select.indices {bad} out of range for a {in_dim}-dimensional parent")
        A = torch.zeros(len(params.indices), in_dim, dtype=CONSTANT_DTYPE)
        A[torch.arange(len(params.indices)), torch.tensor(params.indices)] = 1.0
        super().__init__(Linear.Params(matrix=A.tolist()), in_dim, aux_dims)

    def extra_repr(self) -> str:
        indices = self.A.argmax(-1).tolist()  # the one 1 of each row
        return numbers_repr({"in_dim": self.in_dim, "out_dim": self.out_dim, "indices": indices})


@TASK_MAPS.register(
    "joint_limit",
    examples=[
        Example({"side": "upper", "limit": [2.0, 1.0, 0.5]}, 3, scale=3.0),
        Example({"side": "lower", "limit": -1.0, "joints": [1]}, 3, scale=3.0),
    ],
)
class JointLimit(_Affine):
    """Distance to a joint limit: ``upper − q`` (side=upper) or ``q − lower`` (side=lower), per joint.

    ``limit`` holds one value per selected joint; ``joints`` selects them (default: all).
    """

    idx: Tensor  # buffers: the selected joints (long)
    limit: Tensor  # and their limits

    class Params(Params):
        side: Literal["upper", "lower"]
        limit: float | list[float]
        joints: int | list[int] | None = Field(None, description="coordinates of the parent, from 0; default: all")

        @field_validator("joints")
        @classmethod
        def _from_zero(cls, v: int | list[int] | None) -> int | list[int] | None:
            return v if v is None else _coordinates(v, "joints")

    def __init__(self, params: Params, in_dim: int, aux_dims: Mapping[str, int] | None = None):
        super().__init__(in_dim, aux_dims)
        joints = params.joints
        idx = list(range(in_dim)) if joints is None else ([joints] if isinstance(joints, int) else list(joints))
        bad = [i for i in idx if not 0 <= i < in_dim]
        if bad:
            raise ValueError(f"joint_limit.joints {bad} out of range for a {in_dim}-dimensional parent")
        lim = constant(params.limit).reshape(-1)
        if lim.numel() == 1:
            lim = lim.expand(len(idx)).clone()
        if lim.numel() != len(idx):
            raise ValueError(f"joint_limit.limit has {lim.numel()} values for {len(idx)} joints")
        self.sign = -1.0 if params.side == "upper" else 1.0
        self.register_buffer("idx", torch.tensor(idx))
        self.register_buffer("limit", lim)
        S = torch.zeros(len(idx), in_dim, dtype=CONSTANT_DTYPE)
        S[torch.arange(len(idx)), torch.tensor(idx)] = self.sign
        self.register_buffer("S", S)
        # y = sign·(x[idx] − limit) = S x − sign·limit: the affine map, exactly (S has one ±1 a row)
        self._set(S, -self.sign * lim, persistent=False)

    def extra_repr(self) -> str:
        side = "upper" if self.sign < 0 else "lower"
        return numbers_repr(
            {"in_dim": self.in_dim, "out_dim": self.out_dim, "side": side, "joints": self.idx, "limit": self.limit}
        )


class MapSpec(Params):
    """One stage of a composition: a registered map type and its parameters."""

    model_config = Params.model_config | {"extra": "allow"}
    type: str


@TASK_MAPS.register(
    "compose",
    examples=[
        Example(
            {
                "maps": [
                    {"type": "linear", "matrix": [[1.0, 1.0], [0.0, 2.0], [1.0, -1.0]]},
                    {"type": "sphere_distance", "center": [1.0, 0.0, 0.5], "radius": 0.2},
                ]
            },
            2,
            scale=3.0,
        ),
        Example(
            {"maps": [{"type": "offset", "origin": "c"}, {"type": "sphere_distance", "center": [0.0, 0.0]}]},
            2,
            scale=3.0,
            aux={"c": AuxInput.normal(2)},
        ),
    ],
)
class Compose(TaskMap):
    """ψ = ψ_k ∘ … ∘ ψ_1 with J = J_k⋯J_1 and J̇ẋ accumulated by the chain rule."""

    class Params(Params):
        maps: list[MapSpec] = Field(min_length=1)

    def __init__(self, params: Params, in_dim: int, aux_dims: Mapping[str, int] | None = None):
        super().__init__(in_dim, aux_dims)
        stages, dim = [], self.in_dim
        for k, spec in enumerate(params.maps):
            m = build_map(spec.model_dump(), dim, self.aux_dims, where=f"compose.maps[{k}]")
            stages.append(m)
            dim = m.out_dim
        self.stages = torch.nn.ModuleList(stages)
        self.out_dim = dim
        self.coordinates = stages[-1].coordinates  # the composition's output is its last stage's

    @property
    def bijective(self) -> bool:  # type: ignore[override]
        """Every stage a diffeomorphism of ℝⁿ onto ℝⁿ: so is their composition."""
        return all(bool(m.bijective) for m in self.stages)

    def psi(self, x, aux):
        for m in self.stages:
            x = m.psi(x, aux)
        return x

    def stack_key(self):
        """Compositions stack when their stages do, stage by stage."""
        keys = tuple(m.stack_key() for m in self.stages)
        return None if any(k is None for k in keys) else (Compose, keys)

    @classmethod
    def stacked(cls, members, like: Tensor):
        group = shallow_clone(members[0])
        stages = [type(ms[0]).stacked(ms, like) for ms in zip(*(m.stages for m in members))]
        group.__dict__["_modules"].pop("stages")
        object.__setattr__(group, "stages", stages)
        return group

    def forward(self, x, xd, aux=None):
        J = c = None
        for m in self.stages:
            x, xd, Jk, ck = m(x, xd, aux)
            if J is not None and m.identity_jacobian:
                continue  # J = I and J̇ẋ = 0: the chain so far stands
            if J is None:
                J, c = Jk, ck
            else:
                c = (Jk @ c.unsqueeze(-1)).squeeze(-1) + ck
                J = Jk @ J
        return x, xd, J, c

    def extra_repr(self) -> str:
        return numbers_repr({"in_dim": self.in_dim, "out_dim": self.out_dim})


def build_map(spec: Mapping[str, Any], in_dim: int, aux_dims: Mapping[str, int], where: str = "map") -> TaskMap:
    """Instantiate a map from ``{type: ..., **params}`` (validated by the entry's own model)."""
    spec = dict(spec)
    entry = TASK_MAPS.get(spec.pop("type"))
    return entry.obj(entry.validate(spec), in_dim, aux_dims)
