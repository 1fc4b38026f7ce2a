#!/usr/bin/env python
"""The score-function policy gradient on the Franka (experiment=franka_pg): learner-rmp from its random weights,
no demonstrations, the kinematic simulator. Runs the experiment, then writes <out>/table.md: the task table of
tools/task_table.py (expert and every snapshot on the test starts, 10 s each) and the learning curve in numbers
(the mean policy's task cost on the validation starts, every ``train.log_every`` steps); the figure is
<out>/run/figures/learning_curve_rmp.png.

    python tools/pg_franka.py                      # conf/train/pg.yaml as it is
    python tools/pg_franka.py --table-only         # the table of the run already in --out
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import torch

from rmpfusion.learn.checkpoints import load_checkpoint

sys.path.insert(0, str(Path(__file__).resolve().parent))
from task_table import HEADER, rows


def config(extra: list[str]):
    from hydra import compose, initialize_config_dir

    from rmpfusion.cli import CONF_DIR
    from rmpfusion.pipeline.validate import resolve_and_validate

    with initialize_config_dir(config_dir=CONF_DIR, version_base="1.3"):
        return resolve_and_validate(compose("config", overrides=["experiment=franka_pg", "logger=disabled", *extra]))


def curve(run_dir: Path) -> str:
    """The validation cost of the mean policy and the training episodes' cost, from the last checkpoint."""
    ck = load_checkpoint(max((run_dir / "checkpoints" / "rmp").glob("ckpt-*.pt")))
    train = dict(ck["curve"])
    lines = [
        "| iteration | task cost, validation starts (mean policy) | task cost, training episodes (Gaussian) |",
        "|---|---|---|",
    ]
    for it, v in ck["val_curve"]:
        lines.append(f"| {it} | {v:.3f} | {train[it]:.3f} |" if it in train else f"| {it} | {v:.3f} | – |")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, default=Path("outputs/pg_franka"))
    ap.add_argument("--table-only", action="store_true", help="run nothing: the table of <out>/run")
    ap.add_argument("overrides", nargs="*", help="Hydra overrides of experiment=franka_pg")
    a = ap.parse_args(argv)
    t0 = time.time()
    if not a.table_only:
        from rmpfusion.pipeline.run import run_experiment

        torch.set_num_threads(1)
        run_experiment(config(a.overrides), a.out / "run")
    metrics = json.loads((a.out / "run" / "metrics.json").read_text())
    md = "\n".join(
        [
            f"# franka_pg: REINFORCE on the Franka from random weights ({time.time() - t0:.0f} s)",
            "",
            HEADER,
            "|" + "---|" * (HEADER.count("|") - 1),
            *rows(metrics, with_expert=True),
            "",
            curve(a.out / "run"),
            "",
        ]
    )
    (a.out / "table.md").write_text(md)
    print(md)
    return 0


if __name__ == "__main__":
    sys.exit(main())
