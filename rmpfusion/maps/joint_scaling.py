"""The joint space in units of each joint's velocity limit, read from the robot's URDF.

``velocity_scaled_joints`` maps q to ``y_i = q_i / v̄_i`` with ``v̄_i`` the URDF's ``<limit velocity=...>`` of
actuated joint i (or the ``velocity_limit`` given), so ``|ẏ_i| < 1`` is every joint's velocity limit at once and
one ``velocity_limit`` leaf with ``limit: 1`` serves any robot. A linear map: J = diag(1/v̄), J̇ẋ = 0.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Annotated

import torch
from pydantic import Field
from torch import Tensor

from ..core.auxstate import CONSTANT_DTYPE
from ..examples import Example
from ..registry import TASK_MAPS, numbers_repr
from .basic import Linear
from .kinematics import joint_limit_states, robot_chain
from .robot_files import IIWA, PANDA
from .robot_params import RobotParams


@TASK_MAPS.register(
    "velocity_scaled_joints",
    examples=[
        Example(PANDA, 7, joint_limit_states(PANDA)),
        Example(IIWA(velocity_limit=[1.0, 2.0, 1.5, 1.0, 3.0, 2.0, 2.5]), 7, joint_limit_states(IIWA)),
    ],
)
class VelocityScaledJoints(Linear):
    """y = q ⊘ v̄: each actuated joint divided by its velocity limit (the URDF's, unless ``velocity_limit`` is given)."""

    velocity_limit: Tensor  # buffer: v̄, per actuated joint

    class Params(RobotParams):
        velocity_limit: list[Annotated[float, Field(gt=0)]] | None = Field(
            None, description="per actuated joint, in their order (rad/s or m/s); default: the URDF's"
        )

    def __init__(self, params: Params, in_dim: int, aux_dims: Mapping[str, int] | None = None):
        chain = robot_chain(params, in_dim, "velocity_scaled_joints")
        if params.velocity_limit is not None:
            if len(params.velocity_limit) != chain.dof:
                raise ValueError(
                    f"velocity_scaled_joints.velocity_limit has {len(params.velocity_limit)} values for "
                    f"the {chain.dof} actuated joints ({', '.join(chain.actuated)}); give one per joint"
                )
            limits = list(params.velocity_limit)
        else:
            limits = chain.velocity_limit.tolist()
            missing = [n for n, v in zip(chain.actuated, limits) if not (0 < v < math.inf)]
            if missing:
                raise ValueError(
                    f"velocity_scaled_joints: {params.source()} gives no velocity limit for joints "
                    f"{', '.join(missing)} (<limit velocity=...> absent or 0); give velocity_limit: one "
                    f"value per actuated joint"
                )
        scale = torch.diag(1.0 / torch.tensor(limits, dtype=CONSTANT_DTYPE))
        super().__init__(Linear.Params(matrix=scale.tolist()), in_dim, aux_dims)
        self.register_buffer("velocity_limit", torch.tensor(limits, dtype=CONSTANT_DTYPE))

    def extra_repr(self) -> str:
        return numbers_repr({"in_dim": self.in_dim, "out_dim": self.out_dim, "velocity_limit": self.velocity_limit})
