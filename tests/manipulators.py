"""The robots and scenes of conf/ for tests: the Panda experiment's environment and tree built from the same
files the experiments compose, so a test exercises what `experiment=franka` runs; and pybullet_data's Panda and
KUKA iiwa as the robot maps' tests name them."""

from __future__ import annotations

from contextlib import contextmanager
from pathlib import Path

import pybullet
import pybullet_data
import torch
import yaml

from rmpfusion.envs.manipulator import Manipulator
from rmpfusion.envs.manipulator_tree import manipulator_tree_spec
from rmpfusion.maps.urdf import resolve_urdf_path
from rmpfusion.scenes import Scene, scene_aux

CONF = Path(__file__).resolve().parents[1] / "conf"
F64 = torch.float64

PANDA_URDF = "pkg://pybullet_data/franka_panda/panda.urdf"
#: the Panda's arm joints (its fingers stay at 0)
PANDA_ARM_JOINTS = tuple(f"panda_joint{i}" for i in range(1, 8))
#: the Panda arm as a robot map's ``urdf`` and ``joints``
PANDA_ARM = {"urdf": PANDA_URDF, "joints": list(PANDA_ARM_JOINTS)}
#: a Panda configuration away from its joint limits and from self-collision
PANDA_HOME = torch.tensor([0.0, -0.3, 0.0, -2.2, 0.0, 2.0, 0.8])
IIWA_URDF = str(Path(pybullet_data.getDataPath()) / "kuka_iiwa" / "model.urdf")


def load_panda_urdf_path() -> str:
    """The Panda's URDF as a file path (for pybullet, and for parse_urdf)."""
    return resolve_urdf_path(PANDA_URDF)


@contextmanager
def pybullet_robot(urdf: str):
    """The robot in a private pybullet client, its base fixed at the origin like our root frame: (client, body id,
    {link name: pybullet link index}, {joint name: pybullet joint index}, both in pybullet's joint order)."""
    cid = pybullet.connect(pybullet.DIRECT)
    try:
        body = pybullet.loadURDF(urdf, useFixedBase=True, physicsClientId=cid)
        info = [
            pybullet.getJointInfo(body, i, physicsClientId=cid)
            for i in range(pybullet.getNumJoints(body, physicsClientId=cid))
        ]
        yield cid, body, {j[12].decode(): j[0] for j in info}, {j[1].decode(): j[0] for j in info}
    finally:
        pybullet.disconnect(cid)


def robot(name: str = "panda") -> dict:
    """conf/robot/<name>.yaml as data."""
    return yaml.safe_load((CONF / "robot" / f"{name}.yaml").read_text())


def scene(name: str) -> dict:
    """conf/scene/<name>.yaml as data."""
    return yaml.safe_load((CONF / "scene" / f"{name}.yaml").read_text())


def cylinders(centers, radii, height: float = 0.6) -> dict:
    """A scene of standing cylinders, as the Franka experiment's."""
    return {
        "obstacles": [
            {"type": "cylinder", "center": list(c), "radius": r, "height": height} for c, r in zip(centers, radii)
        ]
    }


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
