"""The regression check of ``make bench`` (tools/bench_baseline.py) on made-up rows: nothing here is timed. A ratio
counts as regressed only beyond its noise, a machine kind without a baseline is never failed, and storing one
machine's ratios keeps every other machine's."""

from __future__ import annotations

import json

from tools import bench_baseline as baseline

KIND = "Some CPU, 2 cores, torch 9.9"


def _row(key: str, ratio: float, spread: float | None = 0.05) -> dict:
    return {"key": key, "ratio_value": ratio, "spread": spread, "what": key}


def test_per_round_ratios_give_their_median_and_spread():
    r = baseline.Ratio.of([2.0, 2.2, 2.4, 2.0, 6.0], [1.0, 1.0, 1.0, 1.0, 1.0])
    assert r.value == 2.2  # one slow round moves the median little
    assert r.spread is not None and 0 < r.spread < 0.2
    assert baseline.Ratio.once(3.0, 2.0).spread is None


def test_a_ratio_regresses_only_beyond_its_noise(tmp_path):
    path = tmp_path / "baseline.json"
    baseline.store([_row("reference/compiled_policy", 0.40), _row("train/eager_step", 1.2, None)], path, KIND, {})
    machines = baseline.load(path)
    within = [_row("reference/compiled_policy", 0.48), _row("train/eager_step", 1.7, None)]  # +20 %, +42 %
    lines, regressed = baseline.check(within, machines, KIND)
    assert regressed == [] and len(lines) == 2 and all(line.endswith("ok") for line in lines)
    beyond = [_row("reference/compiled_policy", 0.55), _row("train/eager_step", 1.9, None)]  # +38 %, +58 %
    _, regressed = baseline.check(beyond, machines, KIND)
    assert regressed == ["reference/compiled_policy", "train/eager_step"]
    noisy = [_row("reference/compiled_policy", 0.55, spread=0.2)]  # a noisy run is allowed more
    assert baseline.check(noisy, machines, KIND)[1] == []
    faster = baseline.check([_row("reference/compiled_policy", 0.2)], machines, KIND)[0]
    assert "faster than the baseline" in faster[0]


def test_a_machine_kind_without_a_baseline_is_reported_not_failed(tmp_path):
    lines, regressed = baseline.check([_row("reference/compiled_policy", 9.0)], {}, KIND)
    assert regressed == [] and "no baseline for this machine kind" in lines[0]


def test_storing_one_machine_keeps_the_others_and_the_rows_not_measured(tmp_path):
    path = tmp_path / "baseline.json"
    baseline.store([_row("a/x", 1.0), _row("a/y", 2.0)], path, KIND, {})
    baseline.store([_row("a/x", 1.5)], path, KIND, {})
    baseline.store([_row("a/x", 0.5)], path, "Other CPU, 8 cores, torch 9.9", {})
    machines = json.loads(path.read_text())["machines"]
    assert machines[KIND]["ratios"]["a/x"]["ratio"] == 1.5 and machines[KIND]["ratios"]["a/y"]["ratio"] == 2.0
    assert machines["Other CPU, 8 cores, torch 9.9"]["ratios"]["a/x"]["ratio"] == 0.5


def test_the_machine_kind_names_cpu_cores_and_torch():
    kind = baseline.machine_kind()
    assert "cores" in kind and "torch" in kind
