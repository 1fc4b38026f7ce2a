"""Figures of the manipulator experiments (paper §4.2, Fig. 5b and Fig. 6): the learner/expert ratio chart, V_r(t) per
policy, a render strip and an animated GIF of one test execution (pybullet's headless renderer), and the
end-effector paths seen from above. Written atomically, like every figure of the project; each ``plot_*`` saves what
a ``_draw_*`` returns, so the tests inspect the ``Figure`` without writing a file."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypedDict

import numpy as np
import torch
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Circle, Patch, Rectangle

from ..envs.protocol import Renders
from ..files import atomic_path
from .figures import (
    LEGEND_SIZE,
    TIME_LABEL,
    TITLE_SIZE,
    V_LABEL,
    _np,
    figure_legend,
    legend_outside,
    save_figure,
    shared_ylim,
    subplots,
    unique_handles,
)

METRIC_LABELS = {
    "time": "time",
    "cspace_length": "conf length",
    "ee_length": "end eff length",
    "goal_distance": "goal distance",
    "timeout_goal_distance": "goal distance\nat time-out",
    "min_goal_distance": "closest\ngoal distance",
}
_STAGE_COLOURS = ("tab:red", "tab:orange", "tab:green", "tab:blue", "tab:purple", "tab:brown", "tab:pink")


def _draw_ratio_bars(ratios, metrics=None, title: str = "") -> Figure:
    labels = list(ratios)
    metrics = list(metrics or (next(iter(ratios.values())).keys() if ratios else []))
    fig, ax = subplots(figsize=(3.4 + 1.5 * len(metrics), 3.6), layout="constrained")
    n = max(len(labels), 1)
    width = 0.8 / n
    x = np.arange(len(metrics))
    for i, lab in enumerate(labels):
        means = [ratios[lab].get(m, {}).get("mean", np.nan) for m in metrics]
        stds = [ratios[lab].get(m, {}).get("std", np.nan) for m in metrics]
        mean = np.array([np.nan if v is None else v for v in means], dtype=float)
        std = np.array([np.nan if v is None else v for v in stds], dtype=float)
        ax.bar(
            x + (i - (n - 1) / 2) * width,
            mean,
            width * 0.9,
            yerr=std,
            capsize=3,
            label=lab,
            color=_STAGE_COLOURS[(i + 1) % len(_STAGE_COLOURS)],
            alpha=0.85,
            error_kw={"lw": 1},
        )
    ax.axhline(1.0, color="k", ls=":", lw=1.2, label="expert (ratio 1)")
    ax.errorbar([], [], yerr=[], fmt="none", ecolor="k", capsize=3, lw=1, label="± std over trajectories")
    tops = [ratios[lab].get(m, {}).get("mean") for lab in labels for m in metrics]
    if any(t is not None and np.isfinite(t) and t > 10 for t in tops):  # e.g. an untrained learner's goal distance
        ax.set_yscale("log")
    ax.set_xticks(x)
    ax.set_xticklabels([METRIC_LABELS.get(m, m) for m in metrics])
    ax.set_xlabel("metric of a test execution")
    ax.set_ylabel("learner / expert (ratio)")
    ax.set_title(title or "learner / expert per test trajectory (mean ± std)", fontsize=TITLE_SIZE)
    legend_outside(ax)
    return fig


def plot_ratio_bars(
    path, ratios: Mapping[str, Mapping[str, Mapping[str, float]]], metrics: Sequence[str] | None = None, title: str = ""
) -> Path:
    """Paper Fig. 5b: per metric, one bar per policy = mean of the per-trajectory ratios learner/expert, error bar
    = their standard deviation; the expert is the dotted line at 1. ``ratios[label][metric] = {mean, std}``."""
    return save_figure(_draw_ratio_bars(ratios, metrics, title), path)


#: The paper's Fig. 5b ratios. The goal distances are drawn in metres instead (``plot_goal_distances``): a policy
#: at rest at the goal is a fraction of a millimetre from it, where a ratio of two such distances is noise.
PATH_RATIOS = ("time", "cspace_length", "ee_length")


def _draw_goal_distances(policies: Sequence[Any], title: str = "") -> Figure:
    keys = (("timeout_goal_distance", "at the 10 s time-out"), ("min_goal_distance", "closest approach"))
    fig, ax = subplots(figsize=(3.6 + 1.1 * len(policies), 3.6), layout="constrained")
    width = 0.8 / len(keys)
    x = np.arange(len(policies))
    for j, (key, label) in enumerate(keys):
        mean = np.array([p.summary.get(key, {}).get("mean", np.nan) for p in policies], dtype=float)
        std = np.array([p.summary.get(key, {}).get("std", np.nan) for p in policies], dtype=float)
        lower = np.minimum(std, mean * 0.999)  # a log axis cannot show mean − std ≤ 0
        ax.bar(
            x + (j - 0.5) * width,
            mean,
            width * 0.9,
            yerr=[lower, std],
            capsize=3,
            label=label,
            color=("tab:blue", "tab:orange")[j],
            alpha=0.85,
            error_kw={"lw": 1},
        )
    ax.axhline(0.05, color="k", ls=":", lw=1.2, label="0.05 m: goal reached")
    ax.errorbar([], [], yerr=[], fmt="none", ecolor="k", capsize=3, lw=1, label="± std over trajectories")
    ax.set_yscale("log")
    ax.set_xticks(x)
    ax.set_xticklabels([p.label for p in policies], fontsize=8)
    ax.set_xlabel("policy")
    ax.set_ylabel("end effector to goal (m)")
    ax.set_title(title or "end effector's distance to the goal on the test set", fontsize=TITLE_SIZE)
    legend_outside(ax)
    return fig


def plot_goal_distances(path, policies: Sequence[Any], title: str = "") -> Path:
    """Per policy (``StageResult``s, the expert first), the end effector's distance to the goal at the 10 s time-out
    and the closest it came, mean ± std over the test trajectories, on a log scale, with the 0.05 m precision
    at which an execution counts as reached."""
    return save_figure(_draw_goal_distances(policies, title), path)


def _draw_lyapunov_stages(panels: Sequence[Mapping[str, Any]], title: str = "") -> Figure:
    n = len(panels)
    fig, axes = subplots(1, n, figsize=(2.9 * n + 0.3, 3.4), squeeze=False, layout="constrained")
    values = []
    for ax, p in zip(axes[0], panels):
        t, V = _np(p["times"]), _np(p["V"])
        V = V.reshape(len(t), -1)
        ax.plot(t, V, lw=0.6, color="0.6")
        ax.plot([], [], lw=0.6, color="0.6", label="each test trajectory")
        h = p.get("highlight")
        if h is not None:
            ax.plot(t, V[:, h], lw=1.8, color="tab:blue", label=f"rendered execution (trajectory {h})")
        values.append(V)
        ax.set_title(str(p["label"]), fontsize=TITLE_SIZE - 1)
        ax.set_xlabel(TIME_LABEL)
        ax.set_ylabel(V_LABEL)
    shared_ylim(axes[0], values)
    figure_legend(fig, *unique_handles(*axes.flat))
    fig.suptitle(title or "$V_r(t)$ per policy on the test set (Theorem 2: non-increasing)", fontsize=TITLE_SIZE)
    return fig


def plot_lyapunov_stages(path, panels: Sequence[Mapping[str, Any]], title: str = "") -> Path:
    """Paper Fig. 6e: one panel per policy with V_r(t) of every test trajectory (thin) and of the rendered
    example (thick), on one y-scale so the policies compare at a glance. ``panels`` items: ``{"label", "times"
    (T,), "V" (T, B), "highlight": int}``."""
    return save_figure(_draw_lyapunov_stages(panels, title), path)


#: The marks drawn over a render: the end-effector path so far and the goal (strip and GIF alike).
TRAIL_LABEL = "end-effector path so far"
GOAL_LABEL = "goal"
OBSTACLE_LABEL = "obstacles (red)"


def _draw_render_strip(rows: Sequence[Mapping[str, Any]], title: str = "") -> Figure:
    n_rows = len(rows)
    n_cols = max(len(r["frames"]) for r in rows) if rows else 1
    h, w = rows[0]["frames"][0]["image"].shape[:2]
    fig, axes = subplots(n_rows, n_cols, figsize=(1.9 * n_cols * w / h, 1.9 * n_rows), squeeze=False)
    for i, r in enumerate(rows):
        for j in range(n_cols):
            ax = axes[i, j]
            ax.set_xticks([])
            ax.set_yticks([])
            if j >= len(r["frames"]):
                ax.axis("off")
                continue
            f = r["frames"][j]
            ax.imshow(f["image"])
            tr = f.get("trail")
            if tr is not None and len(tr) > 1:
                ax.plot(tr[:, 0], tr[:, 1], "-", color="yellow", lw=1.2)
            g = f.get("goal")
            if g is not None:
                ax.plot(g[0], g[1], "*", color="orange", mec="k", ms=9)
            ax.set_xlim(0, w)
            ax.set_ylim(h, 0)
            if i == 0:
                ax.set_title(f"t = {f['t']:.1f} s", fontsize=9)
            if j == 0:
                ax.set_ylabel(str(r["label"]), fontsize=9)
    handles = [
        Line2D([], [], color="yellow", lw=1.5),
        Line2D([], [], ls="none", marker="*", color="orange", mec="k", ms=9),
        Patch(color="tab:red", alpha=0.8),
    ]
    fig.subplots_adjust(wspace=0.02, hspace=0.04)
    # just below the images (the saved figure's tight bounding box takes it in), never over a render
    fig.legend(
        handles,
        [TRAIL_LABEL, GOAL_LABEL, OBSTACLE_LABEL],
        loc="upper center",
        ncol=3,
        fontsize=LEGEND_SIZE,
        frameon=False,
        bbox_to_anchor=(0.5, 0.105),
    )
    fig.suptitle(title or "one test execution per policy (rows), left to right in time", fontsize=TITLE_SIZE)
    return fig


def plot_render_strip(path, rows: Sequence[Mapping[str, Any]], title: str = "") -> Path:
    """Paper Fig. 6a-d: one row per policy, one column per time, each a pybullet render with the end-effector
    path so far (line) and the goal (star). ``rows`` items: ``{"label", "frames": [{"t", "image", "trail" (N, 2)
    pixels, "goal" (2,) pixels}]}``."""
    return save_figure(_draw_render_strip(rows, title), path)


def _draw_ee_paths(aux: Mapping[str, torch.Tensor], paths: Mapping[str, Any], title: str = "") -> Figure:
    fig, ax = subplots(figsize=(6.8, 4.6), layout="constrained")
    k = 1
    while f"obstacle{k}_center" in aux:
        ax.add_patch(_footprint(aux, k, label="obstacles (top view)" if k == 1 else None))
        k += 1
    g = _np(aux["goal"]).reshape(-1)
    ax.add_patch(
        Circle((g[0], g[1]), 0.05, fill=False, ls="--", color="orange", zorder=2, label="within 0.05 m of the goal")
    )
    # learners first and beneath (wide, semi-transparent), the expert last and on top (thin, black, dashed): where
    # a learner retraces the expert's path both stay visible
    learners = [lab for lab in paths if lab != "expert"]
    order = learners + [lab for lab in paths if lab == "expert"]
    # the colours of the ratio chart's bars (_STAGE_COLOURS from index 1), so a policy has one colour throughout
    colours = {lab: _STAGE_COLOURS[(i + 1) % len(_STAGE_COLOURS)] for i, lab in enumerate(learners)}
    started = False
    for lab in order:
        p = _np(paths[lab]).reshape(-1, 3)
        p = p[np.isfinite(p).all(1)]
        if lab == "expert":
            ax.plot(p[:, 0], p[:, 1], "--", color="k", lw=1.3, zorder=4, label=lab)
        else:
            ax.plot(
                p[:, 0],
                p[:, 1],
                "-",
                color=colours[lab],
                lw=2.6,
                alpha=0.6,
                zorder=3,
                solid_capstyle="round",
                label=lab,
            )
        if len(p):
            ax.plot(p[0, 0], p[0, 1], "o", color="k", ms=4, zorder=5, label=None if started else "start")
            started = True
    ax.plot(g[0], g[1], "*", color="orange", mec="k", ms=12, zorder=5, label="goal")
    ax.plot(0, 0, "s", color="0.3", ms=8, label="robot base")
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    legend_outside(ax)
    ax.set_title(title or "end-effector paths of one test execution (top view)", fontsize=TITLE_SIZE)
    return fig


class _FootprintStyle(TypedDict):
    """How every obstacle's footprint is drawn; named keys, so they are never taken for Rectangle's own angle or
    rotation point."""

    color: str
    alpha: float
    lw: float
    zorder: int
    label: str | None


def _footprint(aux: Mapping[str, torch.Tensor], k: int, label: str | None) -> Patch:
    """Obstacle k seen from above: a box as the rectangle its corners span in x-y, a capsule or a tilted cylinder
    as the disc of its radius around its centre, a sphere or a standing cylinder as its disc."""
    c = _np(aux[f"obstacle{k}_center"]).reshape(-1)
    style = _FootprintStyle(color="tab:red", alpha=0.5, lw=0, zorder=1, label=label)
    if f"obstacle{k}_half_extents" in aux:
        e = _np(aux[f"obstacle{k}_half_extents"]).reshape(3)
        R = _np(aux[f"obstacle{k}_rotation"]).reshape(3, 3)
        corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * e @ R.T
        lo, hi = corners[:, :2].min(0), corners[:, :2].max(0)
        (x0, y0), (w, h) = c[:2] + lo, hi - lo
        return Rectangle((x0, y0), w, h, **style)
    return Circle((c[0], c[1]), float(_np(aux[f"obstacle{k}_radius"]).reshape(-1)[0]), **style)


def plot_ee_paths(path, aux: Mapping[str, torch.Tensor], paths: Mapping[str, Any], title: str = "") -> Path:
    """End-effector paths of one test execution seen from above (x-y), obstacles as discs, goal as a star, the
    expert's path (key "expert") drawn over the learners'."""
    return save_figure(_draw_ee_paths(aux, paths, title), path)


def _font(size: int):
    from PIL import ImageFont

    try:
        return ImageFont.load_default(size=size)  # scalable where pillow has FreeType
    except TypeError:  # older pillow: the fixed bitmap font
        return ImageFont.load_default()


def _label(img: np.ndarray, text: str, size: int = 12) -> np.ndarray:
    """``img`` under a white strip holding ``text`` on one line: the label never covers the render, however small
    the frame, and every tile of every frame has the same height."""
    return np.concatenate([_caption(img.shape[1], [text], size, wrap=False), img], axis=0)


def _wrap(draw, text: str, font, width: int) -> list[str]:
    """``text`` broken between words into lines no wider than ``width`` pixels (a longer word keeps its line)."""
    out: list[str] = []
    for word in text.split(" "):
        joined = f"{out[-1]} {word}" if out else word
        if out and draw.textlength(joined, font=font) <= width:
            out[-1] = joined
        else:
            out.append(word)
    return out


def _caption(width: int, lines: Sequence[str], size: int = 12, wrap: bool = True) -> np.ndarray:
    """A white strip of ``width`` pixels holding ``lines`` of text, one under the other (a line too wide is
    broken between words): a GIF's title, key and frame labels."""
    from PIL import Image, ImageDraw

    font = _font(size)
    probe = ImageDraw.Draw(Image.new("RGB", (1, 1)))
    if wrap:
        lines = [part for line in lines for part in _wrap(probe, line, font, width - 12)]
    height = int(probe.textbbox((0, 0), "Ag|", font=font)[3])  # one height for any text: every GIF frame the same size
    im = Image.new("RGB", (width, (height + 4) * len(lines) + 4), (255, 255, 255))
    d = ImageDraw.Draw(im)
    for i, line in enumerate(lines):
        d.text((6, 4 + i * (height + 4)), line, fill=(0, 0, 0), font=font)
    return np.asarray(im)


def save_gif(path, frames: Sequence[np.ndarray], fps: float = 10.0) -> Path:
    """An animated GIF (pillow) of (H, W, 3) uint8 frames, looping."""
    from PIL import Image

    path = Path(path)
    if not frames:
        raise ValueError("save_gif: no frames")
    ims = [Image.fromarray(f) for f in frames]
    with atomic_path(path, suffix=".gif") as tmp:
        ims[0].save(tmp, format="GIF", save_all=True, append_images=ims[1:], duration=round(1000 / fps), loop=0)
    return path


# ---------------------------------------------------------------------------------------------- the whole set
def _example(env: Renders, expert) -> int:
    """The rendered test trajectory: the configured one, else the one where the expert comes closest to the
    obstacle among those it completes (the most interaction)."""
    chosen = env.render_settings.trajectory
    B = expert.rollout.q.shape[1]
    if chosen is not None:
        return min(int(chosen), B - 1)
    clear = expert.per_trajectory["min_clearance"].clone().double()
    ok = expert.per_trajectory["reached"].bool() & ~expert.per_trajectory["collided"].bool()
    clear[~ok] = float("inf")
    return int(clear.argmin()) if bool(ok.any()) else 0


def _index_at(times: torch.Tensor, t: float) -> int:
    return int((times - t).abs().argmin())


def manipulator_figures(
    env: Renders, fig_dir, expert, stages, aux: Mapping[str, torch.Tensor], title: str = "manipulator"
) -> list[Path]:
    """All the figures of a manipulator experiment; see the module docstring. ``expert``/``stages``: ``StageResult``s."""
    fig_dir = Path(fig_dir)
    b = _example(env, expert)
    policies = [expert, *stages]
    ex_aux = {k: v[b : b + 1] for k, v in aux.items()}
    out = _test_set_figures(fig_dir, expert, stages, b, title)
    out.append(
        plot_ee_paths(
            fig_dir / "task_ee_paths.png",
            ex_aux,
            {st.label: st.rollout.ee[:, b] for st in policies},
            title=f"{title}: end-effector paths, test execution {b} (top view)",
        )
    )
    execution = _Execution(env, policies, b, ex_aux, float(expert.rollout.times[-1]))
    out.append(_execution_strip(execution, fig_dir / "task_execution.png", title))
    out.append(_execution_gif(execution, fig_dir / "task_execution.gif", title))
    return out


def _test_set_figures(fig_dir: Path, expert, stages, b: int, title: str) -> list[Path]:
    """The figures over the whole test set: learner/expert ratios (when there are any), goal distances, and V_r(t)
    of every tree policy with the rendered execution ``b`` drawn thick."""
    out: list[Path] = []
    ratios = {st.label: st.ratios for st in stages if st.ratios}
    if ratios:
        out.append(
            plot_ratio_bars(
                fig_dir / "task_ratios.png",
                ratios,
                PATH_RATIOS,
                title=f"{title}: learner / expert on the test set (mean ± std over trajectories)",
            )
        )
    out.append(
        plot_goal_distances(
            fig_dir / "task_goal_distances.png",
            [expert, *stages],
            title=f"{title}: goal distance on the test set (mean ± std over trajectories)",
        )
    )
    panels = [
        {"label": st.label, "times": st.rollout.times, "V": st.rollout.V, "highlight": b}
        for st in [expert, *stages]
        if st.rollout.V is not None
    ]
    if panels:
        out.append(
            plot_lyapunov_stages(
                fig_dir / "task_lyapunov.png",
                panels,
                title=f"{title}: $V_r(t)$ on the test set (thick: the rendered execution {b})",
            )
        )
    return out


@dataclass
class _Execution:
    """The rendered test execution ``b`` of every policy: what the strip and the animation draw."""

    env: Renders
    policies: list
    b: int
    aux: dict[str, torch.Tensor]  # the execution's own aux state (batch of one)
    horizon: float  # s: the expert's rollout's length

    def goal_pixel(self, width: int, height: int):
        return self.env.project(self.aux["goal"].reshape(1, 3).cpu().numpy(), width, height)[0]

    def frame(self, st, t: float, width: int, height: int, goal) -> dict:
        """Policy ``st`` at the record nearest ``t`` (its last valid state where its rollout ended early): the
        render, the end effector's trail so far in pixels, and the goal's pixel."""
        ro, b = st.rollout, self.b
        i = _index_at(ro.times, t)
        q = ro.q[i, b]
        if not bool(q.isfinite().all()):  # the rollout ended early: show its last valid state
            ok = ro.q[:, b].isfinite().all(-1).nonzero().flatten()
            i = int(ok.max()) if len(ok) else 0
            q = ro.q[i, b].nan_to_num()
        ee = ro.ee[: i + 1, b]
        ee = ee[ee.isfinite().all(-1)].cpu().numpy()
        return {
            "t": float(ro.times[i]),
            "image": self.env.render(q, self.aux, width=width, height=height, sample=0),
            "trail": self.env.project(ee, width, height) if len(ee) else None,
            "goal": goal,
        }


def _execution_strip(execution: _Execution, path: Path, title: str) -> Path:
    """The execution at the configured times, one row per policy, left to right in time."""
    settings = execution.env.render_settings
    w, h = settings.size
    goal_px = execution.goal_pixel(w, h)
    times = [t for t in settings.times if t <= execution.horizon + 1e-9] or [0.0]
    rows = [
        {"label": st.label, "frames": [execution.frame(st, t, w, h, goal_px) for t in times]}
        for st in execution.policies
    ]
    return plot_render_strip(path, rows, title=f"{title}: test execution {execution.b}, left to right in time")


def _execution_gif(execution: _Execution, path: Path, title: str) -> Path:
    """The animation: the policies side by side, in real time, each tile with its trail, the goal and its time."""
    settings = execution.env.render_settings
    w, h = settings.size
    gw, gh = (w * 3) // 4, (h * 3) // 4
    goal_g = execution.goal_pixel(gw, gh)
    n_frames = int(np.floor(execution.horizon * settings.gif_fps + 1e-9)) + 1
    caption = _caption(
        gw * len(execution.policies),
        [
            f"{title}: test execution {execution.b}, policies side by side, real time",
            f"yellow line: {TRAIL_LABEL}; orange ring: {GOAL_LABEL}; red: obstacles",
        ],
    )
    frames = []
    for k in range(n_frames):
        t = k / settings.gif_fps
        tiles = []
        for st in execution.policies:
            f = execution.frame(st, t, gw, gh, goal_g)
            tiles.append(_label(_draw_trail(f["image"], f["trail"], goal_g), f"{st.label}, t = {f['t']:.1f} s"))
        frames.append(np.concatenate([caption, np.concatenate(tiles, axis=1)], axis=0))
    return save_gif(path, frames, settings.gif_fps)


def _draw_trail(img: np.ndarray, trail, goal) -> np.ndarray:
    from PIL import Image, ImageDraw

    im = Image.fromarray(img)
    d = ImageDraw.Draw(im)
    if trail is not None and len(trail) > 1:
        d.line([tuple(map(float, p)) for p in trail], fill=(230, 200, 0), width=2)
    if goal is not None:
        x, y = float(goal[0]), float(goal[1])
        d.ellipse([x - 4, y - 4, x + 4, y + 4], outline=(255, 140, 0), width=2)
    return np.asarray(im)


__all__ = [
    "manipulator_figures",
    "plot_ee_paths",
    "plot_goal_distances",
    "plot_lyapunov_stages",
    "plot_ratio_bars",
    "plot_render_strip",
    "save_gif",
]
