"""Obstacles as a simulator builds them, read from the numbers the tree reads: a scene's obstacles from one sample's
aux state (``scenes/aux.py``), a run-time world's present set members from its set tensors (``scenes/sets.py``). What
the tree avoids and what the simulator collides with are then one geometry."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from torch import Tensor

from ..scenes import ObstacleSet, Scene
from .protocol import Obstacle, ShapeKind


def rotation_z_to(axis: np.ndarray) -> np.ndarray:
    """The shortest rotation taking z to the unit ``axis`` (a half turn about x when ``axis`` is −z)."""
    z = np.array([0.0, 0.0, 1.0])
    axis = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    c = float(z @ axis)
    if c < -1 + 1e-12:
        return np.diag([1.0, -1.0, -1.0])
    v = np.cross(z, axis)
    K = np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])
    return np.eye(3) + K + K @ K / (1.0 + c)


def obstacle(kind: str, fields: Mapping[str, np.ndarray]) -> Obstacle:
    """One obstacle of shape ``kind`` from its fields (``center``, ``radius`` and its shape's, as numpy vectors)."""
    centre, radius = np.asarray(fields["center"], dtype=float), float(fields["radius"][0])
    if kind == "sphere":
        return Obstacle("sphere", centre, radius=radius)
    if kind == "box":
        hx, hy, hz = (float(h) for h in fields["half_extents"])
        return Obstacle("box", centre, np.reshape(fields["rotation"], (3, 3)), half_extents=(hx, hy, hz))
    if kind in ("cylinder", "capsule"):
        length = float(fields["half_height" if kind == "cylinder" else "half_length"][0])
        shape: ShapeKind = "cylinder" if kind == "cylinder" else "capsule"
        return Obstacle(shape, centre, rotation_z_to(fields["axis"]), radius=radius, half_length=length)
    raise ValueError(f"no simulator body for an obstacle of shape {kind!r} (a plane is the world's ground)")


def obstacles_of(scene: Scene, a: Mapping[str, np.ndarray]) -> list[Obstacle]:
    """The obstacles of ``scene`` as sample ``a`` (its aux state as numpy vectors) places and sizes them."""
    out = []
    for k, o in enumerate(scene.obstacles, start=1):
        pre = f"obstacle{k}_"
        out.append(obstacle(o.type, {name.removeprefix(pre): v for name, v in a.items() if name.startswith(pre)}))
    return out


def obstacles_of_sets(sets: list[ObstacleSet], aux: Mapping[str, Tensor], sample: int = 0) -> list[Obstacle]:
    """The present members of obstacle ``sets`` (their tensors and masks in ``aux``) of sample ``sample``, in set
    order and member order: what a simulator builds for a run-time world (``scenes.World``). Plane members have no
    body: a simulator's ground is ``set_ground``."""
    out = []
    for s in sets:
        if s.shape == "plane":
            continue
        mask = aux[f"{s.prefix}_mask"][sample].detach().cpu().numpy()
        fields = {f: aux[f"{s.prefix}_{f}"][sample].detach().cpu().numpy() for f in s.fields()}
        out += [obstacle(s.shape, {f: v[i].reshape(-1) for f, v in fields.items()}) for i in np.flatnonzero(mask > 0.5)]
    return out
