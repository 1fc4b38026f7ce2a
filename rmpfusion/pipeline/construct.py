"""The experiment's objects from a validated run config: its environment, the expert tree and the learners.

Validation (``validate.py``) builds these once to learn the dimensions it checks; the pipeline's stages build
them to run. Both call the functions here, so what was checked is what runs.
"""
from __future__ import annotations

from contextlib import nullcontext
from typing import Mapping

from ..assembly.errors import ConfigError, Issue
from ..assembly.tree import build_tree
from ..assembly.weighting import plain_data, tree_with_weights
from ..core.tree import RMPTree
from ..learn.learners import build_learner, build_order
from ..registry import ENVS
from .config import RunConfig


def make_env(run: RunConfig):
    """The run's environment, built from its validated block."""
    return ENVS.get(run.env.type).obj(run.env)


def expert_spec(run: RunConfig) -> dict:
    """The tree with the expert's weights: on edges by node name, or replacing a shared weight by its name."""
    return tree_with_weights(run.tree, run.expert, where="expert")


def build_expert(run: RunConfig, aux_dims: Mapping[str, int]) -> RMPTree:
    """The expert tree; a problem with one of the expert's weights is reported at ``expert.<name>``."""
    return build_tree(expert_spec(run), aux_dims=aux_dims,
                      weight_paths={n: f"expert.{n}" for n in run.expert if n in run.tree.nodes})


def build_learners(run: RunConfig, aux_dims: Mapping[str, int], seeded=None) -> dict:
    """Every learner, in an order where ``match_parameters_of`` targets come first. ``seeded(name)`` is a
    context entered around each construction (the pipeline draws each learner's initial weights from its
    own seed); problems are reported at ``learners.<name>``."""
    blocks = {n: b.model_dump() for n, b in run.learners.items()}
    tree, expert = run.tree.model_dump(), {k: plain_data(w) for k, w in run.expert.items()}
    built: dict = {}
    issues: list[Issue] = []
    for n in build_order(blocks):
        try:
            with (seeded(n) if seeded is not None else nullcontext()):
                built[n] = build_learner(blocks[n], tree, aux_dims, run.tree.root.dim, expert=expert,
                                         built=built, where=f"learners.{n}")
        except ConfigError as e:
            issues += e.issues
        except (ValueError, KeyError, TypeError) as e:
            issues.append(Issue(f"learners.{n}", str(e)))
    if issues:
        raise ConfigError(issues)
    return built


def build_all(run: RunConfig):
    """``(env, expert_tree, learners)`` for a validated config: everything an experiment runs on."""
    env = make_env(run)
    aux_dims = dict(env.aux_dims())
    return env, build_expert(run, aux_dims), build_learners(run, aux_dims)
