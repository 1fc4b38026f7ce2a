"""A run configuration composed from conf/ as the commands compose it: the one place outside a Hydra app that does.

conf/ lives at the repository root (docs/architecture.md §1), outside the package, so it is resolved from this
file's location: that works for a source checkout and an editable install from any working directory, and a wheel
carries a copy inside the package (``rmpfusion/conf/``). ``RMPFUSION_CONF`` points everything at another conf/ (a
wheel install, or a project's own copy). Nothing here runs on import.

``compose_config`` gives the merged YAML (neither resolved nor validated, as Hydra hands it to a job);
``compose_run`` gives the validated ``RunConfig`` every command runs on.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from .config import RunConfig
from .validate import resolve_and_validate

__all__ = ["compose_config", "compose_run", "conf_dir"]


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
    candidates = [here.parents[2] / "conf", here.parents[1] / "conf"]  # the checkout's, then a wheel's copy
    for c in candidates:
        if (c / "config.yaml").is_file():
            return str(c)
    tried = ", ".join(str(c) for c in candidates)
    raise FileNotFoundError(
        f"rmpfusion: no conf/config.yaml found (tried {tried}); set RMPFUSION_CONF to your conf/ directory"
    )


def compose_config(
    overrides: Sequence[str] = (),
    config_dir: Path | None = None,
    *,
    conf: str | Path | None = None,
    hydra_config: bool = False,
) -> Any:
    """conf/config.yaml composed with ``overrides`` as the commands compose it, outside a Hydra app (neither resolved
    nor validated); ``config_dir`` joins the search path as Hydra's ``--config-dir`` does (a user's robot files),
    ``conf`` replaces conf/ itself (default ``conf_dir()``), and ``hydra_config`` keeps the ``hydra`` node."""
    from hydra import compose, initialize_config_dir

    search = [f"hydra.searchpath=[file://{config_dir.resolve()}]"] if config_dir is not None else []
    root = str(Path(conf).resolve()) if conf is not None else conf_dir()
    with initialize_config_dir(config_dir=root, version_base="1.3"):
        return compose(config_name="config", overrides=[*overrides, *search], return_hydra_config=hydra_config)


def compose_run(
    overrides: Sequence[str] = (), config_dir: Path | None = None, *, conf: str | Path | None = None
) -> RunConfig:
    """The validated run config of ``overrides`` (``compose_config`` then ``resolve_and_validate``): what
    ``rmpfusion-run`` with these overrides runs on, or one ``ConfigError`` listing every problem."""
    return resolve_and_validate(compose_config(overrides, config_dir, conf=conf))
