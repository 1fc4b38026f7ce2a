"""Figures of the 2D experiments: trajectories (Fig. 3a,b,e), V_r(t) (3c), learning curves (3d) and the
progression grid over training snapshots (Fig. 4, 7, 8). Written atomically so a crashed run never leaves
a half-written PNG that looks like a result.

Every figure names what it shows (a title), its axes with their units, and every kind of mark in a legend, so it
reads without the code or the caller. Each ``plot_*`` saves what a ``_draw_*`` returns: the tests inspect that
``Figure`` without writing a file."""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Literal

import matplotlib
import numpy as np
import torch
from matplotlib.figure import Figure
from matplotlib.patches import Circle
from matplotlib.ticker import FuncFormatter, MaxNLocator

from ..files import atomic_path

_OBSTACLE_COLOURS = ("tab:red", "tab:blue", "tab:purple", "tab:brown")
_LEARNER_COLOURS = ("tab:green", "tab:cyan", "tab:olive", "tab:pink")

#: The 2D particle's length unit. docs/protocol.md §2 and ``envs/particle2d.py`` give the workspace ([−5, 5]²), the
#: start speeds and the 0.1 goal tolerance without a unit (only time is in seconds), so positions are in arbitrary
#: units and accelerations in a.u./s².
PLANE_UNIT = "a.u."

#: The expert is drawn over the learners, thin, black and dashed, and the learners wide and semi-transparent
#: beneath it: where a learner follows the expert exactly, the learner's colour still shows on both sides of the
#: expert's dashes instead of one line hiding the other.
EXPERT_STYLE = {"ls": "--", "lw": 1.3, "zorder": 4}
LEARNER_STYLE = {"ls": "-", "lw": 2.8, "alpha": 0.6, "zorder": 3, "solid_capstyle": "round"}

V_LABEL = "Lyapunov function $V_r$"
TIME_LABEL = "t (s)"
TITLE_SIZE = 10
LEGEND_SIZE = 8


def subplots(
    *grid, figsize: tuple[float, float], layout: Literal["constrained", "compressed", "tight"] | None = None, **kwargs
):
    """A figure and its axes, drawn off-screen: a ``Figure`` renders to a file without pyplot, so importing
    the plots never selects a matplotlib backend for the whole process (an interactive session keeps its own).
    ``layout="constrained"`` makes room for titles, labels and figure legends outside the axes."""
    fig = Figure(figsize=figsize, layout=layout)
    return fig, fig.subplots(*grid, **kwargs)


def _iterations(value: float, _position=None) -> str:
    """Tick labels of iteration axes: 20000 as 20k, so five ticks never run into each other."""
    return f"{value / 1000:g}k" if abs(value) >= 1000 else f"{value:g}"


def colour_cycle() -> list[str]:
    return matplotlib.rcParams["axes.prop_cycle"].by_key()["color"]


def save_figure(fig, path: str | os.PathLike, dpi: int = 110) -> Path:
    path = Path(path)
    with atomic_path(path, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=dpi, format="png", bbox_inches="tight")
    return path


def _np(x) -> np.ndarray:
    return x.detach().cpu().double().numpy() if isinstance(x, torch.Tensor) else np.asarray(x, dtype=float)


#: Legend entries of the scene (starts, goal, obstacles, ...) follow those of the policies' lines.
_SCENE_MARKS = ("obstacle", "goal", "start", "initial velocity", "within", "robot base")


def policies_first(handles: Sequence, labels: Sequence[str]) -> tuple[list, list[str]]:
    """Legend entries reordered: the expert, then the learners, then the marks of the scene, which are drawn
    first but matter last (the expert is drawn last, on top)."""
    pairs = sorted(zip(handles, labels), key=lambda hl: 2 if hl[1].startswith(_SCENE_MARKS) else int(hl[1] != "expert"))
    return [h for h, _ in pairs], [lab for _, lab in pairs]


def legend_outside(ax, **kwargs):
    """A legend right of the axes: it never covers the data, whatever the data's layout."""
    handles, labels = policies_first(*ax.get_legend_handles_labels())
    if not handles:
        return None
    return ax.legend(
        handles, labels, loc="upper left", bbox_to_anchor=(1.02, 1.0), borderaxespad=0.0, fontsize=LEGEND_SIZE, **kwargs
    )


def figure_legend(fig, handles: Sequence, labels: Sequence[str], ncol: int | None = None):
    """One legend below all panels of a grid (constrained layout): every kind of mark named once."""
    if not handles:
        return None
    handles, labels = policies_first(handles, labels)
    return fig.legend(
        handles,
        labels,
        loc="outside lower center",
        fontsize=LEGEND_SIZE,
        ncol=ncol or min(len(labels), 4),
        frameon=False,
    )


def unique_handles(*axes) -> tuple[list, list[str]]:
    """The legend entries of several axes, each label once, in the order first drawn."""
    handles, labels = [], []
    for ax in axes:
        for h, lab in zip(*ax.get_legend_handles_labels()):
            if lab not in labels:
                handles.append(h)
                labels.append(lab)
    return handles, labels


def shared_ylim(axes, values: Sequence[np.ndarray], pad: float = 0.05) -> None:
    """One y-range over the panels of a row, so their curves compare at a glance."""
    finite = [v[np.isfinite(v)] for v in (np.asarray(x, dtype=float).ravel() for x in values)]
    finite = [v for v in finite if v.size]
    if not finite:
        return
    lo, hi = min(float(v.min()) for v in finite), max(float(v.max()) for v in finite)
    span = hi - lo if hi > lo else max(abs(hi), 1.0)
    for ax in axes:
        ax.set_ylim(lo - pad * span, hi + pad * span)


def draw_environment(ax, aux: Mapping[str, torch.Tensor], q0=None, qd0=None) -> None:
    """Obstacles as filled circles, the goal as an orange square, starts as black dots with velocity arrows
    (an arrow spans the distance covered in 1 s at the initial velocity); each kind labelled for the legend."""
    k = 1
    while f"obstacle{k}_center" in aux:
        c = _np(aux[f"obstacle{k}_center"]).reshape(-1, 2)[0]
        r = float(_np(aux[f"obstacle{k}_radius"]).reshape(-1)[0])
        ax.add_patch(
            Circle(
                c,
                r,
                color=_OBSTACLE_COLOURS[(k - 1) % len(_OBSTACLE_COLOURS)],
                alpha=0.45,
                lw=0,
                label=f"obstacle {k}",
                zorder=1,
            )
        )
        k += 1
    g = _np(aux["goal"]).reshape(-1, 2)[0]
    ax.plot(g[0], g[1], "s", color="orange", ms=9, mec="k", zorder=5, label="goal")
    if q0 is not None:
        q0 = _np(q0).reshape(-1, 2)
        ax.plot(q0[:, 0], q0[:, 1], "o", color="k", ms=4, zorder=5, ls="none", label="start")
        if qd0 is not None:
            v = _np(qd0).reshape(-1, 2)
            ax.quiver(
                q0[:, 0],
                q0[:, 1],
                v[:, 0],
                v[:, 1],
                angles="xy",
                scale_units="xy",
                scale=1.0,
                color="k",
                width=0.004,
                zorder=5,
            )
            # a quiver has no legend mark of its own: an arrow-shaped stand-in names it
            ax.plot([], [], ls="none", marker=r"$\rightarrow$", ms=12, color="k", label="initial velocity (1 s)")
    ax.set_aspect("equal")


def _plane_axes(ax, limits: Sequence[float], unit: str) -> None:
    ax.set_xlim(*limits)
    ax.set_ylim(*limits)
    ax.set_xlabel(f"x ({unit})")
    ax.set_ylabel(f"y ({unit})")


def _trajectories(ax, q, style: Mapping, colour: str, label: str | None) -> list:
    q = _np(q)  # (T, n, 2)
    return [
        ax.plot(q[:, i, 0], q[:, i, 1], color=colour, label=label if i == 0 else None, **style)[0]
        for i in range(q.shape[1])
    ]


def _expert_and_learners(ax, expert_q, learner_q: Mapping[str, object]) -> None:
    """Learners first and beneath, the expert last and on top (``EXPERT_STYLE``)."""
    for (name, q), colour in zip(learner_q.items(), _LEARNER_COLOURS):
        _trajectories(ax, q, LEARNER_STYLE, colour, name)
    if expert_q is not None:
        _trajectories(ax, expert_q, EXPERT_STYLE, "k", "expert")


def _draw_trajectories(
    aux,
    expert_q,
    learner_q=None,
    q0=None,
    qd0=None,
    title: str = "",
    limits: Sequence[float] = (-5, 5),
    unit: str = PLANE_UNIT,
) -> Figure:
    fig, ax = subplots(figsize=(6.6, 4.6), layout="constrained")
    draw_environment(ax, aux, q0, qd0)
    _expert_and_learners(ax, expert_q, dict(learner_q or {}))
    _plane_axes(ax, limits, unit)
    legend_outside(ax)
    ax.set_title(title or "trajectories of the expert and the learners", fontsize=TITLE_SIZE)
    return fig


def plot_trajectories(
    path,
    aux: Mapping[str, torch.Tensor],
    expert_q,
    learner_q: Mapping[str, object] | None = None,
    q0=None,
    qd0=None,
    title: str = "",
    limits: Sequence[float] = (-5, 5),
    unit: str = PLANE_UNIT,
) -> Path:
    """Expert (black dashed, on top) and learners (wide, semi-transparent) from the same initial states in one
    environment; ``unit`` is the length unit of the plane."""
    return save_figure(_draw_trajectories(aux, expert_q, learner_q, q0, qd0, title, limits, unit), path)


#: Up to this many V_r(t) curves get a colour and a legend entry each; more are drawn in one colour.
MAX_NAMED_CURVES = 10


def _draw_lyapunov(times, V, title: str = "", labels: Sequence[str] | None = None) -> Figure:
    fig, ax = subplots(figsize=(6.2, 3.4), layout="constrained")
    t, v = _np(times), _np(V).reshape(len(_np(times)), -1)
    n = v.shape[1]
    if labels is None:
        labels = [f"trajectory {i}" for i in range(n)]
    if n <= MAX_NAMED_CURVES:
        for i in range(n):
            ax.plot(t, v[:, i], lw=1.2, label=labels[i])
    else:
        ax.plot(t, v, lw=0.8, color="tab:blue", alpha=0.6)
        ax.plot([], [], lw=0.8, color="tab:blue", label=f"each of the {n} trajectories")
    ax.set_xlabel(TIME_LABEL)
    ax.set_ylabel(V_LABEL)
    legend_outside(ax)
    ax.set_title(title or "$V_r(t)$ along each rollout (Theorem 2: non-increasing)", fontsize=TITLE_SIZE)
    return fig


def plot_lyapunov(path, times, V, title: str = "", labels: Sequence[str] | None = None) -> Path:
    """V_r(t) of every trajectory; Theorem 2 says each curve is non-increasing. ``labels`` name the curves
    (default "trajectory i", in the order of V's columns)."""
    return save_figure(_draw_lyapunov(times, V, title, labels), path)


def _loss_label(unit: str | None) -> str:
    return f"MSE of q̈ (({unit})²)" if unit else "MSE of q̈ ((unit of q̈)²)"


def _snapshot_marks(ax, line: np.ndarray, snapshots: Sequence[int], marked: bool) -> bool:
    """Red dots on ``line`` (iteration, value) at the snapshots' own iterations, even between two evaluations
    (straight segments of a log axis: interpolate the logarithm); returns whether the legend has its entry."""
    for s in snapshots:
        y = np.exp(np.interp(s, line[:, 0], np.log(np.maximum(line[:, 1], 1e-300))))
        ax.plot(s, y, "o", color="red", ms=5, zorder=5, label=None if marked else "evaluated snapshot")
        marked = True
    return marked


def _draw_learning_curves(
    curves, snapshots=None, smooth: int = 50, title: str = "", unit: str | None = None, measure: str = "loss"
) -> Figure:
    fig, ax = subplots(figsize=(7.6, 3.8), layout="constrained")
    marked = False
    step = "train minibatch" if measure == "loss" else "training rollouts"
    for (name, c), colour in zip(curves.items(), colour_cycle()):
        tr = np.asarray(c.get("train") or [], dtype=float).reshape(-1, 2)
        if len(tr):
            k = max(1, min(smooth, len(tr) // 10 or 1))
            y = np.convolve(tr[:, 1], np.ones(k) / k, mode="valid")
            mean = f", mean of {k} iterations" if k > 1 else ""
            ax.plot(tr[k - 1 :, 0], y, color=colour, alpha=0.6, lw=1, label=f"{name}: {step}{mean}")
        va = np.asarray(c.get("val") or [], dtype=float).reshape(-1, 2)
        if len(va):
            ax.plot(va[:, 0], va[:, 1], "--", color=colour, lw=1.4, label=f"{name}: validation set")
        te = np.asarray(c.get("test") or [], dtype=float).reshape(-1, 2)
        if len(te):
            ax.plot(te[:, 0], te[:, 1], color=colour, lw=1.8, label=f"{name}: test set (batch-loss)")
        marks = te if len(te) else va  # cost curves have no test line: mark the validation one
        if len(marks):
            marked = _snapshot_marks(ax, marks, (snapshots or {}).get(name, []), marked)
    ax.set_yscale("log")
    ax.set_xlabel("training iteration")
    ax.xaxis.set_major_locator(MaxNLocator(nbins=5, integer=True))  # long runs: 20000 needs room for its digits
    ax.xaxis.set_major_formatter(FuncFormatter(_iterations))
    ax.set_ylabel(_loss_label(unit) if measure == "loss" else "task cost per rollout")
    legend_outside(ax)
    default = (
        "learning curves: loss against the expert's accelerations"
        if measure == "loss"
        else "learning curves: task cost of the rollouts"
    )
    ax.set_title(title or default, fontsize=TITLE_SIZE)
    return fig


def plot_learning_curves(
    path,
    curves: Mapping[str, Mapping[str, Sequence]],
    snapshots: Mapping[str, Sequence[int]] | None = None,
    smooth: int = 50,
    title: str = "",
    unit: str | None = None,
    measure: str = "loss",
) -> Path:
    """Train loss (smoothed), validation (dashed) and test batch-loss per learner on a log scale, snapshot
    iterations marked in red. ``unit`` is the unit of q̈ (the loss is in its square). ``measure="cost"``: the
    curves hold a task cost (policy optimisation without an expert): the training rollouts' and the validation
    starts'.

    ``curves[name] = {"train": [(it, loss)...], "val": [...], "test": [(it, loss)...]}`` ("val" optional).
    """
    return save_figure(_draw_learning_curves(curves, snapshots, smooth, title, unit, measure), path)


def _draw_progression(
    aux, expert_q, stages, q0=None, qd0=None, limits: Sequence[float] = (-5, 5), title: str = "", unit: str = PLANE_UNIT
) -> Figure:
    n = len(stages)
    has_v = any(s.get("V") is not None for s in stages)
    rows = 2 if has_v else 1
    fig, axes = subplots(rows, n, figsize=(3.1 * n + 0.4, 3.1 * rows + 0.9), squeeze=False, layout="constrained")
    v_axes, v_values = [], []
    for j, s in enumerate(stages):
        ax = axes[0, j]
        draw_environment(ax, aux, q0, qd0)
        _trajectories(ax, s["q"], LEARNER_STYLE, _LEARNER_COLOURS[0], "learner")
        if expert_q is not None:
            _trajectories(ax, expert_q, EXPERT_STYLE, "k", "expert")
        _plane_axes(ax, limits, unit)
        ax.set_title(str(s["label"]), fontsize=TITLE_SIZE - 1)
        if has_v:
            axv = axes[1, j]
            if s.get("V") is not None:
                V = _np(s["V"])
                axv.plot(_np(s["times"]), V, lw=1.1, color=_LEARNER_COLOURS[0])
                axv.plot([], [], lw=1.1, color=_LEARNER_COLOURS[0], label="learner's $V_r(t)$, one line per start")
                axv.set_xlabel(TIME_LABEL)
                axv.set_ylabel(V_LABEL)
                v_axes.append(axv)
                v_values.append(V)
            else:
                axv.axis("off")
    shared_ylim(v_axes, v_values)
    figure_legend(fig, *unique_handles(*axes.flat))
    fig.suptitle(
        title or "the learner vs the expert at each training snapshot (columns: learner @ iteration)",
        fontsize=TITLE_SIZE,
    )
    return fig


def plot_progression(
    path,
    aux: Mapping[str, torch.Tensor],
    expert_q,
    stages: Sequence[Mapping[str, object]],
    q0=None,
    qd0=None,
    limits: Sequence[float] = (-5, 5),
    title: str = "",
    unit: str = PLANE_UNIT,
) -> Path:
    """One column per snapshot: trajectories (top) and, when the learner has one, V_r(t) (bottom), the V_r
    panels on one y-scale so the snapshots compare at a glance.

    ``stages`` items: ``{"label": str, "q": (T, n, 2), "times": (T,), "V": (T, n) or None}``.
    """
    return save_figure(_draw_progression(aux, expert_q, stages, q0, qd0, limits, title, unit), path)


def _draw_weights(times, expert, learned, title: str = "") -> Figure:
    edges = list(expert) or sorted({e for w in learned.values() for e in w})
    n = max(len(edges), 1)
    cols = min(n, 5)
    rows = (n + cols - 1) // cols
    fig, axes = subplots(
        rows, cols, figsize=(3.0 * cols, 2.5 * rows + 0.8), squeeze=False, sharex=True, layout="constrained"
    )
    t = _np(times)
    colours = colour_cycle()
    for ax, e in zip(axes.flat, edges):
        span = []
        for (label, w), colour in zip(learned.items(), colours):
            if e in w:
                ax.plot(t, _np(w[e]), color=colour, lw=1.3, label=label, zorder=3)
                span.append(_np(w[e]))
        if e in expert:
            ax.plot(t, _np(expert[e]), "--", color="k", lw=2.0, label="expert", zorder=5)
            span.append(_np(expert[e]))
        values = np.concatenate(span) if span else np.ones(1)
        if values.min() > 0 and values.max() / values.min() > 50:  # e.g. Franka's 1-200 obstacle weights
            ax.set_yscale("log")
        ax.set_title(f"edge into '{e}'", fontsize=TITLE_SIZE - 1)
        ax.tick_params(labelsize=7)
        ax.set_xlabel(TIME_LABEL, fontsize=8)
        ax.set_ylabel("weight $w$", fontsize=8)
        ax.xaxis.set_tick_params(labelbottom=True)
    for ax in axes.flat[len(edges) :]:
        ax.axis("off")
    handles, labels = unique_handles(*axes.flat)
    figure_legend(fig, handles, labels, ncol=min(len(labels), 6))
    fig.suptitle(title or "weights along a test trajectory: expert (dashed) vs learner", fontsize=TITLE_SIZE)
    return fig


def plot_weights(
    path, times, expert: Mapping[str, torch.Tensor], learned: Mapping[str, Mapping[str, torch.Tensor]], title: str = ""
) -> Path:
    """One panel per learned edge: the expert's weight (thick dashed black, on top) and each learner snapshot's
    weight (coloured) at the same states along a test trajectory, on a log scale when the weights span a decade.

    ``expert[edge]`` and ``learned[label][edge]`` are (T,) values at ``times`` (T,).
    """
    return save_figure(_draw_weights(times, expert, learned, title), path)
