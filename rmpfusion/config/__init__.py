"""Schemas and validation: configs become frozen pydantic models with errors that name their YAML path."""
from .errors import ConfigError, Issue  # noqa: F401
from .tree_spec import TreeSpec, validate_tree_spec  # noqa: F401
