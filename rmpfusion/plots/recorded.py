"""Figures of an experiment on recorded demonstrations, drawn from the rollouts the evaluation made: what each policy
does from a grid of starts at rest over the demonstrations (a second-order policy has no single velocity field to
draw, so its rollouts are drawn), and V_r along those rollouts (Theorem 2: never rising)."""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from matplotlib.patches import Circle

from ..envs.rollout import Rollout
from .figures import LEGEND_SIZE, TIME_LABEL, TITLE_SIZE, V_LABEL, save_figure, subplots

#: configurations (..., d) -> points of the drawn plane (..., 2): the plane itself, or an arm's end effector seen from
#: above or from the side
ToPlane = Callable[[np.ndarray], np.ndarray]


@dataclass(frozen=True)
class View:
    """One way of drawing rollouts: configurations to the plane drawn (``to_plane``), which two of the goal aux's
    coordinates that plane shows (``goal_axes``), and its axes' names. ``from_above``: the plane looks down the
    world's z axis, so each obstacle's footprint is drawn (a circle of its radius), for every held-out
    demonstration where its own obstacle stood."""

    to_plane: ToPlane
    goal_axes: tuple[int, int] = (0, 1)
    labels: tuple[str, str] = ("x (m)", "y (m)")
    title: str = ""
    from_above: bool = False


PLANE = View(lambda q: q[..., :2])


def draw_rollouts(rollouts: Mapping[str, Rollout], batch, demos: Mapping[str, list], views: Sequence[View] = (PLANE,)):
    """One column per policy, one row per view: its rollouts from the grid of starts at rest and from the held-out
    demonstrations' starts, the demonstrations beneath (training grey, held-out coloured), the goal. An arm's
    end effector is drawn from above and from the side, since a detour over an obstacle is invisible from above."""
    n = len(rollouts)
    fig, axes = subplots(len(views), n, figsize=(3.8 * n, 3.8 * len(views)), layout="constrained", squeeze=False)
    for row, view in zip(axes, views):
        for ax, (label, ro) in zip(row, rollouts.items()):
            _draw_panel(ax, ro, batch, demos, view)
            ax.set_title(f"{label}{view.title}", fontsize=TITLE_SIZE)
    handles, labels = axes[0][0].get_legend_handles_labels()
    fig.legend(handles, labels, fontsize=LEGEND_SIZE, loc="outside lower center", ncols=4)
    return fig


def _draw_panel(ax, ro: Rollout, batch, demos: Mapping[str, list], view: View) -> None:
    grid = batch.grid
    goal = batch.aux["goal"][grid][0].numpy()[list(view.goal_axes)]
    q = view.to_plane(ro.q.numpy())
    for k, (split, shown) in enumerate(demos.items()):
        style = {"color": "0.65", "lw": 3.0} if split == "train" else {"color": f"C{k}", "lw": 2.4}
        for i, d in enumerate(shown):
            xy = view.to_plane(d.q)
            ax.plot(xy[:, 0], xy[:, 1], alpha=0.9, label=f"{split} demonstration" if i == 0 else None, **style)
    for i, b in enumerate(range(grid.start, grid.stop)):
        ax.plot(q[:, b, 0], q[:, b, 1], color="k", lw=0.6, label="rollout from rest" if i == 0 else None)
    for split, idx in batch.index.items():
        for i, b in enumerate(range(idx.start, idx.stop)):
            ax.plot(
                q[:, b, 0],
                q[:, b, 1],
                color="tab:red",
                lw=1.4,
                ls="--",
                label="rollout from a held-out start" if (i == 0 and split == "test") else None,
            )
    if view.from_above:
        _draw_footprints(ax, batch)
    starts = q[0, grid]
    ax.plot(starts[:, 0], starts[:, 1], "k.", ms=3, label="start at rest")
    ax.plot(*goal, "r*", ms=12, label="goal")
    shown_demos = np.concatenate([view.to_plane(d.q) for ds in demos.values() for d in ds] + [starts])
    lo, hi = shown_demos.min(0), shown_demos.max(0)
    pad = 0.05 * (hi - lo).max()
    ax.set_xlim(lo[0] - pad, hi[0] + pad), ax.set_ylim(lo[1] - pad, hi[1] + pad)
    ax.set_xlabel(view.labels[0]), ax.set_ylabel(view.labels[1])
    ax.set_aspect("equal", adjustable="box")


def _draw_footprints(ax, batch) -> None:
    """Each obstacle's footprint seen from above (``obstacleK_center`` and ``obstacleK_radius`` of the aux state):
    where the starts at rest saw it (grey), and, where a held-out demonstration's own obstacle stood elsewhere, there
    (dotted, in the held-out rollouts' red)."""
    rows = [batch.grid.start, *(b for idx in batch.index.values() for b in range(idx.start, idx.stop))]
    k = 1
    while f"obstacle{k}_center" in batch.aux and f"obstacle{k}_radius" in batch.aux:
        centres, radii = batch.aux[f"obstacle{k}_center"].numpy(), batch.aux[f"obstacle{k}_radius"].numpy()
        drawn: list[tuple[float, float]] = []
        for b in rows:
            xy = (float(centres[b, 0]), float(centres[b, 1]))
            if any(np.hypot(xy[0] - x, xy[1] - y) < 1e-9 for x, y in drawn):
                continue
            scene = b == batch.grid.start
            style = {"color": "0.45", "ls": "-"} if scene else {"color": "tab:red", "ls": ":"}
            ax.add_patch(Circle(xy, float(radii[b, 0]), fill=False, lw=1.0, **style))
            drawn.append(xy)
        k += 1


def draw_lyapunov(rollouts: Mapping[str, Rollout], grid: slice, shown: int = 25):
    """V_r / V_r(0) along each policy's rollouts from rest (log scale): every curve must never rise."""
    fig, axes = subplots(1, 1, figsize=(5.2, 3.4), layout="constrained", squeeze=False)
    ax = axes[0][0]
    for k, (label, ro) in enumerate(rollouts.items()):
        if ro.V is None:
            continue
        V = ro.V[:, grid].numpy()
        rel = V / np.maximum(V[:1], 1e-300)
        t = ro.times.numpy()
        for b in np.linspace(0, rel.shape[1] - 1, min(shown, rel.shape[1])).astype(int):
            ax.plot(t, np.maximum(rel[:, b], 1e-12), color=f"C{k}", lw=0.8, alpha=0.6, label=label if b == 0 else None)
    ax.set_yscale("log")
    ax.set_xlabel(TIME_LABEL), ax.set_ylabel(f"{V_LABEL} / $V_r(0)$")
    ax.set_title(f"V_r along rollouts from rest ({shown} starts per policy)", fontsize=TITLE_SIZE)
    ax.legend(fontsize=LEGEND_SIZE)
    return fig


def recorded_figures(
    out_dir: Path,
    rollouts: Mapping[str, Rollout],
    batch,
    demos: Mapping[str, list],
    views: Sequence[View] | None = None,
    trees: Mapping[str, object] | None = None,
) -> dict[str, str]:
    """rollouts.png (2-D demonstrations, or any whose configurations ``views`` map to planes) and lyapunov.png
    in ``out_dir``, and for 2-D demonstrations latent_<learner>.png for each of ``trees`` ({learner: its trained
    RMPTree}) that has a learned map (its deepest); their paths."""
    paths = {}
    if views is not None or batch.q0.shape[1] == 2:
        drawn = draw_rollouts(rollouts, batch, demos, views or (PLANE,))
        paths["rollouts"] = save_figure(drawn, Path(out_dir) / "rollouts.png")
    paths["lyapunov"] = save_figure(draw_lyapunov(rollouts, batch.grid), Path(out_dir) / "lyapunov.png")
    if batch.q0.shape[1] == 2:
        starts = batch.q0[batch.grid].numpy()
        goal = batch.aux["goal"][batch.grid][0].numpy()
        for name, tree in (trees or {}).items():
            learned = learned_map_nodes(tree)
            if learned:
                drawn = draw_latent(tree, learned[-1], demos, goal, starts.min(0), starts.max(0))
                paths[f"latent_{name}"] = save_figure(drawn, Path(out_dir) / f"latent_{name}.png")
    return {k: str(v) for k, v in paths.items()}


def learned_map_nodes(tree) -> list[str]:
    """The nodes of an ``RMPTree`` whose task maps have parameters (learned maps), root side first."""
    return [n for n in tree.order if n in tree.maps and any(True for _ in tree.maps[n].parameters())]


def _grid_lines(lo: np.ndarray, hi: np.ndarray, lines: int = 13, points: int = 120) -> list[np.ndarray]:
    """A regular grid over the box [lo, hi] as polylines (points, 2): what a map's deformation is drawn on."""
    xs, ys = np.linspace(lo[0], hi[0], lines), np.linspace(lo[1], hi[1], lines)
    t = np.linspace(0.0, 1.0, points)
    return [np.stack([np.full_like(t, x), lo[1] + t * (hi[1] - lo[1])], -1) for x in xs] + [
        np.stack([lo[0] + t * (hi[0] - lo[0]), np.full_like(t, y)], -1) for y in ys
    ]


def draw_latent(tree, node: str, demos: Mapping[str, list], goal: np.ndarray, lo: np.ndarray, hi: np.ndarray):
    """The plane and the learned map's latent space side by side: a regular grid over the box [lo, hi] and the
    demonstrations, and their images at ``node`` (the map's output; its first two coordinates). A map that has learned
    the motion straightens the demonstrations towards the goal's image; the bent grid shows how far it had to bend
    space to do so."""
    dtype = next(tree.parameters()).dtype

    def image(xy: np.ndarray) -> np.ndarray:
        q = torch.as_tensor(xy, dtype=dtype)
        aux = {"goal": torch.as_tensor(goal, dtype=dtype).expand(q.shape[0], -1)}
        with torch.no_grad():
            y = tree(q, torch.zeros_like(q), aux, return_nodes=True).nodes["state"][node][0]
        return y[:, :2].numpy()

    fig, axes = subplots(1, 2, figsize=(8.4, 4.0), layout="constrained", squeeze=False)
    panels = (
        (axes[0][0], lambda p: p, "the plane", ("x (m)", "y (m)")),
        (axes[0][1], image, f"latent space ({node})", ("latent 1", "latent 2")),
    )
    for ax, to, title, (xlabel, ylabel) in panels:
        ax.set_xlabel(xlabel), ax.set_ylabel(ylabel)
        for line in _grid_lines(lo, hi):
            xy = to(line)
            ax.plot(xy[:, 0], xy[:, 1], color="0.8", lw=0.6)
        drawn = []
        for k, (split, shown) in enumerate(demos.items()):
            for i, d in enumerate(shown):
                xy = to(np.asarray(d.q)[:, :2])
                drawn.append(xy)
                color = "0.35" if split == "train" else f"C{k}"
                ax.plot(xy[:, 0], xy[:, 1], color=color, lw=1.8, label=f"{split} demonstration" if i == 0 else None)
        g = to(np.asarray(goal, dtype=float)[None, :2])[0]
        ax.plot(*g, "r*", ms=12, label="goal")
        # framed on the demonstrations (a learned map may stretch far regions of the box a long way)
        seen = np.concatenate([*drawn, g[None]]) if drawn else g[None]
        centre, half = (seen.max(0) + seen.min(0)) / 2, 0.75 * (seen.max(0) - seen.min(0)).max() + 1e-9
        ax.set_xlim(centre[0] - half, centre[0] + half), ax.set_ylim(centre[1] - half, centre[1] + half)
        ax.set_title(title, fontsize=TITLE_SIZE)
        ax.set_aspect("equal", adjustable="box")
    handles, labels = axes[0][0].get_legend_handles_labels()
    fig.legend(handles, labels, fontsize=LEGEND_SIZE, loc="outside lower center", ncols=4)
    return fig
