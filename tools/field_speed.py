#!/usr/bin/env python
"""How fast a finished recorded-demonstrations run's learned field moves away from its recordings: the speed of its
first-order field v(q) over a grid of the convergence check's box of starts, against the fastest recorded speed.

The recordings constrain a fitted field only where they pass; elsewhere a learned map may stretch space steeply, and a
field many times faster than any demonstration flings second-order rollouts far out (and past what a fixed
integration step can follow). This measures it without training again:

    python tools/field_speed.py <run dir>                 # 200 × 200 grid of the box, learner rmp

Prints the fastest recorded speed, the field's largest speed and 99th percentile over the grid, and the fractions of
the grid faster than 2 and 5 times the fastest recorded speed. Nothing is written.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch

from rmpfusion.pipeline.finished import finished_run
from rmpfusion.pipeline.recorded import start_box


def field_speeds(run_dir: Path, learner: str, points: int) -> dict[str, float]:
    """The run's learner's field speeds over a points × points grid of its box of starts (2-D runs)."""
    with finished_run(run_dir, learner) as f:
        exp, model, every = f.exp, f.model, f.every
    lo, hi = start_box(every, exp.recorded_data.enlarge)
    if len(lo) != 2:
        raise SystemExit(f"{run_dir}: a {len(lo)}-dimensional run; this grid is for 2-D demonstrations")
    axes = [np.linspace(a, b, points) for a, b in zip(lo, hi)]
    q = torch.as_tensor(np.stack(np.meshgrid(*axes), -1).reshape(-1, 2))
    goal = torch.as_tensor(every[0].goal)[None].expand(len(q), -1).clone()
    with torch.no_grad():
        v = model.first_order_field(q, {"goal": goal}).norm(dim=-1)
    fastest = max(float(np.linalg.norm(d.qd, axis=-1).max()) for d in every)
    return {
        "fastest_recorded": fastest,
        "field_max": float(v.max()),
        "field_p99": float(v.quantile(0.99)),
        "above_2x": float((v > 2 * fastest).double().mean()),
        "above_5x": float((v > 5 * fastest).double().mean()),
    }


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("run_dir", type=Path, help="a finished experiment=lasa (2-D recorded) run")
    ap.add_argument("--learner", default="rmp")
    ap.add_argument("--points", type=int, default=200, help="grid points per side of the box")
    a = ap.parse_args(argv)
    if not (a.run_dir / "checkpoints" / a.learner / "final.pt").is_file():
        print(f"{a.run_dir}: no checkpoints/{a.learner}/final.pt; give a finished run", file=sys.stderr)
        return 1
    s = field_speeds(a.run_dir, a.learner, a.points)
    print(
        f"fastest recorded {s['fastest_recorded']:.3f} m/s; the field over the box of starts: max {s['field_max']:.3f} "
        f"({s['field_max'] / s['fastest_recorded']:.1f}×), 99th percentile {s['field_p99']:.3f}; "
        f"{s['above_2x']:.1%} of it above 2×, {s['above_5x']:.1%} above 5×"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
