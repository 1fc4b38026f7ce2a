"""What every entry point shares: where conf/ is, the run directory, and turning config errors into exit codes.

conf/ lives at the repository root (DESIGN.md §2), outside the package, so the apps resolve it from this
file's location: that works for a source checkout and an editable install from any working directory.
``RMPFUSION_CONF`` points the apps at another conf/ (a wheel install, or a project's own copy).
"""
from __future__ import annotations

import contextlib
import os
import sys
from pathlib import Path
from typing import Iterator

#: Exit code of a command whose configuration is invalid (nothing was run).
CONFIG_ERROR_EXIT = 2


def conf_dir() -> str:
    env = os.environ.get("RMPFUSION_CONF")
    candidates = [Path(env)] if env else []
    here = Path(__file__).resolve()
    candidates += [here.parents[2] / "conf", here.parents[1] / "conf"]
    for c in candidates:
        if (c / "config.yaml").is_file():
            return str(c)
    tried = ", ".join(str(c) for c in candidates)
    raise FileNotFoundError(f"rmpfusion: no conf/config.yaml found (tried {tried}); set RMPFUSION_CONF to your conf/ directory")


CONF_DIR = conf_dir()


@contextlib.contextmanager
def config_errors_exit() -> Iterator[None]:
    """Print configuration problems as the user should read them (paths and fixes), no traceback."""
    from ..config.errors import ConfigError
    from ..registry import RegistryError

    try:
        yield
    except ConfigError as e:
        print(f"error: {e}", file=sys.stderr)
        sys.exit(CONFIG_ERROR_EXIT)
    except RegistryError as e:
        print(f"error: {e}", file=sys.stderr)
        sys.exit(CONFIG_ERROR_EXIT)


def hydra_run_dir() -> Path:
    from hydra.core.hydra_config import HydraConfig

    return Path(HydraConfig.get().runtime.output_dir)


def save_resolved(run, run_dir: Path) -> Path:
    """The resolved, validated config beside Hydra's unresolved copy: what actually ran."""
    import yaml

    path = run_dir / "config.resolved.yaml"
    run_dir.mkdir(parents=True, exist_ok=True)
    path.write_text(yaml.safe_dump(run.model_dump(mode="json"), sort_keys=False))
    return path
