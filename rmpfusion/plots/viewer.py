"""A robot, its scene and its rollouts as one interactive 3D page: plotly, written as a self-contained HTML file.

What a user of a collision-sphere model wants to *see*: the control spheres where the tree puts them (rmpfusion's
own kinematics, ``maps/kinematics.py``, with the robot's mount), the obstacles as the tree reads them (``scenes/``;
moving ones where ``scenes/aux.py`` moves them), the goal, and what each policy did, on one time slider. Nothing
here simulates: the rollouts are given, so the page shows exactly the recorded states. The plotly JavaScript is
inlined, so the file opens with no network (4.8 MB of it is plotly.js itself).

Sizes stay small on purpose: each sphere is a low-resolution mesh (``SPHERE_RINGS`` × ``SPHERE_SEGMENTS``), all
spheres of one robot are one mesh trace, frames are at most ``max_frames`` of the recorded times, and vertex
coordinates travel as float32 (plotly encodes numpy arrays in binary).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import plotly.graph_objects as go
import torch
from torch import Tensor

from ..files import atomic_write_bytes
from ..maps.kinematics import rpy_matrix
from ..robots import RobotDescription, build_robot
from ..scenes import Scene, aux_at
from ..scenes.spec import Box, Capsule, Cylinder, Ground

#: latitude rings and longitude segments of a sphere's mesh: coarse, recognisably round
SPHERE_RINGS, SPHERE_SEGMENTS = 5, 10
#: the expert's spheres; tests look for this colour in screenshots
EXPERT_COLOR = "#d62728"
UNIT_COLOR = "#9467bd"
LEARNER_COLORS = ("#1f77b4", "#17becf", "#2ca02c", "#bcbd22", "#ff7f0e", "#e377c2", "#8c564b")
OBSTACLE_COLOR = "#7f7f7f"
GROUND_COLOR = "#c8c8b4"
GOAL_COLOR = "#2ca02c"


@dataclass
class PolicyTrack:
    """One policy's rollout from the start the page shows: configurations (T, d) at ``times`` (T,)."""

    label: str
    q: Tensor
    color: str | None = None  # None: the expert's red for "expert", else the next learner colour


@dataclass
class ViewerInput:
    """Everything the page draws: the robot, the scene at t = 0 as aux state of one sample, the goal, the tracks."""

    robot: RobotDescription
    scene: Scene
    aux: Mapping[str, Tensor]  # one sample's aux state at t = 0 (each (1, k) or (k,))
    times: Tensor  # (T,) record times shared by every track
    tracks: list[PolicyTrack] = field(default_factory=list)
    title: str = ""


# ---------------------------------------------------------------------------------------------------- meshes
def _unit_sphere(rings: int = SPHERE_RINGS, segments: int = SPHERE_SEGMENTS) -> tuple[np.ndarray, np.ndarray]:
    """(vertices (V, 3), triangles (F, 3)) of a unit sphere: two poles and ``rings - 1`` latitude circles."""
    lat = np.linspace(0, math.pi, rings + 1)[1:-1]
    lon = np.linspace(0, 2 * math.pi, segments, endpoint=False)
    ring = np.stack(
        [
            np.sin(lat)[:, None] * np.cos(lon),
            np.sin(lat)[:, None] * np.sin(lon),
            np.cos(lat)[:, None].repeat(segments, 1),
        ],
        -1,
    ).reshape(-1, 3)
    verts = np.concatenate([[[0, 0, 1]], ring, [[0, 0, -1]]])
    south, tris = len(verts) - 1, []
    for s in range(segments):
        n = (s + 1) % segments
        tris.append((0, 1 + s, 1 + n))
        last = 1 + (rings - 2) * segments
        tris.append((south, last + n, last + s))
        for r in range(rings - 2):
            a, b = 1 + r * segments, 1 + (r + 1) * segments
            tris += [(a + s, b + s, b + n), (a + s, b + n, a + n)]
    return verts, np.asarray(tris)


def _frame_towards(axis: np.ndarray) -> np.ndarray:
    """A rotation taking +z to the unit vector ``axis``."""
    z = axis / np.linalg.norm(axis)
    helper = np.array([1.0, 0, 0]) if abs(z[0]) < 0.9 else np.array([0, 1.0, 0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    return np.stack([x, np.cross(z, x), z], 1)


def _unit_cylinder(segments: int = 2 * SPHERE_SEGMENTS) -> tuple[np.ndarray, np.ndarray]:
    """A cylinder of radius 1 from z = -1 to z = 1, with its two caps."""
    lon = np.linspace(0, 2 * math.pi, segments, endpoint=False)
    circle = np.stack([np.cos(lon), np.sin(lon)], 1)
    verts = np.concatenate(
        [np.c_[circle, -np.ones(segments)], np.c_[circle, np.ones(segments)], [[0, 0, -1], [0, 0, 1]]]
    )
    tris = []
    for s in range(segments):
        n = (s + 1) % segments
        tris += [
            (s, n, segments + n),
            (s, segments + n, segments + s),
            (2 * segments, n, s),
            (2 * segments + 1, segments + s, segments + n),
        ]
    return verts, np.asarray(tris)


_BOX_VERTS = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=float)
_BOX_TRIS = np.array(
    [
        (0, 1, 3),
        (0, 3, 2),
        (4, 6, 7),
        (4, 7, 5),
        (0, 4, 5),
        (0, 5, 1),
        (2, 3, 7),
        (2, 7, 6),
        (0, 2, 6),
        (0, 6, 4),
        (1, 5, 7),
        (1, 7, 3),
    ]
)


def obstacle_mesh(o, center: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(vertices, triangles) of obstacle ``o`` (a scene spec entry) centred at ``center``."""
    if isinstance(o, Box):
        return _BOX_VERTS * np.asarray(o.half_extents) @ rpy_matrix(o.rpy).numpy().T + center, _BOX_TRIS
    if isinstance(o, Cylinder):
        v, t = _unit_cylinder()
        return v * [o.radius, o.radius, o.height / 2] @ _frame_towards(np.asarray(o.axis, float)).T + center, t
    v, t = _unit_sphere(SPHERE_RINGS + 1, 2 * SPHERE_SEGMENTS)
    v = v * o.radius
    if isinstance(o, Capsule):  # a sphere split at its equator, the halves pushed apart along the axis
        v[:, 2] += np.where(v[:, 2] >= 0, 1.0, -1.0) * o.length / 2
        v = v @ _frame_towards(np.asarray(o.axis, float)).T
    return v + center, t


def spheres_mesh(centers: np.ndarray, radii: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One mesh of many spheres: vertices (N·V, 3), triangles (N·F, 3)."""
    v, t = _unit_sphere()
    verts = (centers[:, None, :] + radii[:, None, None] * v[None]).reshape(-1, 3)
    tris = (t[None] + len(v) * np.arange(len(centers))[:, None, None]).reshape(-1, 3)
    return verts, tris


# ------------------------------------------------------------------------------------------------ kinematics
def control_sphere_centers(robot: RobotDescription, q: Tensor) -> tuple[Tensor, Tensor]:
    """World centres (..., N, 3) of the robot's control spheres at configurations q (..., d), and their radii (N,):
    the robot's own chain (its mount included) and each sphere's link and offset, as the tree's distance maps."""
    q = torch.as_tensor(q, dtype=torch.float64)
    points = robot.control_points
    flat = build_robot(robot).sphere_centres(q.reshape(-1, q.shape[-1]))
    return flat.reshape(*q.shape[:-1], len(points), 3), torch.tensor([c.radius for c in points], dtype=q.dtype)


def _forward_filled(q: Tensor) -> Tensor:
    """A track's configurations (T, d) with every non-finite record (a sample ended early) replaced by the last
    finite one, so the robot stays where it stopped instead of vanishing."""
    q = q.clone()
    for k in range(1, q.shape[0]):
        if not torch.isfinite(q[k]).all():
            q[k] = q[k - 1]
    return q


def frame_indices(n_times: int, max_frames: int) -> list[int]:
    """At most ``max_frames`` record indices, evenly spread, the first and the last always among them."""
    if n_times <= max_frames:
        return list(range(n_times))
    return sorted(set(np.linspace(0, n_times - 1, max_frames).round().astype(int).tolist()))


# ---------------------------------------------------------------------------------------------------- traces
def _mesh(
    verts: np.ndarray,
    tris: np.ndarray,
    color: str,
    name: str,
    opacity: float = 1.0,
    legend: bool = True,
    visible: bool | str = True,
) -> go.Mesh3d:
    v = verts.astype(np.float32)
    return go.Mesh3d(
        x=v[:, 0],
        y=v[:, 1],
        z=v[:, 2],
        i=tris[:, 0].astype(np.int32),
        j=tris[:, 1].astype(np.int32),
        k=tris[:, 2].astype(np.int32),
        color=color,
        opacity=opacity,
        name=name,
        showlegend=legend,
        legendgroup=name,
        visible=visible,
        flatshading=False,
        lighting={"ambient": 0.55, "diffuse": 0.6, "specular": 0.1},
        hoverinfo="name",
    )


def _moved(v: np.ndarray) -> dict:
    v = v.astype(np.float32)
    return {"type": "mesh3d", "x": v[:, 0], "y": v[:, 1], "z": v[:, 2]}


def _one(aux: Mapping[str, Tensor]) -> dict[str, Tensor]:
    return {k: torch.as_tensor(v, dtype=torch.float64).reshape(1, -1) for k, v in aux.items()}


def _obstacle_centers(scene: Scene, aux: Mapping[str, Tensor], times: Tensor) -> np.ndarray:
    """(T, K, 3) obstacle centres at ``times``: moving obstacles along their paths (``scenes.aux_at``)."""
    aux1 = _one(aux)
    out = []
    for t in times.tolist():
        at = aux_at(scene, aux1, torch.tensor([t], dtype=torch.float64))
        out.append([at[f"obstacle{k}_center"][0].numpy() for k in range(1, len(scene.obstacles) + 1)])
    return np.asarray(out, dtype=float).reshape(len(times), len(scene.obstacles), 3)


def _ground(ground: Ground, points: np.ndarray, margin: float = 0.25) -> go.Mesh3d:
    """The ground plane under everything else drawn (``points`` (N, 3)), ``margin`` m beyond it on every side."""
    h = ground.height
    (x0, y0), (x1, y1) = points[:, :2].min(0) - margin, points[:, :2].max(0) + margin
    v = np.array([[x0, y0, h], [x1, y0, h], [x1, y1, h], [x0, y1, h]])
    return _mesh(v, np.array([(0, 1, 2), (0, 2, 3)]), GROUND_COLOR, "ground", opacity=0.6)


def _colors(tracks: Sequence[PolicyTrack]) -> list[str]:
    palette, out = iter(LEARNER_COLORS * (len(tracks) // len(LEARNER_COLORS) + 1)), []
    for tr in tracks:
        out.append(
            tr.color
            or (EXPERT_COLOR if tr.label == "expert" else UNIT_COLOR if tr.label == "unit weights" else next(palette))
        )
    return out


def viewer_figure(inp: ViewerInput, max_frames: int = 40) -> go.Figure:
    """The page's figure: static traces (ground, still obstacles, goal, end paths), then the traces frames move
    (each track's spheres, the moving obstacles), and one plotly frame per shown record time on a slider."""
    times = torch.as_tensor(inp.times, dtype=torch.float64)
    shown = frame_indices(len(times), max_frames)
    tracks = [
        PolicyTrack(t.label, _forward_filled(torch.as_tensor(t.q, dtype=torch.float64)), t.color) for t in inp.tracks
    ]
    colors = _colors(tracks)
    centers = {t.label: control_sphere_centers(inp.robot, t.q[shown]) for t in tracks}
    radii = control_sphere_centers(inp.robot, tracks[0].q[:1])[1].numpy() if tracks else np.zeros(0)
    obstacles = _obstacle_centers(inp.scene, inp.aux, times[shown])
    goal = torch.as_tensor(inp.aux["goal"], dtype=torch.float64).reshape(-1).numpy()

    static: list = []
    if inp.scene.ground is not None:
        drawn = [c[0].reshape(-1, 3).numpy() for c in centers.values()] + [obstacles.reshape(-1, 3), goal[None]]
        static.append(_ground(inp.scene.ground, np.concatenate(drawn)))
    moving = [k for k, o in enumerate(inp.scene.obstacles) if o.moving]
    for k, o in enumerate(inp.scene.obstacles):
        if not o.moving:
            static.append(
                _mesh(*obstacle_mesh(o, obstacles[0, k]), OBSTACLE_COLOR, f"obstacle {k + 1} ({o.type})", opacity=0.8)
            )
    static.append(
        go.Scatter3d(
            x=[goal[0]],
            y=[goal[1]],
            z=[goal[2]],
            mode="markers",
            name="goal",
            marker={"size": 7, "color": GOAL_COLOR, "symbol": "diamond"},
        )
    )
    ee = inp.robot.end_effector
    for tr, color in zip(tracks, colors):
        chain = build_robot(inp.robot).chain
        R, p = chain.forward_kinematics(tr.q, [ee.link])[ee.link]
        path = (p + R @ torch.tensor(ee.offset, dtype=torch.float64)).numpy()
        static.append(
            go.Scatter3d(
                x=path[:, 0],
                y=path[:, 1],
                z=path[:, 2],
                mode="lines",
                name=f"{tr.label}: path",
                legendgroup=tr.label,
                showlegend=False,
                line={"color": color, "width": 4},
            )
        )

    first = len(static)
    dynamic = []
    for n, (tr, color) in enumerate(zip(tracks, colors)):
        v, t = spheres_mesh(centers[tr.label][0][0].numpy(), radii)
        shown_first = n < 2 or n == len(tracks) - 1  # the expert, the next policy and the last; the rest on a click
        dynamic.append(
            _mesh(v, t, color, tr.label, opacity=1.0 if n == 0 else 0.5, visible=True if shown_first else "legendonly")
        )
    for k in moving:
        o = inp.scene.obstacles[k]
        dynamic.append(
            _mesh(
                *obstacle_mesh(o, obstacles[0, k]), OBSTACLE_COLOR, f"obstacle {k + 1} ({o.type}, moving)", opacity=0.8
            )
        )
    indices = list(range(first, first + len(dynamic)))

    frames = []
    for f, idx in enumerate(shown):
        data = [_moved(spheres_mesh(centers[tr.label][0][f].numpy(), radii)[0]) for tr in tracks]
        data += [_moved(obstacle_mesh(inp.scene.obstacles[k], obstacles[f, k])[0]) for k in moving]
        frames.append(go.Frame(data=data, traces=indices, name=f"{float(times[idx]):.2f}"))

    fig = go.Figure(data=static + dynamic, frames=frames)
    fig.update_layout(_layout(inp, frames))
    return fig


def _layout(inp: ViewerInput, frames: Sequence[go.Frame]) -> dict:
    def go_to(name: str | None, play: bool = False) -> list:
        return [
            [name] if name is not None else None,
            {
                "frame": {"duration": 120 if play else 0, "redraw": True},
                "mode": "immediate",
                "fromcurrent": True,
                "transition": {"duration": 0},
            },
        ]

    steps = [{"method": "animate", "label": fr.name, "args": go_to(fr.name)} for fr in frames]
    return {
        "title": {"text": inp.title or f"{inp.robot.name}: control spheres, obstacles, goal and rollouts"},
        "scene": {
            "aspectmode": "data",
            "xaxis": {"title": "x (m)"},
            "yaxis": {"title": "y (m)"},
            "zaxis": {"title": "z (m)"},
            "camera": {"eye": {"x": 1.4, "y": -1.4, "z": 0.9}},
        },
        "legend": {"title": {"text": "click to show or hide"}},
        "margin": {"l": 0, "r": 0, "t": 40, "b": 0},
        "updatemenus": [
            {
                "type": "buttons",
                "showactive": False,
                "x": 0.05,
                "y": 0.05,
                "xanchor": "right",
                "buttons": [
                    {"label": "play", "method": "animate", "args": go_to(None, play=True)},
                    {
                        "label": "pause",
                        "method": "animate",
                        "args": [[None], {"frame": {"duration": 0}, "mode": "immediate"}],
                    },
                ],
            }
        ],
        "sliders": [
            {
                "active": 0,
                "x": 0.08,
                "len": 0.9,
                "y": 0.05,
                "currentvalue": {"prefix": "t = ", "suffix": " s"},
                "steps": steps,
            }
        ],
    }


def write_viewer(fig: go.Figure, path: str | Path) -> Path:
    """The figure as one HTML file with plotly.js inlined (opens with no network), written atomically. The
    caller decides whether an existing file may be replaced."""
    path = Path(path)
    html = fig.to_html(include_plotlyjs=True, full_html=True, auto_play=False, config={"displaylogo": False})
    atomic_write_bytes(path, html.encode())
    return path
