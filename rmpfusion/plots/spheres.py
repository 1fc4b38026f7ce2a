"""The coverage figure of a robot's control spheres: per link, the checked surface samples seen along the link's
two widest directions, covered ones grey, uncovered ones red, the spheres as circles."""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Circle

from ..robots.spheres import LinkFit, summary
from .figures import TITLE_SIZE, figure_legend, save_figure, subplots


def _draw_coverage(fits: Sequence[LinkFit], title: str = "") -> Figure:
    n = max(len(fits), 1)
    cols = min(4, n)
    rows = math.ceil(n / cols)
    fig, axes = subplots(rows, cols, figsize=(3.1 * cols, 3.1 * rows + 0.6), squeeze=False, layout="constrained")
    for ax in axes.flat[len(fits) :]:
        ax.axis("off")
    for ax, f in zip(axes.flat, fits):
        mean = f.points.mean(0)
        _, _, vt = np.linalg.svd(f.points - mean, full_matrices=False)  # the link's widest directions
        uv = (f.points - mean) @ vt[:2].T
        ax.scatter(*uv[f.covered].T, s=1, color="0.6", rasterized=True)
        ax.scatter(*uv[~f.covered].T, s=4, color="tab:red", rasterized=True)
        for c, r in zip((f.centers - mean) @ vt[:2].T, f.radii):
            ax.add_patch(Circle(c, r, fill=False, color="tab:blue", lw=1))
        ax.set_aspect("equal")
        ax.autoscale_view()
        over = f"{1000 * f.overshoot.max():.0f}" if len(f.overshoot) else "–"
        ax.set_title(
            f"{f.link}: {100 * f.coverage:.2f} % covered\n{len(f.radii)} spheres, overshoot ≤ {over} mm", fontsize=9
        )
        ax.set_xlabel("widest direction (m)", fontsize=8)
        ax.set_ylabel("second widest (m)", fontsize=8)
    handles = [
        Line2D([], [], ls="none", marker="o", color="0.6", ms=3),
        Line2D([], [], ls="none", marker="o", color="tab:red", ms=3),
        Line2D([], [], color="tab:blue", lw=1),
    ]
    figure_legend(
        fig,
        handles,
        ["surface sample inside a sphere", "surface sample outside every sphere", "control sphere (projected)"],
    )
    s = summary(list(fits))
    fig.suptitle(
        title
        or f"control-sphere coverage: {100 * s['coverage']:.2f} % of the collision surface, {s['spheres']} spheres",
        fontsize=TITLE_SIZE,
    )
    return fig


def plot_coverage(path, fits: Sequence[LinkFit], title: str = "") -> Path:
    """Per link, the independent surface samples (covered grey, uncovered red) and the spheres, projected on the
    link's two widest directions; titles give each link's coverage and largest overshoot."""
    return save_figure(_draw_coverage(fits, title), path)
