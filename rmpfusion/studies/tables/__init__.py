"""Table kinds: how a study's stored jobs become a Markdown table of a results page.

Each kind is a function ``{row label: metrics} -> Markdown`` (rows in the order given, a trailing newline), the same
whether it formats a run just made or the metrics stored under results/.
"""

from __future__ import annotations

from collections.abc import Callable

from . import (
    apg,
    camera,
    dagger,
    expert_design,
    lasa,
    lasa_methods,
    leaves,
    paper_2d,
    recorded_arm,
    task,
    unseen_obstacle,
)

TableKind = Callable[[dict[str, dict]], str]

#: every table kind a study may name, by that name
TABLE_KINDS: dict[str, TableKind] = {
    "paper_2d": paper_2d.table,
    "task": task.table,
    "dagger": dagger.markdown_table,
    "leaves": leaves.table,
    "apg": apg.table_of,
    "expert_design": expert_design.table,
    "lasa": lasa.table_of,
    "lasa_choice": lasa.choice_table,
    "lasa_peer": lasa.peer_table,
    "lasa_methods": lasa_methods.table,
    "recorded_arm": recorded_arm.table,
    "camera": camera.table,
    "unseen_obstacle": unseen_obstacle.table,
}
