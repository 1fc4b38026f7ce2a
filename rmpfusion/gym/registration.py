"""Versioned Gymnasium ids for rmpfusion's simulated experiments: ``rmpfusion/<Experiment>-v0``.

Every experiment of conf/experiment/ whose environment is simulated (the 2-D particle, the manipulators) gets an id
made of its name in CamelCase (``franka`` → ``rmpfusion/Franka-v0``, ``2d1level`` → ``rmpfusion/2d1level-v0``,
``franka_three_obstacles`` → ``rmpfusion/FrankaThreeObstacles-v0``); ``gymnasium.make`` passes its keyword arguments
on to ``build_task`` (overrides, base, decision_interval, action_scale, horizon, cost, split), plus ``num_envs`` for
the vector version (``gymnasium.make_vec``). A variant of an experiment (its config groups, e.g. ``robot=xarm6``) is
its id with ``overrides``: ``gymnasium.make("rmpfusion/Reach-v0", overrides=["robot=xarm6"])``. Gymnasium 1.x no
longer reads plugin entry points, so the ids are registered when ``rmpfusion.gym`` is imported, which
``gymnasium.make("rmpfusion.gym:rmpfusion/Franka-v0")`` does by itself. A change to what an id's environment
observes, rewards or accepts gets a new version, never the same id.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import gymnasium as gym

from ..pipeline.compose import compose_config, conf_dir
from .env import RMPfusionEnv, RMPfusionVectorEnv
from .task import build_task

NAMESPACE = "rmpfusion"
VERSION = 0
#: the environments a Gymnasium task can step (an experiment on recorded demonstrations has no task to simulate)
SIMULATED = ("particle2d", "manipulator")


def gym_name(experiment: str) -> str:
    """``franka_three_obstacles`` → ``FrankaThreeObstacles``: an experiment's name as Gymnasium ids spell them."""
    return "".join(part[:1].upper() + part[1:] for part in experiment.split("_"))


def gym_id(experiment: str) -> str:
    return f"{NAMESPACE}/{gym_name(experiment)}-v{VERSION}"


def simulated_experiments(conf: Path | None = None) -> list[str]:
    """The experiments of conf/experiment/ whose environment a Gymnasium task can step: each composed as
    ``rmpfusion-run`` would (its environment and data come from the groups it chooses), ~0.2 s each."""
    root = Path(conf or conf_dir())
    out = []
    for path in sorted((root / "experiment").glob("*.yaml")):
        cfg = compose_config([f"experiment={path.stem}"], conf=root)
        if cfg.env.type in SIMULATED and cfg.data.get("source", "expert") == "expert":
            out.append(path.stem)
    return out


def make_env(experiment: str, **kwargs: Any) -> RMPfusionEnv:
    return RMPfusionEnv(build_task(experiment, **kwargs))


def make_vector_env(experiment: str, num_envs: int = 1, **kwargs: Any) -> RMPfusionVectorEnv:
    return RMPfusionVectorEnv(build_task(experiment, **kwargs), num_envs)


def register_all() -> list[str]:
    """Register every simulated experiment's id (once); returns the ids."""
    ids = []
    for experiment in simulated_experiments():
        env_id = gym_id(experiment)
        if env_id not in gym.registry:
            gym.register(
                id=env_id,
                entry_point=f"{__name__}:make_env",
                vector_entry_point=f"{__name__}:make_vector_env",
                kwargs={"experiment": experiment},
                disable_env_checker=False,
            )
        ids.append(env_id)
    return ids
