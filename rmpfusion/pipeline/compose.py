"""A run configuration composed from conf/ as the commands compose it: the one place outside a Hydra app that does.

conf/ is found by ``rmpfusion/confdir.py::conf_dir`` (``RMPFUSION_CONF``, else the checkout's, else a wheel's copy),
re-exported here; nothing runs on import.

``compose_config`` gives the merged YAML (neither resolved nor validated, as Hydra hands it to a job);
``compose_run`` gives the validated ``RunConfig`` every command runs on.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

from ..confdir import conf_dir
from .config import RunConfig
from .validate import resolve_and_validate

__all__ = ["compose_config", "compose_run", "conf_dir"]


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
