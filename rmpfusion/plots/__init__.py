"""Figures as PNG files, drawn off-screen on matplotlib Figures (no pyplot: importing them never picks a backend)."""

from .figures import (
    plot_learning_curves,
    plot_lyapunov,
    plot_progression,
    plot_trajectories,
    plot_weights,
    save_figure,
)

__all__ = [
    "plot_learning_curves",
    "plot_lyapunov",
    "plot_progression",
    "plot_trajectories",
    "plot_weights",
    "save_figure",
]
