"""A scene's obstacles as a simulator builds them, read from one sample's aux state (``scenes/aux.py``): the same
numbers the tree reads, so what the tree avoids and what the simulator collides with are one geometry."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from ..scenes import Scene
from .protocol import Obstacle


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


def obstacles_of(scene: Scene, a: Mapping[str, np.ndarray]) -> list[Obstacle]:
    """The obstacles of ``scene`` as sample ``a`` (its aux state as numpy vectors) places and sizes them."""
    out = []
    for k, o in enumerate(scene.obstacles, start=1):
        pre = f"obstacle{k}_"
        centre, radius = np.asarray(a[pre + "center"], dtype=float), float(a[pre + "radius"][0])
        if o.type == "sphere":
            out.append(Obstacle("sphere", centre, radius=radius))
        elif o.type == "box":
            hx, hy, hz = (float(h) for h in a[pre + "half_extents"])
            out.append(Obstacle("box", centre, np.reshape(a[pre + "rotation"], (3, 3)), half_extents=(hx, hy, hz)))
        else:
            length = float(a[pre + ("half_height" if o.type == "cylinder" else "half_length")][0])
            out.append(Obstacle(o.type, centre, rotation_z_to(a[pre + "axis"]), radius=radius, half_length=length))
    return out
