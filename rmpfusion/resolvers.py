"""OmegaConf resolvers the shipped configs use, registered when rmpfusion is imported.

``rmpfusion.set_or``: ``${rmpfusion.set_or:data.shape,recorded}`` is the value at ``data.shape`` unless that key is
missing *or null*, then the default. OmegaConf's own ``oc.select`` falls back only on a missing key, so a block that
lists every key with null for "unset" (conf/data/recorded.yaml) would name a run ``lasa_None``.
"""

from __future__ import annotations

from typing import Any

from omegaconf import OmegaConf


def _set_or(key: str, default: Any = None, *, _root_: Any) -> Any:
    value = OmegaConf.select(_root_, key, default=None)
    return default if value is None else value


def register() -> None:
    """Register the resolvers (again is harmless: an existing registration is replaced by the same function)."""
    OmegaConf.register_new_resolver("rmpfusion.set_or", _set_or, replace=True)


register()
