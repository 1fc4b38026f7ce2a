"""Every figure reads on its own: a title, axis labels with units, a legend naming every kind of mark, the
expert's line drawn over the learner's, which test environment a panel shows, and one V_r scale across the panels
of a grid. Drawn on small synthetic data; the ``_draw_*`` helpers return the Figure without saving it."""

from __future__ import annotations

import re
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from rmpfusion.plots import figures as F
from rmpfusion.plots import manipulator as FR

UNIT = re.compile(r"\(.+\)")
T, N = 21, 3


# ------------------------------------------------------------------------------------------------- helpers
def title_of(fig) -> str:
    """The figure's suptitle and its axes' titles, joined."""
    return " | ".join([fig.get_suptitle()] + [ax.get_title() for ax in fig.axes]).strip(" |")


def legend_texts(fig) -> list[str]:
    """Every entry of every legend of the figure (axes legends and figure legends)."""
    legends = [ax.get_legend() for ax in fig.axes if ax.get_legend() is not None] + list(fig.legends)
    return [t.get_text() for lg in legends for t in lg.get_texts()]


def data_axes(fig):
    """The axes that draw something (not switched off)."""
    return [ax for ax in fig.axes if ax.axison]


def assert_labelled(ax, x_unit: bool = True, y_unit: bool = True) -> None:
    xl, yl = ax.get_xlabel(), ax.get_ylabel()
    assert xl and yl, (xl, yl)
    if x_unit:
        assert UNIT.search(xl), f"no unit in x label {xl!r}"
    if y_unit:
        assert UNIT.search(yl), f"no unit in y label {yl!r}"


def line(ax, label: str):
    found = [ln for ln in ax.get_lines() if ln.get_label() == label]
    assert found, f"no line labelled {label!r} in {[ln.get_label() for ln in ax.get_lines()]}"
    return found[0]


def assert_expert_on_top(ax, learner_label: str) -> None:
    """The expert's line is drawn above the learner's: a higher zorder, or the same one and drawn later."""
    lines = ax.get_lines()
    e, lrn = line(ax, "expert"), line(ax, learner_label)
    assert (e.get_zorder(), lines.index(e)) > (lrn.get_zorder(), lines.index(lrn))
    assert e.get_linestyle() != lrn.get_linestyle() or e.get_color() != lrn.get_color()


@pytest.fixture
def scene():
    """One 2D environment with two obstacles, three starts, an expert and a learner that follows it closely."""
    g = torch.Generator().manual_seed(0)
    aux = {
        "goal": torch.tensor([[3.0, 1.0]]),
        "obstacle1_center": torch.tensor([[0.5, 0.5]]),
        "obstacle1_radius": torch.tensor([[0.8]]),
        "obstacle2_center": torch.tensor([[0.0, -1.5]]),
        "obstacle2_radius": torch.tensor([[0.6]]),
    }
    q0 = torch.tensor([[-3.0, 0.0], [-2.5, 1.0], [-3.0, -1.0]])
    qd0 = torch.randn(N, 2, generator=g) * 0.5
    s = torch.linspace(0, 1, T)[:, None, None]
    expert = q0[None] * (1 - s) + aux["goal"][None] * s + torch.sin(np.pi * s) * torch.tensor([0.0, 1.5])
    learner = expert + 0.02 * torch.randn(T, N, 2, generator=g)
    times = torch.linspace(0, 20, T)
    return SimpleNamespace(aux=aux, q0=q0, qd0=qd0, expert=expert, learner=learner, times=times)


def decreasing_V(scale: float, n: int = N) -> torch.Tensor:
    return scale * torch.linspace(1, 0, T)[:, None] ** 2 * torch.arange(1, n + 1, dtype=torch.float)


# ------------------------------------------------------------------------------------------------- the 2D set
def test_trajectories_name_every_mark_and_keep_the_expert_visible(scene):
    fig = F._draw_trajectories(
        scene.aux,
        scene.expert,
        {"learner-rmp": scene.learner},
        scene.q0,
        scene.qd0,
        title="2d2level: expert vs learner-rmp, test environment 0",
    )
    (ax,) = fig.axes
    assert_labelled(ax)
    assert ax.get_xlabel() == f"x ({F.PLANE_UNIT})" and ax.get_ylabel() == f"y ({F.PLANE_UNIT})"
    assert "test environment 0" in title_of(fig)
    texts = legend_texts(fig)
    for entry in ("expert", "learner-rmp", "start", "goal", "obstacle 1", "obstacle 2"):
        assert entry in texts, texts
    assert any(t.startswith("initial velocity") for t in texts), texts
    assert texts.index("expert") < texts.index("learner-rmp") < texts.index("goal")  # policies first, the scene after
    assert_expert_on_top(ax, "learner-rmp")
    assert line(ax, "learner-rmp").get_alpha() < 1  # the expert's dashes show the learner's line between them
    assert ax.get_legend().get_bbox_to_anchor().x0 >= ax.get_window_extent().x1  # beside the data, not over it


def test_trajectories_without_an_expert_or_starts_still_have_a_title_and_labels(scene):
    fig = F._draw_trajectories(scene.aux, None, {"rmp": scene.learner}, unit="m")
    (ax,) = fig.axes
    assert ax.get_xlabel() == "x (m)" and title_of(fig)
    assert "expert" not in legend_texts(fig) and "rmp" in legend_texts(fig)


def test_lyapunov_names_its_curves_and_axes(scene):
    fig = F._draw_lyapunov(scene.times, decreasing_V(2.0), title="rmp: $V_r(t)$, test environment 0")
    (ax,) = fig.axes
    assert_labelled(ax, y_unit=False)
    assert ax.get_xlabel() == "t (s)" and "V_r" in ax.get_ylabel() and "Lyapunov" in ax.get_ylabel()
    assert legend_texts(fig) == ["trajectory 0", "trajectory 1", "trajectory 2"]
    assert "test environment 0" in title_of(fig)
    many = F._draw_lyapunov(scene.times, decreasing_V(1.0, n=40))  # 40 curves: one colour, one entry
    assert legend_texts(many) == ["each of the 40 trajectories"] and title_of(many)


def test_learning_curves_label_loss_units_and_every_curve_kind():
    curves = {
        "rmp": {
            "train": [(i, 1.0 / (i + 1)) for i in range(1, 61)],
            "val": [(0, 0.9), (30, 0.2), (60, 0.1)],
            "test": [(0, 1.0), (60, 0.05)],
        }
    }
    fig = F._draw_learning_curves(curves, {"rmp": [0, 30, 60]}, title="2d2level: learning curve of rmp", unit="a.u./s²")
    (ax,) = fig.axes
    assert ax.get_ylabel() == "MSE of q̈ ((a.u./s²)²)" and ax.get_xlabel() == "training iteration"
    assert ax.get_yscale() == "log"
    texts = legend_texts(fig)
    assert any(t.startswith("rmp: train") for t in texts) and "rmp: validation set" in texts
    assert any(t.startswith("rmp: test") for t in texts)
    assert texts.count("evaluated snapshot") == 1  # the dots, named once
    assert title_of(fig) == "2d2level: learning curve of rmp"
    dots = [ln for ln in ax.get_lines() if ln.get_marker() == "o"]
    assert [float(d.get_xdata()[0]) for d in dots] == [0.0, 30.0, 60.0]  # each at its own iteration
    assert float(dots[1].get_ydata()[0]) == pytest.approx(np.sqrt(1.0 * 0.05))  # on the drawn (log) line
    assert UNIT.search(F._draw_learning_curves(curves).axes[0].get_ylabel())  # a unit even when none is given


def test_progression_shares_one_V_scale_and_names_the_environment(scene):
    stages = [
        {"label": f"rmp @ {it}", "q": scene.learner + k * 0.3, "times": scene.times, "V": decreasing_V(scale)}
        for k, (it, scale) in enumerate([(0, 4.0), (30, 2.0), (60, 1.0)])
    ]
    fig = F._draw_progression(
        scene.aux,
        scene.expert,
        stages,
        scene.q0,
        scene.qd0,
        title="2d2level: rmp vs the expert at each training snapshot, test environment 0",
    )
    axes = fig.axes
    top, bottom = axes[:3], axes[3:]
    assert [ax.get_title() for ax in top] == ["rmp @ 0", "rmp @ 30", "rmp @ 60"]
    assert "test environment 0" in fig.get_suptitle()
    for ax in top:
        assert_labelled(ax)
        assert_expert_on_top(ax, "learner")
    for ax in bottom:
        assert_labelled(ax, y_unit=False)
        assert "V_r" in ax.get_ylabel()
    ylims = {ax.get_ylim() for ax in bottom}
    assert len(ylims) == 1, ylims
    lo, hi = ylims.pop()
    assert lo <= 0.0 and hi >= 4.0 * N  # the largest V of any panel fits
    texts = legend_texts(fig)
    for entry in ("expert", "learner", "start", "goal", "obstacle 1", "obstacle 2"):
        assert entry in texts, texts
    assert any("V_r" in t for t in texts)
    assert len(texts) == len(set(texts))  # one figure legend, each entry once


def test_progression_without_V_has_one_row(scene):
    stages = [{"label": "rmp @ 0", "q": scene.learner, "times": scene.times, "V": None}]
    fig = F._draw_progression(scene.aux, scene.expert, stages)
    assert len(data_axes(fig)) == 1 and fig.get_suptitle()


def test_weights_label_every_panel_and_draw_the_expert_on_top(scene):
    t = scene.times
    expert = {"goal": 1 + t / 20, "obstacle1": 1 + 4 * torch.exp(-((t - 10) ** 2) / 8)}
    learned = {
        "rmp @ 0": {"goal": 0.5 + 0 * t, "obstacle1": 0.7 + 0 * t},
        "rmp @ 60": {"goal": 1 + t / 21, "obstacle1": 1 + 3.8 * torch.exp(-((t - 10) ** 2) / 8)},
    }
    fig = F._draw_weights(t, expert, learned, title="2d2level: rmp's weights vs the expert's, test environment 0")
    axes = data_axes(fig)
    assert len(axes) == 2
    for ax, edge in zip(axes, expert):
        assert ax.get_xlabel() == "t (s)" and "weight" in ax.get_ylabel()  # a weight has no unit
        assert edge in ax.get_title()
        assert_expert_on_top(ax, "rmp @ 60")
    assert legend_texts(fig) == ["expert", "rmp @ 0", "rmp @ 60"]
    assert "test environment 0" in title_of(fig)


def test_the_old_positional_calls_still_write_pngs(scene, tmp_path):
    """The callers' signatures are unchanged: every new argument is a keyword with a default."""
    paths = [
        F.plot_trajectories(
            tmp_path / "t.png", scene.aux, scene.expert, {"rmp": scene.learner}, scene.q0, scene.qd0, "title", (-5, 5)
        ),
        F.plot_lyapunov(tmp_path / "v.png", scene.times, decreasing_V(1.0), "title"),
        F.plot_learning_curves(
            tmp_path / "l.png", {"rmp": {"train": [(1, 1.0), (2, 0.5)], "test": [(0, 1.0)]}}, {"rmp": [0]}, 50
        ),
        F.plot_progression(
            tmp_path / "p.png",
            scene.aux,
            scene.expert,
            [{"label": "rmp @ 0", "q": scene.learner, "times": scene.times, "V": decreasing_V(1.0)}],
            scene.q0,
            scene.qd0,
            (-5, 5),
        ),
        F.plot_weights(tmp_path / "w.png", scene.times, {"goal": scene.times}, {"rmp": {"goal": scene.times}}, "t"),
    ]
    for p in paths:
        assert p.is_file() and p.stat().st_size > 1000


# ------------------------------------------------------------------------------------------------- the Franka set
def _ratios():
    return {
        "learner-0": {"time": {"mean": 2.0, "std": 0.5}, "ee_length": {"mean": 1.4, "std": 0.2}},
        "learner-4": {"time": {"mean": 1.1, "std": 0.1}, "ee_length": {"mean": 1.0, "std": 0.05}},
    }


def test_ratio_bars_name_the_policies_the_expert_and_the_error_bars():
    fig = FR._draw_ratio_bars(_ratios(), ["time", "ee_length"], title="franka: learner / expert on the test set")
    (ax,) = fig.axes
    assert ax.get_xlabel() and "learner / expert" in ax.get_ylabel()
    assert [t.get_text() for t in ax.get_xticklabels()] == ["time", "end eff length"]
    texts = legend_texts(fig)
    assert {"learner-0", "learner-4"} <= set(texts)
    assert any(t.startswith("expert") for t in texts) and any("std" in t for t in texts)
    assert title_of(fig) == "franka: learner / expert on the test set"


def test_goal_distances_in_metres_with_the_precision_line():
    policies = [
        SimpleNamespace(
            label=lab,
            summary={
                "timeout_goal_distance": {"mean": m, "std": m / 2},
                "min_goal_distance": {"mean": m / 3, "std": m / 4},
            },
        )
        for lab, m in (("expert", 0.003), ("learner-0", 0.4), ("learner-4", 0.1))
    ]
    fig = FR._draw_goal_distances(policies)
    (ax,) = fig.axes
    assert_labelled(ax, x_unit=False)
    assert "(m)" in ax.get_ylabel() and ax.get_yscale() == "log"
    texts = legend_texts(fig)
    assert any("0.05 m" in t for t in texts) and any("time-out" in t for t in texts)
    assert any("closest" in t for t in texts) and title_of(fig)


def test_lyapunov_stages_share_one_scale_and_name_both_line_kinds(scene):
    panels = [
        {"label": lab, "times": scene.times, "V": decreasing_V(scale), "highlight": 1}
        for lab, scale in (("expert", 1.0), ("learner-0", 5.0), ("learner-4", 2.0))
    ]
    fig = FR._draw_lyapunov_stages(panels, title="franka: $V_r(t)$ on the test set")
    axes = fig.axes
    assert [ax.get_title() for ax in axes] == ["expert", "learner-0", "learner-4"]
    for ax in axes:
        assert ax.get_xlabel() == "t (s)" and "V_r" in ax.get_ylabel()
    ylims = {ax.get_ylim() for ax in axes}
    assert len(ylims) == 1 and ylims.pop()[1] >= 5.0 * N
    texts = legend_texts(fig)
    assert "each test trajectory" in texts and any("rendered execution" in t for t in texts)
    assert fig.get_suptitle() == "franka: $V_r(t)$ on the test set"


def test_render_strip_names_the_trail_and_the_goal():
    img = np.full((60, 80, 3), 200, dtype=np.uint8)
    trail = np.array([[10.0, 10.0], [30.0, 20.0], [50.0, 40.0]])
    rows = [
        {
            "label": lab,
            "frames": [{"t": t, "image": img, "trail": trail, "goal": np.array([60.0, 45.0])} for t in (0.0, 1.0)],
        }
        for lab in ("expert", "learner-0")
    ]
    fig = FR._draw_render_strip(rows, title="franka: test execution 1")
    assert [ax.get_ylabel() for ax in fig.axes[::2]] == ["expert", "learner-0"]
    assert [ax.get_title() for ax in fig.axes[:2]] == ["t = 0.0 s", "t = 1.0 s"]
    assert legend_texts(fig) == [FR.TRAIL_LABEL, FR.GOAL_LABEL, FR.OBSTACLE_LABEL]
    assert fig.get_suptitle() == "franka: test execution 1"


def test_ee_paths_in_metres_with_the_expert_over_the_learners():
    aux = {
        "goal": torch.tensor([[0.44, -0.18, 0.3]]),
        "obstacle1_center": torch.tensor([[0.5, 0.08, 0.3]]),
        "obstacle1_radius": torch.tensor([[0.06]]),
    }
    s = torch.linspace(0, 1, 30)[:, None]
    expert = torch.tensor([0.32, 0.35, 0.4]) * (1 - s) + aux["goal"] * s
    paths = {"expert": expert, "learner-0": expert + 0.01, "learner-4": expert + 0.002}
    fig = FR._draw_ee_paths(aux, paths, title="franka: end-effector paths, test execution 1 (top view)")
    (ax,) = fig.axes
    assert ax.get_xlabel() == "x (m)" and ax.get_ylabel() == "y (m)"
    for lab in ("learner-0", "learner-4"):
        assert_expert_on_top(ax, lab)
    texts = legend_texts(fig)
    for entry in ("expert", "learner-0", "learner-4", "start", "goal", "robot base", "obstacles (top view)"):
        assert entry in texts, texts
    assert any("0.05 m" in t for t in texts)
    assert texts.count("start") == 1 and "test execution 1" in title_of(fig)


def test_gif_labels_fit_their_text_and_the_caption_spans_the_frame():
    tile = np.full((36, 48, 3), 100, dtype=np.uint8)  # as small as the tests' renders
    labelled = FR._label(tile, "learner-4, t = 1.0 s")
    assert labelled.shape[1] == tile.shape[1] and labelled.shape[0] > tile.shape[0]
    assert (labelled[-tile.shape[0] :] == tile).all()  # the label sits above the render, never over it
    for text in ("learner-4, t = 10.0 s", "expert, t = 0.1 s", "a much longer policy label, t = 0.0 s"):
        assert FR._label(tile, text).shape == labelled.shape  # the tiles of a GIF frame line up
    caption = FR._caption(360, ["franka: test execution 1", f"yellow line: {FR.TRAIL_LABEL}"])
    assert caption.shape[1] == 360 and caption.shape[2] == 3 and caption.shape[0] >= 20
    assert (caption < 128).any()  # text was drawn
    key = "yellow line: end-effector path so far; orange ring: goal; red cylinder: obstacle"
    wide, narrow = FR._caption(2000, [key]), FR._caption(200, [key])
    assert narrow.shape[0] > 2 * wide.shape[0]  # three lines on a narrow frame instead of text running off it
