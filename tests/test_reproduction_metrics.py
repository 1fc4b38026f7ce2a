"""The reproduction measures against cases worked by hand and against a brute-force DTW."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from rmpfusion.evaluate.reproduction import (
    dtw_distance,
    final_distance,
    overshoot,
    swept_error_area,
    time_to_tolerance,
)


def brute_force_dtw(a, b):
    """The DTW recursion cell by cell, as the definition reads."""
    n, m = len(a), len(b)
    D = [[math.inf] * (m + 1) for _ in range(n + 1)]
    D[0][0] = 0.0
    for i, j in itertools.product(range(1, n + 1), range(1, m + 1)):
        D[i][j] = float(np.linalg.norm(a[i - 1] - b[j - 1])) + min(D[i - 1][j - 1], D[i - 1][j], D[i][j - 1])
    return D[n][m] / m


def test_dtw_equals_the_cell_by_cell_recursion_on_random_paths():
    rng = np.random.default_rng(0)
    for n, m, d in [(7, 11, 2), (13, 5, 3), (1, 4, 2)]:
        a, b = rng.normal(size=(n, d)), rng.normal(size=(m, d))
        assert dtw_distance(a, b) == pytest.approx(brute_force_dtw(a, b), rel=1e-12)


def test_dtw_ignores_speed_but_not_shape():
    s = np.linspace(0, 1, 200)
    path = np.stack([np.cos(3 * s), np.sin(3 * s)], 1)
    slow_start = np.stack([np.cos(3 * s**2), np.sin(3 * s**2)], 1)  # same curve, other timing
    assert dtw_distance(slow_start, path) < 0.01
    line = np.stack([s, 0 * s], 1)  # a parallel line 0.1 away: no alignment does better than 0.1 a sample
    assert dtw_distance(line + [0.0, 0.1], line) == pytest.approx(0.1, rel=1e-9)
    assert dtw_distance(path + [0.0, 0.1], path) > 0.05


def test_swept_error_area_of_parallel_segments_and_a_crossing_is_worked_by_hand():
    t = np.linspace(0, 2, 21)
    demo = np.stack([t, 0 * t], 1)
    assert swept_error_area(demo + [0.0, 0.3], demo) == pytest.approx(0.6, rel=1e-12)  # 2 long, 0.3 apart
    assert swept_error_area(demo, demo) == 0.0
    # 3-D: the same strip tilted out of the plane has the same area
    tilted = np.stack([t, 0 * t, 0 * t], 1), np.stack([t, 0.3 / np.sqrt(2) + 0 * t, 0.3 / np.sqrt(2) + 0 * t], 1)
    assert swept_error_area(tilted[1], tilted[0]) == pytest.approx(0.6, rel=1e-12)


def test_final_distance_and_time_to_tolerance():
    t = np.linspace(0, 1, 11)
    path = np.stack([1 - t, 0 * t], 1)
    assert final_distance(path, [0.0, 0.0]) == pytest.approx(0.0, abs=1e-15)
    assert time_to_tolerance(t, path, [0.0, 0.0], 0.25) == pytest.approx(0.8)
    assert time_to_tolerance(t, path, [5.0, 0.0], 0.1) == math.inf


def test_overshoot_is_how_far_a_path_swings_back_out_after_having_been_closer():
    t = np.linspace(0.0, 1.0, 201)
    approach = np.stack([1.0 - t, np.zeros_like(t)], -1)  # straight at the goal (the origin), stopping on it
    assert overshoot(np.linalg.norm(approach, axis=-1)) == 0.0
    passing = np.stack([1.0 - 1.5 * t, 0.02 * np.ones_like(t)], -1)  # passes 2 cm beside it, ends 0.5 beyond
    d = np.linalg.norm(passing, axis=-1)
    assert overshoot(d) == pytest.approx(
        math.hypot(0.5, 0.02) - 0.02, abs=1e-3
    )  # out to the end from the closest sample
    wiggle = np.array([3.0, 2.0, 2.5, 1.0, 1.2, 0.0])
    assert overshoot(wiggle) == pytest.approx(0.5)  # the larger of the two rises over the running minimum
