"""A scene's obstacles as aux state, and how it changes while obstacles move.

Obstacle k (numbered from 1) reaches the tree as ``obstacle{k}_center`` (3) and ``obstacle{k}_radius`` (1), the
two entries every obstacle has and the learned obstacle weights read, plus what its shape needs
(``obstacle{k}_half_extents`` and ``_rotation`` of a box, ``_axis`` and ``_half_height`` of a cylinder, ``_axis``
and ``_half_length`` of a capsule) and, when it moves, ``obstacle{k}_velocity`` (3). The radius of a box is its
smallest half extent. Centres are where the obstacle is at the time the aux describes: ``aux_at`` moves a
t = 0 aux state to any time (one time per sample), so rollouts, demonstrations and the evaluation all see the
same motion.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import torch
from torch import Tensor

from ..maps.kinematics import rpy_matrix
from .spec import Box, Capsule, Cylinder, Linear, Scene, Waypoints

#: aux entries of each shape beyond centre and radius: name suffix -> dimension
SHAPE_AUX: dict[str, dict[str, int]] = {
    "sphere": {},
    "box": {"half_extents": 3, "rotation": 9},
    "cylinder": {"axis": 3, "half_height": 1},
    "capsule": {"axis": 3, "half_length": 1},
}


def obstacle_aux_names(k: int, shape: str, moving: bool) -> dict[str, int]:
    """Aux name -> dimension of obstacle ``k`` (from 1)."""
    dims = {f"obstacle{k}_center": 3, f"obstacle{k}_radius": 1}
    dims.update({f"obstacle{k}_{s}": d for s, d in SHAPE_AUX[shape].items()})
    if moving:
        dims[f"obstacle{k}_velocity"] = 3
    return dims


def scene_aux_dims(scene: Scene) -> dict[str, int]:
    dims: dict[str, int] = {}
    for k, o in enumerate(scene.obstacles, start=1):
        dims.update(obstacle_aux_names(k, o.type, o.moving))
    return dims


def _unit(v) -> list[float]:
    n = math.sqrt(sum(a * a for a in v))
    return [a / n for a in v]


def _shape_values(o) -> dict[str, list[float]]:
    if isinstance(o, Box):
        return {
            "radius": [min(o.half_extents)],
            "half_extents": list(o.half_extents),
            "rotation": rpy_matrix(o.rpy).reshape(-1).tolist(),
        }
    if isinstance(o, Cylinder):
        return {"radius": [o.radius], "axis": _unit(o.axis), "half_height": [o.height / 2]}
    if isinstance(o, Capsule):
        return {"radius": [o.radius], "axis": _unit(o.axis), "half_length": [o.length / 2]}
    return {"radius": [o.radius]}


def scene_aux(scene: Scene, centers: Tensor, dtype: torch.dtype) -> dict[str, Tensor]:
    """The t = 0 aux state of ``n`` copies of the scene whose obstacles start at ``centers`` (n, K, 3)."""
    n, out = centers.shape[0], {}
    for k, o in enumerate(scene.obstacles, start=1):
        out[f"obstacle{k}_center"] = centers[:, k - 1].to(dtype).contiguous()
        for s, v in _shape_values(o).items():
            out[f"obstacle{k}_{s}"] = torch.tensor(v, dtype=dtype).expand(n, len(v)).contiguous()
        if o.moving:
            out[f"obstacle{k}_velocity"] = path(o.motion, torch.zeros(n, dtype=dtype))[1]
    return out


def path(motion, t: Tensor) -> tuple[Tensor, Tensor]:
    """(offset from the centre (B, 3), velocity (B, 3)) of a moving obstacle at times ``t`` (B,)."""
    t = t.reshape(-1)
    if isinstance(motion, Linear):
        v = torch.tensor(motion.velocity, dtype=t.dtype)
        return t[:, None] * v, v.expand(t.shape[0], 3).clone()
    if isinstance(motion, Waypoints):
        return _waypoint_path(motion, t)
    return t.new_zeros(t.shape[0], 3), t.new_zeros(t.shape[0], 3)


def _waypoint_path(m: Waypoints, t: Tensor) -> tuple[Tensor, Tensor]:
    pts = torch.tensor([(0.0, 0.0, 0.0), *m.points, (0.0, 0.0, 0.0)], dtype=t.dtype)
    seg = pts[1:] - pts[:-1]
    length = seg.norm(dim=-1)
    keep = length > 0
    pts0, seg, length = pts[:-1][keep], seg[keep], length[keep]
    if length.numel() == 0:  # every waypoint at the centre: it stays there
        return t.new_zeros(t.shape[0], 3), t.new_zeros(t.shape[0], 3)
    start = torch.cumsum(length, 0) - length
    s = torch.remainder(m.speed * t, length.sum())
    i = (torch.searchsorted(start, s, right=True) - 1).clamp(0, length.numel() - 1)
    frac = ((s - start[i]) / length[i])[:, None]
    return pts0[i] + frac * seg[i], m.speed * seg[i] / length[i][:, None]


def aux_at(scene: Scene, aux0: Mapping[str, Tensor], t: Tensor) -> dict[str, Tensor]:
    """The aux state ``aux0`` (at t = 0) at times ``t`` (B,) or one time: moving obstacles' centres and velocities
    advanced along their paths; everything else as it is."""
    out = dict(aux0)
    for k, o in enumerate(scene.obstacles, start=1):
        if not o.moving:
            continue
        c0 = aux0[f"obstacle{k}_center"]
        tt = torch.as_tensor(t, dtype=c0.dtype).reshape(-1).expand(c0.shape[0])
        offset, velocity = path(o.motion, tt)
        out[f"obstacle{k}_center"] = c0 + offset
        out[f"obstacle{k}_velocity"] = velocity
    return out


#: what an absent member of an obstacle set (scenes/sets.py) holds in its fields: a small, well-formed obstacle at
#: the origin (its distance is never used)
PARKED: dict[str, tuple[float, ...]] = {
    "center": (0.0, 0.0, 0.0),
    "radius": (0.1,),
    "velocity": (0.0, 0.0, 0.0),
    "half_extents": (0.1, 0.1, 0.1),
    "rotation": (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0),
    "axis": (0.0, 0.0, 1.0),
    "half_height": (0.1,),
    "half_length": (0.1,),
    "normal": (0.0, 0.0, 1.0),
}
