"""Stored configs written before a key or a name changed: what to write instead, never "unknown key".

A checkpoint or run directory embeds the config it was made with; when a later rmpfusion renamed a key or
retired a name, that config must be answered with its replacement. These checks run before the schema, on
plain data, and remove what they reported so the rest of the config is still checked at once.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from ..assembly.errors import Issue
from .config import RENAMED_KEYS

#: (block, key, value) of names that configs stored before robots and scenes became data still carry -> what to
#: write instead (the experiments and config groups of conf/ kept their names: compose them anew)
RETIRED = {
    ("env", "type", "franka"): "the environment 'franka' became 'manipulator', which takes its robot and scene from "
    "conf/robot/ and conf/scene/; compose the experiment anew (experiment=franka keeps "
    "its name and protocol)",
    ("tree", "generator", "franka_fig1b"): "the generator 'franka_fig1b' became 'arm_reach', which takes the robot and "
    "the scene (conf/tree/arm_reach.yaml reads the environment's); compose the experiment anew (tree=franka keeps its "
    "name)",
    ("tree", "generator", "fig1b"): "the generator 'fig1b' (named after the paper's figure) became 'arm_reach', the "
    "same tree for any robot and scene; write generator: arm_reach (tree=arm_reach for conf/tree/arm_reach.yaml)",
}


def retired_issues(data: Mapping[str, Any]) -> list[Issue]:
    """A stored config naming a retired environment or generator gets what to write instead, not 'unknown name'."""
    return [
        Issue(f"{block}.{key}", f"{value!r} was retired: {fix}")
        for (block, key, value), fix in RETIRED.items()
        if isinstance(data.get(block), Mapping) and data[block].get(key) == value
    ]


def renamed_issues(data: dict[str, Any]) -> list[Issue]:
    """Renamed keys get their new name (not "unknown key"); they are removed from ``data`` so the rest of the
    config is still checked and every problem reported."""
    issues = []
    for block, names in RENAMED_KEYS.items():
        for old, new in names.items():
            if isinstance(data.get(block), Mapping) and old in data[block]:
                issues.append(
                    Issue(
                        f"{block}.{old}", f"was renamed {block}.{new}; write {block}.{new}={data[block][old]!r} instead"
                    )
                )
                data[block] = {k: v for k, v in data[block].items() if k != old}
    return issues
