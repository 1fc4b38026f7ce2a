"""How well a rollout reproduces a demonstration: the measures of the learning-from-demonstration literature
on the LASA benchmark (Khansari-Zadeh & Billard 2011/2014; Rana et al. 2020).

* ``dtw_distance``: dynamic time warping, the least sum of Euclidean distances over monotone alignments of the
  two paths (demonstrations differ in speed; DTW compares shapes). Reported as that sum divided by the
  demonstration's length in samples, so it reads as a mean distance per sample.
* ``swept_error_area``: the area swept between the rollout and the demonstration sampled at the same times,
  the sum of the quadrilaterals (x_k, x_{k+1}, y_{k+1}, y_k), each split into two triangles (exact for planar
  quadrilaterals that do not cross; in more dimensions, the two triangles' areas).
* ``final_distance``, ``time_to_tolerance``: where the rollout ends relative to the goal, and when it first
  comes within a tolerance of it (inf if never).
* ``overshoot``: how far the path goes back away from the goal after having been closer, the largest rise of its
  distance to the goal over its running minimum (0 for a path that approaches the goal monotonically; a path that
  passes the goal and swings out 14 mm before coming back reads 14 mm).
"""

from __future__ import annotations

import numpy as np


def pairwise_distances(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(N, M) Euclidean distances between the rows of a (N, d) and b (M, d)."""
    return np.linalg.norm(a[:, None, :] - b[None, :, :], axis=-1)


def dtw_distance(a: np.ndarray, b: np.ndarray) -> float:
    """Σ of distances along the best monotone alignment of a (N, d) with b (M, d), divided by M.

    The table D[i, j] = c[i, j] + min(D[i−1, j−1], D[i−1, j], D[i, j−1]) is filled one anti-diagonal at a
    time (cells of one anti-diagonal depend only on the two before it), so the loop runs N + M times, not N·M."""
    cost = pairwise_distances(np.asarray(a, np.float64), np.asarray(b, np.float64))
    n, m = cost.shape
    D = np.full((n + 1, m + 1), np.inf)
    D[0, 0] = 0.0
    for s in range(2, n + m + 1):  # i + j = s over the padded table, 1 ≤ i ≤ n, 1 ≤ j ≤ m
        i = np.arange(max(1, s - m), min(n, s - 1) + 1)
        j = s - i
        D[i, j] = cost[i - 1, j - 1] + np.minimum(np.minimum(D[i - 1, j - 1], D[i - 1, j]), D[i, j - 1])
    return float(D[n, m] / m)


def _triangle_areas(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """½|u × v| for rows of u, v in any dimension: ½·sqrt(|u|²|v|² − (u·v)²)."""
    uu, vv, uv = (u * u).sum(-1), (v * v).sum(-1), (u * v).sum(-1)
    return 0.5 * np.sqrt(np.clip(uu * vv - uv * uv, 0.0, None))


def swept_error_area(rollout: np.ndarray, demo: np.ndarray) -> float:
    """Area between two paths sampled at the same times, (T, d) each (the shorter is held at its last point)."""
    rollout, demo = np.asarray(rollout, np.float64), np.asarray(demo, np.float64)
    T = max(len(rollout), len(demo))
    pad = lambda p: np.concatenate([p, np.repeat(p[-1:], T - len(p), axis=0)])
    x, y = pad(rollout), pad(demo)
    x0, x1, y0, y1 = x[:-1], x[1:], y[:-1], y[1:]
    return float((_triangle_areas(x1 - x0, y0 - x0) + _triangle_areas(y1 - x1, y0 - x1)).sum())


def final_distance(path: np.ndarray, goal: np.ndarray) -> float:
    return float(np.linalg.norm(np.asarray(path)[-1] - np.asarray(goal)))


def time_to_tolerance(t: np.ndarray, path: np.ndarray, goal: np.ndarray, tolerance: float) -> float:
    """The first time the path is within ``tolerance`` of the goal (inf if it never is)."""
    inside = np.flatnonzero(np.linalg.norm(np.asarray(path) - np.asarray(goal), axis=-1) <= tolerance)
    return float(np.asarray(t)[inside[0]]) if inside.size else float("inf")


def overshoot(goal_distance: np.ndarray) -> float:
    """max_t [d(t) − min_{s ≤ t} d(s)] of a path's distances to the goal ``goal_distance`` (T,), in their unit."""
    d = np.asarray(goal_distance, np.float64)
    return float((d - np.minimum.accumulate(d)).max()) if d.size else 0.0
