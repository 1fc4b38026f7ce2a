"""Figures of an experiment on recorded demonstrations, drawn from the rollouts the evaluation made: what each policy
does from a grid of starts at rest over the demonstrations (a second-order policy has no single velocity field to
draw, so its rollouts are drawn), and V_r along those rollouts (Theorem 2: never rising)."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from pathlib import Path

import numpy as np

from ..envs.rollout import Rollout
from .figures import LEGEND_SIZE, TIME_LABEL, TITLE_SIZE, V_LABEL, save_figure, subplots

#: configurations (..., d) -> points of the drawn plane (..., 2): the plane itself, or an arm's end effector seen from
#: above
ToPlane = Callable[[np.ndarray], np.ndarray]


def _first_two(q: np.ndarray) -> np.ndarray:
    return q[..., :2]


def draw_rollouts(rollouts: Mapping[str, Rollout], batch, demos: Mapping[str, list], to_plane: ToPlane = _first_two):
    """One panel per policy: its rollouts from the grid of starts at rest and from the held-out demonstrations'
    starts, the demonstrations beneath (training grey, held-out coloured), the goal; drawn in the plane ``to_plane``
    maps configurations to (an arm's end effector from above; the goal aux is then the end effector's)."""
    n = len(rollouts)
    fig, axes = subplots(1, n, figsize=(3.8 * n, 3.8), layout="constrained", squeeze=False)
    grid = batch.grid
    goal = batch.aux["goal"][grid][0].numpy()[:2]
    for ax, (label, ro) in zip(axes[0], rollouts.items()):
        q = to_plane(ro.q.numpy())
        for k, (split, shown) in enumerate(demos.items()):
            style = {"color": "0.65", "lw": 3.0} if split == "train" else {"color": f"C{k}", "lw": 2.4}
            for i, d in enumerate(shown):
                xy = to_plane(d.q)
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
        starts = q[0, grid]
        ax.plot(starts[:, 0], starts[:, 1], "k.", ms=3, label="start at rest")
        ax.plot(*goal, "r*", ms=12, label="goal")
        lo, hi = starts.min(0), starts.max(0)
        ax.set_xlim(lo[0], hi[0]), ax.set_ylim(lo[1], hi[1])
        ax.set_title(label, fontsize=TITLE_SIZE)
        ax.set_xlabel("x (m)"), ax.set_ylabel("y (m)")
        ax.set_aspect("equal", adjustable="box")
    handles, labels = axes[0][0].get_legend_handles_labels()
    fig.legend(handles, labels, fontsize=LEGEND_SIZE, loc="outside lower center", ncols=4)
    return fig


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
    to_plane: ToPlane | None = None,
) -> dict[str, str]:
    """rollouts.png (2-D demonstrations, or any whose configurations ``to_plane`` maps to a plane) and lyapunov.png
    in ``out_dir``; their paths."""
    paths = {}
    if to_plane is not None or batch.q0.shape[1] == 2:
        drawn = draw_rollouts(rollouts, batch, demos, to_plane or _first_two)
        paths["rollouts"] = save_figure(drawn, Path(out_dir) / "rollouts.png")
    paths["lyapunov"] = save_figure(draw_lyapunov(rollouts, batch.grid), Path(out_dir) / "lyapunov.png")
    return {k: str(v) for k, v in paths.items()}
