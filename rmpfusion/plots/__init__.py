"""Figures of the 2D experiments (paper Fig. 3, 4, 7, 8) as PNG files; matplotlib runs headless (Agg)."""
from .figures import (  # noqa: F401
    plot_learning_curves,
    plot_lyapunov,
    plot_progression,
    plot_trajectories,
    plot_weights,
    save_figure,
)
