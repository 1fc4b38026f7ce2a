"""The ``sim:`` block of an environment's config: ``{type: <simulator>, ...}``, validated by the named backend's
own parameter model (``rmpfusion.registry.SIMULATORS``), looked up when the config is validated so a plugin's
simulator is found like a built-in one; and opening a world from it."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Annotated, Any

from pydantic import BeforeValidator, Field, SerializeAsAny
from pydantic_core import PydanticCustomError

from ..registry import SIMULATORS, Params, validate_kind
from ..robots import URDFRobot
from .protocol import SimWorld, WorldSettings

DEFAULT_SIMULATOR = "pybullet"


class SimulatorParams(Params):
    """Base of every backend's parameter model: ``type`` names the backend (conf/sim/)."""

    type: str = Field(DEFAULT_SIMULATOR, description="the simulator backend (rmpfusion.registry.SIMULATORS)")


def _sim_block(value: Any) -> Any:
    """Validate a ``sim`` block by its backend's own model (a bare name is ``{type: name}``)."""
    if isinstance(value, SimulatorParams):
        return value
    if isinstance(value, str):
        value = {"type": value}
    if not isinstance(value, Mapping):
        _refuse(f"sim is a simulator's block {{type: <name>, ...}} (conf/sim/), given {value!r}")
    return validate_kind(SIMULATORS, value, DEFAULT_SIMULATOR, "simulator")


def _refuse(message: str):
    raise PydanticCustomError("simulator", "{message}", {"message": message})


#: A field holding a simulator block, validated by the backend it names.
SimField = Annotated[SerializeAsAny[SimulatorParams], BeforeValidator(_sim_block)]


def has_window(params: SimulatorParams) -> bool:
    """Whether the backend ``params`` names can show a world in a window."""
    return bool(SIMULATORS.get(params.type).obj.has_window)


def open_world(robot: URDFRobot, settings: WorldSettings, params: SimulatorParams) -> SimWorld:
    """A new world of the backend ``params`` names (given as the base ``SimulatorParams``, validated by the
    backend's own model: its defaults filled in)."""
    entry = SIMULATORS.get(params.type)
    own = params if isinstance(params, entry.params) else entry.validate(params.model_dump())
    world = entry.obj(robot, settings, own)
    assert isinstance(world, SimWorld), f"simulator '{params.type}' must subclass rmpfusion.sims.SimWorld"
    return world
