"""Ratios measured side by side, and the baseline ``make bench`` keeps of them per kind of machine.

A benchmark's absolute times say more about the host than about the code (on a shared 2-core machine the same
numpy call took 89–410 µs within an hour), so what is compared from run to run is a ratio: the subject's time over
its reference's, both timed in the same rounds, one after the other (``side_by_side``), so that whatever slows the
host slows both. Each round gives one ratio; a row reports their median and their spread (half the interquartile
range over the median), which is the noise a later run is allowed before a change counts as a regression.

The baseline (tools/bench_baseline.json, checked in) holds, for each kind of machine (CPU model, cores, torch
version: ``machine_kind``), the ratio and spread of every row that has one. ``python -m tools.bench --check`` says
which ratios rose beyond noise against this machine kind's baseline and exits non-zero then;
``--store-baseline`` (what ``make bench`` runs, after the check) writes this run's ratios for this machine kind.
"""

from __future__ import annotations

import json
import math
import os
import platform
import statistics
import time
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path

import torch

from rmpfusion.files import atomic_write_bytes

BASELINE = Path(__file__).resolve().parent / "bench_baseline.json"
#: a ratio counts as regressed when it exceeds its baseline by more than this fraction, or by three times the
#: rounds' combined spread when that is larger (a shared machine's noise between two runs)
MIN_TOLERANCE = 0.25
#: the same for a ratio of two single timings (minutes-long rows timed once each): no spread to go by
SINGLE_TIMING_TOLERANCE = 0.5


def cpu_model() -> str:
    """The CPU's model name as the kernel reports it (the processor field elsewhere)."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def machine_kind() -> str:
    """What a baseline is kept for: the CPU model, the number of cores and the torch version (a ratio of torch's
    per-operation overhead to numpy's moves with any of them)."""
    return f"{cpu_model()}, {os.cpu_count()} cores, torch {torch.__version__}"


def side_by_side(
    fns: Mapping[str, Callable[[], object]], rounds: int = 15, min_time: float = 1.5, warmup: int = 3
) -> dict[str, list[float]]:
    """Seconds per call of each of ``fns`` in every one of ``rounds`` rounds; in each round every function is timed
    in turn, for about ``min_time / rounds`` shared between them (enough calls that the clock's resolution does not
    matter), so a change of the host's speed falls on all of them alike."""
    calls = {}
    for name, fn in fns.items():
        for _ in range(warmup):
            fn()
        t0 = time.perf_counter()
        fn()
        one = max(time.perf_counter() - t0, 1e-7)
        calls[name] = max(1, int(min_time / rounds / len(fns) / one))
    out: dict[str, list[float]] = {name: [] for name in fns}
    for _ in range(rounds):
        for name, fn in fns.items():
            t0 = time.perf_counter()
            for _ in range(calls[name]):
                fn()
            out[name].append((time.perf_counter() - t0) / calls[name])
    return out


@dataclass(frozen=True)
class Ratio:
    """A subject's time over its reference's: the median of the per-round ratios, and their spread (half the
    interquartile range, relative to the median; None for a ratio of two single timings)."""

    value: float
    spread: float | None

    @classmethod
    def of(cls, times: list[float], reference: list[float]) -> Ratio:
        per_round = [t / r for t, r in zip(times, reference)]
        if len(per_round) < 2:
            return cls(per_round[0], None)
        q1, median, q3 = statistics.quantiles(per_round, n=4, method="inclusive")
        return cls(median, (q3 - q1) / 2 / median)

    @classmethod
    def once(cls, time_s: float, reference_s: float) -> Ratio:
        return cls(time_s / reference_s, None)

    def text(self) -> str:
        return f"{self.value:.2f}" + ("" if self.spread is None else f" ±{100 * self.spread:.0f}%")


def load(path: Path = BASELINE) -> dict:
    """The stored baselines: {machine kind: {"ratios": {key: {"ratio", "spread", "what"}}, ...}}."""
    if not path.is_file():
        return {}
    try:
        data = json.loads(path.read_text())
    except json.JSONDecodeError as e:
        raise SystemExit(f"{path}: not valid JSON ({e}); restore it from git or delete it to start a new one") from None
    return data.get("machines", {})


def tolerance(now: Mapping, base: Mapping) -> float:
    """How far above its baseline a ratio may come out before it counts as regressed (``MIN_TOLERANCE``)."""
    spreads = [s for s in (now.get("spread"), base.get("spread")) if s is not None]
    if len(spreads) < 2:
        return SINGLE_TIMING_TOLERANCE
    return max(MIN_TOLERANCE, 3 * math.hypot(*spreads))


def check(rows: Iterable[Mapping], machines: Mapping, kind: str) -> tuple[list[str], list[str]]:
    """(lines to print, keys of the ratios that regressed) for this run's ``rows`` against ``kind``'s baseline."""
    base = machines.get(kind, {}).get("ratios", {})
    lines, regressed = [], []
    if not base:
        return [f"no baseline for this machine kind ({kind}): ratios printed, not checked (make bench stores one)"], []
    for r in rows:
        if r.get("key") is None or r["key"] not in base:
            continue
        b, limit = base[r["key"]], tolerance(r, base[r["key"]])
        verdict = "ok"
        if r["ratio_value"] > b["ratio"] * (1 + limit):
            verdict = "REGRESSED"
            regressed.append(r["key"])
        elif r["ratio_value"] < b["ratio"] / (1 + limit):
            verdict = "faster than the baseline (make bench stores the new ratios)"
        lines.append(
            f"  {r['key']:<40} {r['ratio_value']:8.3f}  baseline {b['ratio']:.3f} (allowed +{100 * limit:.0f}%)  {verdict}"
        )
    return lines, regressed


def store(rows: Iterable[Mapping], path: Path, kind: str, info: Mapping) -> int:
    """This run's ratios written as ``kind``'s baseline (rows not measured in this run keep their stored values);
    returns how many were written."""
    machines = load(path)
    entry = machines.setdefault(kind, {"ratios": {}})
    written = 0
    for r in rows:
        if r.get("key") is not None:
            entry["ratios"][r["key"]] = {"ratio": r["ratio_value"], "spread": r.get("spread"), "what": r["what"]}
            written += 1
    entry.update(date=time.strftime("%Y-%m-%d"), torch=info.get("torch"), python=info.get("python"))
    note = (
        "Ratios of make bench per kind of machine (tools/bench_baseline.py): each a subject's time over its "
        "reference's, timed side by side; python -m tools.bench --check compares a run with its machine kind's."
    )
    text = json.dumps({"about": note, "machines": machines}, indent=1, sort_keys=True) + "\n"
    atomic_write_bytes(path, text.encode())  # written whole, then renamed: never a half-written baseline
    return written


def main() -> None:
    """``python -m tools.bench_baseline``: this machine's kind and the baseline stored for it (or which kinds are)."""
    kind, machines = machine_kind(), load()
    print(f"this machine: {kind}")
    if kind not in machines:
        stored = ", ".join(sorted(machines)) or "none"
        print(f"no baseline stored for it in {BASELINE} (stored: {stored}); make bench stores one")
        return
    entry = machines[kind]
    print(f"baseline of {entry.get('date')} (torch {entry.get('torch')}, python {entry.get('python')}):")
    for key, r in sorted(entry["ratios"].items()):
        spread = "" if r.get("spread") is None else f" ± {r['spread']:.0%}"
        print(f"  {key}: {r['ratio']:.3g}{spread}  ({r['what']})")


if __name__ == "__main__":
    main()
