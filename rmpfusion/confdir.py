"""Where conf/ is: the configs every command composes and the robot files (conf/robot/) the maps' examples read.

conf/ lives at the repository root (docs/architecture.md §1), outside the package, so it is resolved from this
file's location: that works for a source checkout and an editable install from any working directory, and a wheel
carries a copy inside the package (``rmpfusion/conf/``). ``RMPFUSION_CONF`` points everything at another conf/ (a
wheel install, or a project's own copy). It is looked up when asked for, never on import.
"""

from __future__ import annotations

import os
from pathlib import Path

__all__ = ["conf_dir"]


def conf_dir() -> str:
    """conf/ of the checkout (or ``RMPFUSION_CONF``). A ``RMPFUSION_CONF`` that holds no config.yaml is an error,
    never passed over for the checkout's: the user meant that directory."""
    env = os.environ.get("RMPFUSION_CONF")
    if env:
        if (Path(env) / "config.yaml").is_file():
            return env
        what = "does not exist" if not Path(env).exists() else "holds no config.yaml"
        raise FileNotFoundError(
            f"RMPFUSION_CONF={env} {what}; point it at a conf/ directory (one with config.yaml, "
            "like the checkout's conf/) or unset it to use the checkout's"
        )
    here = Path(__file__).resolve()
    candidates = [here.parents[1] / "conf", here.parents[0] / "conf"]  # the checkout's, then a wheel's copy
    for c in candidates:
        if (c / "config.yaml").is_file():
            return str(c)
    tried = ", ".join(str(c) for c in candidates)
    raise FileNotFoundError(
        f"rmpfusion: no conf/config.yaml found (tried {tried}); set RMPFUSION_CONF to your conf/ directory"
    )
