"""The robots and scenes of conf/ for tests: the Panda experiment's environment and tree built from the same
files the experiments compose, so a test exercises what `experiment=franka` runs."""
from __future__ import annotations

from pathlib import Path

import torch
import yaml

from rmpfusion.envs.manipulator import Manipulator
from rmpfusion.envs.manipulator_tree import manipulator_tree_spec
from rmpfusion.scenes import Scene, scene_aux

CONF = Path(__file__).resolve().parents[1] / "conf"
F64 = torch.float64


def robot(name: str = "panda") -> dict:
    """conf/robot/<name>.yaml as data."""
    return yaml.safe_load((CONF / "robot" / f"{name}.yaml").read_text())


def scene(name: str) -> dict:
    """conf/scene/<name>.yaml as data."""
    return yaml.safe_load((CONF / "scene" / f"{name}.yaml").read_text())


def cylinders(centers, radii, height: float = 0.6) -> dict:
    """A scene of standing cylinders, as the Franka experiment's."""
    return {"obstacles": [{"type": "cylinder", "center": list(c), "radius": r, "height": height}
                          for c, r in zip(centers, radii)]}


def franka_env(scene_spec: dict | None = None, **overrides) -> Manipulator:
    """The Panda among the Franka experiment's cylinder (or ``scene_spec``)."""
    return Manipulator(robot=robot("panda"), scene=scene_spec or scene("franka_cylinder"), **overrides)


def franka_tree_spec(n_obstacles: int = 1, **settings) -> dict:
    """The Franka experiment's tree (conf/tree/franka.yaml) with ``n_obstacles`` standing cylinders."""
    sc = cylinders([(0.5, 0.1 * k, 0.3) for k in range(n_obstacles)], [0.05] * n_obstacles)
    return manipulator_tree_spec(robot("panda"), sc, obstacle_maps={"cylinder": "cylinder_distance"}, **settings)


def make_aux(goal, centers, radii, height: float = 0.5) -> dict:
    """One sample's aux state: a goal among standing cylinders."""
    sc = Scene.model_validate(cylinders(centers, radii, height))
    aux = scene_aux(sc, torch.tensor([centers], dtype=F64).reshape(1, len(centers), 3), F64) if centers else {}
    for k, r in enumerate(radii, start=1):
        aux[f"obstacle{k}_radius"] = torch.tensor([[r]], dtype=F64)
    return {"goal": torch.tensor([goal], dtype=F64), **aux}
