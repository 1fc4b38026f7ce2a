"""What the rollout modes, their records and the demonstrations read of a manipulator: a protocol, so those modules
need not import ``env.py`` (which imports them) and the import graph stays without circles."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any, Literal, Protocol

import torch
from torch import Tensor

from ...robots import URDFRobot
from ...scenes import Scene
from ..rollout import Rollout
from .params import ManipulatorParams
from .worlds import HelperWorlds, TaskWorld


class ManipulatorTask(Protocol):
    """The manipulator environment as its rollouts and demonstrations see it (``env.py::Manipulator`` is one)."""

    params: ManipulatorParams
    robot: URDFRobot
    worlds: HelperWorlds
    dim: int
    dtype: torch.dtype

    @property
    def scene(self) -> Scene: ...

    @property
    def moving(self) -> bool: ...

    @property
    def dt(self) -> float: ...

    def aux_at(self, aux: Mapping[str, Tensor], t: Tensor | float) -> dict[str, Tensor]: ...

    def checker(self) -> TaskWorld: ...

    def ee_position(self, q: Tensor) -> Tensor: ...

    def sample_envs(
        self, n_envs: int, generator: torch.Generator | None = None, split: str = "train"
    ) -> dict[str, Tensor]: ...

    def sample_initial_states(
        self, envs_aux: Mapping[str, Tensor], n_per_env: int, generator: torch.Generator | None = None
    ) -> tuple[Tensor, Tensor, dict[str, Tensor]]: ...

    def rollout(
        self,
        policy: Callable[..., Any],
        q0: Tensor,
        qd0: Tensor,
        aux: Mapping[str, Tensor],
        horizon: float,
        record_every: float = 0.1,
        mode: Literal["torque", "kinematic"] | None = None,
        monitor: Callable[..., Any] | None = None,
        enable_grad: bool = False,
        progress: Callable[[int, int], Any] | None = None,
    ) -> Rollout: ...
