"""Hydra entry points (console scripts): validate, run the whole pipeline, or one stage of it.

``rmpfusion.cli.CONF_DIR`` is the conf/ directory the commands compose from, for composing the same configs from
Python: ``$RMPFUSION_CONF`` if set, else the conf/ of the source checkout rmpfusion is imported from (a clone or an
editable install; see ``rmpfusion.pipeline.compose``, whose ``compose_config`` and ``compose_run`` compose them). It
is looked up when read, so importing a submodule never needs it.
"""

from ..pipeline.compose import conf_dir

__all__ = ["CONF_DIR"]  # the console scripts are the package's interface; CONF_DIR is looked up when read


def __getattr__(name: str):
    if name == "CONF_DIR":
        return conf_dir()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
