"""Two runs' metrics number by number: did a change keep the results? (``rmpfusion-study check``, and
``rmpfusion-study compare A B`` for any two runs.)

Every number present in both is compared (nested keys flattened to paths like
``learners.rmp.snapshots.60.online_loss``), except what says how a run went rather than what it found:
wall-clock times, file paths, whether data was reused or training resumed, and the config hash (which
changes with the config's spelling, not its meaning). Dataset checksums are compared: equal checksums mean
bit-identical demonstrations. Residuals that are zero in exact arithmetic (the certificate's energy-identity
error, a finite difference of V_r against −q̇ᵀB_r q̇) are rounding and truncation error, whose relative
differences say nothing: they are compared by absolute difference, far below the certificate's own tolerance.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterator
from pathlib import Path
from typing import Any

#: keys of residuals that are zero in exact arithmetic: compared by absolute difference
RESIDUALS = {"max_energy_identity_error"}

#: keys about how the run went (time, places, resumption), not about what it found
IGNORED = {
    "timing",
    "train_seconds",
    "eval_seconds",
    "seconds",
    "path",
    "figures",
    "config_hash",
    "reused",
    "resumed_from",
}


def leaves(x: Any, prefix: str = "") -> Iterator[tuple[str, Any]]:
    """(path, value) of every scalar below ``x``, skipping the IGNORED keys."""
    if isinstance(x, dict):
        for k, v in x.items():
            if k not in IGNORED:
                yield from leaves(v, f"{prefix}.{k}" if prefix else str(k))
    elif isinstance(x, list):
        for i, v in enumerate(x):
            yield from leaves(v, f"{prefix}[{i}]")
    else:
        yield prefix, x


def relative_difference(a: Any, b: Any) -> float:
    """|a − b| / max(|a|, |b|) for numbers (0 when both are equal, NaN-equal or both null); inf when unequal
    non-numbers."""
    if isinstance(a, bool) or isinstance(b, bool) or not isinstance(a, (int, float)) or not isinstance(b, (int, float)):
        return 0.0 if a == b else math.inf
    if a == b or (math.isnan(a) and math.isnan(b)):
        return 0.0
    return abs(a - b) / max(abs(a), abs(b))


def _residual_differs(a: Any, b: Any, atol: float) -> bool:
    """Two residuals differ when they are not equal and not two numbers within ``atol`` of each other."""
    numbers = all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in (a, b))
    return relative_difference(a, b) > 0 and not (numbers and abs(a - b) <= atol)


def compare(a: dict, b: dict, rtol: float, residual_atol: float = 1e-7) -> tuple[int, float, list[str], list[str]]:
    """(numbers compared, largest relative difference of the numbers compared relatively, lines for differing
    numbers, lines for one-sided keys)."""
    la, lb = dict(leaves(a)), dict(leaves(b))
    shared = [k for k in la if k in lb]
    worst, differ = 0.0, []
    for k in shared:
        if k.rsplit(".", 1)[-1] in RESIDUALS:
            if _residual_differs(la[k], lb[k], residual_atol):
                differ.append(f"  {k}: {la[k]!r} vs {lb[k]!r} (a residual: more than {residual_atol:g} apart)")
            continue
        d = relative_difference(la[k], lb[k])
        worst = max(worst, d)
        if d > rtol:
            differ.append(f"  {k}: {la[k]!r} vs {lb[k]!r} (relative {d:.3g})")
    one_sided = [f"  only in the first: {k}" for k in la if k not in lb] + [
        f"  only in the second: {k}" for k in lb if k not in la
    ]
    return len(shared), worst, differ, one_sided


def metrics_path(p: Path) -> Path:
    """A run's metrics.json given the file itself or the directory holding it: a run directory, or a run stored in
    results/ (``results/2d1level``), so a fresh run is compared with the stored one by naming both."""
    return p / "metrics.json" if p.is_dir() else p


def read_metrics(path: Path) -> dict:
    """A run's metrics.json, or a ValueError naming the file and what is wrong with it (missing, cut short)."""
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        raise ValueError(f"{path} does not exist; give the metrics.json of a finished run") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise ValueError(
            f"{path} is not readable JSON ({e}): a run killed while writing it, or a damaged copy; "
            "rerun that run (it resumes and writes metrics.json again)"
        ) from None
    if not isinstance(data, dict):
        # ValueError, not TypeError: callers catch ValueError for a bad file, whatever is wrong with it
        raise ValueError(f"{path} holds {type(data).__name__}, not the mapping a metrics.json holds")  # noqa: TRY004
    return data
