"""Figures of the 2D experiments: trajectories (Fig. 3a,b,e), V_r(t) (3c), learning curves (3d) and the
progression grid over training snapshots (Fig. 4, 7, 8). Written atomically so a crashed run never leaves
a half-written PNG that looks like a result."""
from __future__ import annotations

import os
from pathlib import Path
from typing import Mapping, Sequence

import matplotlib
import numpy as np
import torch
from matplotlib.figure import Figure
from matplotlib.patches import Circle

from ..files import atomic_path

_OBSTACLE_COLOURS = ("tab:red", "tab:blue", "tab:purple", "tab:brown")


def subplots(*grid, figsize: tuple[float, float], **kwargs):
    """A figure and its axes, drawn off-screen: a ``Figure`` renders to a file without pyplot, so importing
    the plots never selects a matplotlib backend for the whole process (an interactive session keeps its own)."""
    fig = Figure(figsize=figsize)
    return fig, fig.subplots(*grid, **kwargs)


def colour_cycle() -> list[str]:
    return matplotlib.rcParams["axes.prop_cycle"].by_key()["color"]


def save_figure(fig, path: str | os.PathLike, dpi: int = 110) -> Path:
    path = Path(path)
    with atomic_path(path, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=dpi, format="png", bbox_inches="tight")
    return path


def _np(x) -> np.ndarray:
    return x.detach().cpu().double().numpy() if isinstance(x, torch.Tensor) else np.asarray(x, dtype=float)


def draw_environment(ax, aux: Mapping[str, torch.Tensor], q0=None, qd0=None) -> None:
    """Obstacles as filled circles, the goal as an orange square, starts as black dots with velocity arrows."""
    k = 1
    while f"obstacle{k}_center" in aux:
        c = _np(aux[f"obstacle{k}_center"]).reshape(-1, 2)[0]
        r = float(_np(aux[f"obstacle{k}_radius"]).reshape(-1)[0])
        ax.add_patch(Circle(c, r, color=_OBSTACLE_COLOURS[(k - 1) % len(_OBSTACLE_COLOURS)], alpha=0.45, lw=0))
        k += 1
    g = _np(aux["goal"]).reshape(-1, 2)[0]
    ax.plot(g[0], g[1], "s", color="orange", ms=9, mec="k", zorder=5, label="goal")
    if q0 is not None:
        q0 = _np(q0).reshape(-1, 2)
        ax.plot(q0[:, 0], q0[:, 1], "o", color="k", ms=4, zorder=5)
        if qd0 is not None:
            v = _np(qd0).reshape(-1, 2)
            ax.quiver(q0[:, 0], q0[:, 1], v[:, 0], v[:, 1], angles="xy", scale_units="xy", scale=1.0, color="k",
                      width=0.004, zorder=5)
    ax.set_aspect("equal")


def _trajectories(ax, q, style: str, colour: str, label: str | None) -> None:
    q = _np(q)  # (T, n, 2)
    for i in range(q.shape[1]):
        ax.plot(q[:, i, 0], q[:, i, 1], style, color=colour, lw=1.2, label=label if i == 0 else None)


def plot_trajectories(path, aux: Mapping[str, torch.Tensor], expert_q, learner_q: Mapping[str, object] | None = None,
                      q0=None, qd0=None, title: str = "", limits: Sequence[float] = (-5, 5)) -> Path:
    """Expert (dashed) and learners (solid) from the same initial states in one environment."""
    fig, ax = subplots(figsize=(5, 5))
    draw_environment(ax, aux, q0, qd0)
    if expert_q is not None:
        _trajectories(ax, expert_q, "--", "0.35", "expert")
    for (name, q), colour in zip((learner_q or {}).items(), ("tab:green", "tab:cyan", "tab:olive", "tab:pink")):
        _trajectories(ax, q, "-", colour, name)
    ax.set_xlim(*limits)
    ax.set_ylim(*limits)
    ax.legend(loc="upper left", fontsize=7)
    ax.set_title(title, fontsize=9)
    return save_figure(fig, path)


def plot_lyapunov(path, times, V, title: str = "") -> Path:
    """V_r(t) of every trajectory; Theorem 2 says each curve is non-increasing."""
    fig, ax = subplots(figsize=(5, 3.2))
    t, v = _np(times), _np(V)
    ax.plot(t, v, lw=1)
    ax.set_xlabel("t [s]")
    ax.set_ylabel("$V_r$")
    ax.set_title(title, fontsize=9)
    return save_figure(fig, path)


def plot_learning_curves(path, curves: Mapping[str, Mapping[str, Sequence]], snapshots: Mapping[str, Sequence[int]] | None = None,
                         smooth: int = 50) -> Path:
    """Train loss (smoothed), validation (dashed) and test batch-loss per learner on a log scale, snapshot
    iterations marked in red.

    ``curves[name] = {"train": [(it, loss)...], "val": [...], "test": [(it, loss)...]}`` ("val" optional).
    """
    fig, ax = subplots(figsize=(6, 3.6))
    for (name, c), colour in zip(curves.items(), colour_cycle()):
        tr = np.asarray(c.get("train") or [], dtype=float).reshape(-1, 2)
        if len(tr):
            k = max(1, min(smooth, len(tr) // 10 or 1))
            y = np.convolve(tr[:, 1], np.ones(k) / k, mode="valid")
            ax.plot(tr[k - 1:, 0], y, color=colour, alpha=0.6, lw=1, label=f"{name} train")
        va = np.asarray(c.get("val") or [], dtype=float).reshape(-1, 2)
        if len(va):
            ax.plot(va[:, 0], va[:, 1], "--", color=colour, lw=1.4, label=f"{name} validation")
        te = np.asarray(c.get("test") or [], dtype=float).reshape(-1, 2)
        if len(te):
            ax.plot(te[:, 0], te[:, 1], color=colour, lw=1.8, label=f"{name} test")
            for s in (snapshots or {}).get(name, []):
                j = np.argmin(np.abs(te[:, 0] - s))
                ax.plot(te[j, 0], te[j, 1], "o", color="red", ms=5, zorder=5)
    ax.set_yscale("log")
    ax.set_xlabel("iteration")
    ax.set_ylabel("MSE")
    ax.legend(fontsize=7)
    return save_figure(fig, path)


def plot_progression(path, aux: Mapping[str, torch.Tensor], expert_q, stages: Sequence[Mapping[str, object]],
                     q0=None, qd0=None, limits: Sequence[float] = (-5, 5)) -> Path:
    """One column per snapshot: trajectories (top) and, when the learner has one, V_r(t) (bottom).

    ``stages`` items: ``{"label": str, "q": (T, n, 2), "times": (T,), "V": (T, n) or None}``.
    """
    n = len(stages)
    has_v = any(s.get("V") is not None for s in stages)
    rows = 2 if has_v else 1
    fig, axes = subplots(rows, n, figsize=(3 * n, 3 * rows), squeeze=False)
    for j, s in enumerate(stages):
        ax = axes[0, j]
        draw_environment(ax, aux, q0, qd0)
        if expert_q is not None:
            _trajectories(ax, expert_q, "--", "0.35", None)
        _trajectories(ax, s["q"], "-", "tab:green", None)
        ax.set_xlim(*limits)
        ax.set_ylim(*limits)
        ax.set_title(str(s["label"]), fontsize=9)
        if has_v:
            axv = axes[1, j]
            if s.get("V") is not None:
                axv.plot(_np(s["times"]), _np(s["V"]), lw=1)
                axv.set_xlabel("t [s]")
            else:
                axv.axis("off")
    if has_v:
        axes[1, 0].set_ylabel("$V_r$")
    return save_figure(fig, path)


def plot_weights(path, times, expert: Mapping[str, Sequence], learned: Mapping[str, Mapping[str, Sequence]],
                 title: str = "") -> Path:
    """One panel per learned edge: the expert's weight (thick dashed black) and each learner snapshot's weight
    (coloured) at the same states along a test trajectory, on a log scale when the weights span a decade.

    ``expert[edge]`` and ``learned[label][edge]`` are (T,) values at ``times`` (T,).
    """
    edges = list(expert) or sorted({e for w in learned.values() for e in w})
    n = max(len(edges), 1)
    cols = min(n, 5)
    rows = (n + cols - 1) // cols
    fig, axes = subplots(rows, cols, figsize=(2.9 * cols, 2.4 * rows), squeeze=False, sharex=True)
    t = _np(times)
    colours = colour_cycle()
    for ax, e in zip(axes.flat, edges):
        span = []
        for (label, w), colour in zip(learned.items(), colours):
            if e in w:
                ax.plot(t, _np(w[e]), color=colour, lw=1.3, label=label)
                span.append(_np(w[e]))
        if e in expert:
            ax.plot(t, _np(expert[e]), "--", color="k", lw=2.0, label="expert", zorder=5)
            span.append(_np(expert[e]))
        values = np.concatenate(span) if span else np.ones(1)
        if values.min() > 0 and values.max() / values.min() > 50:  # e.g. Franka's 1-200 obstacle weights
            ax.set_yscale("log")
        ax.set_title(e, fontsize=8)
        ax.tick_params(labelsize=7)
    for ax in axes.flat[len(edges):]:
        ax.axis("off")
    for ax in axes[-1]:
        ax.set_xlabel("t [s]", fontsize=8)
    for ax in axes[:, 0]:
        ax.set_ylabel("weight $w$", fontsize=8)
    handles, labels = axes.flat[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", fontsize=7, ncol=min(len(labels), 6), frameon=False)
    fig.suptitle(title or "weights along a test trajectory: expert (dashed) vs learner", fontsize=9)
    fig.tight_layout(rect=(0, 0.1 if rows == 1 else 0.05, 1, 0.93))
    return save_figure(fig, path)
