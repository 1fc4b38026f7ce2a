"""The experiment's objects from a validated run config: its environment, the expert tree and the learners.

Validation (``validate.py``) builds these once to learn the dimensions it checks; the pipeline's stages build
them to run. Both call the functions here, so what was checked is what runs.
"""

from __future__ import annotations

from collections.abc import Mapping
from contextlib import nullcontext

import torch

from ..assembly.errors import ConfigError, Issue
from ..assembly.tree import build_tree
from ..assembly.weighting import plain_data, tree_with_weights
from ..core.tree import RMPTree
from ..envs.manipulator_tree import copy_weights, with_obstacle_sets
from ..learn.learner import Learner
from ..learn.learners import build_learner, build_order
from ..registry import ENVS
from ..scenes import ObstacleSet, set_dims, sets_read
from .config import RunConfig


def make_env(run: RunConfig):
    """The run's environment, built from its validated block."""
    return ENVS.get(run.env.type).obj(run.env)


def expert_spec(run: RunConfig) -> dict:
    """The tree with the expert's weights: on edges by node name, or replacing a shared weight by its name."""
    return tree_with_weights(run.tree, run.expert, where="expert")


def build_expert(run: RunConfig, aux_dims: Mapping[str, int]) -> RMPTree:
    """The expert tree; a problem with one of the expert's weights is reported at ``expert.<name>``. A run with no
    expert at all (``expert: null``: an experiment on recorded demonstrations, or its quick check on an expert data
    preset) has the tree with every weight 1 as its reference, rather than weights at their random initialisation."""
    if not run.expert:
        return build_unit_weights(run, aux_dims)
    return build_tree(
        expert_spec(run), aux_dims=aux_dims, weight_paths={n: f"expert.{n}" for n in run.expert if n in run.tree.nodes}
    )


def build_unit_weights(run: RunConfig, aux_dims: Mapping[str, int]) -> RMPTree:
    """The run's tree with every edge weight 1: RMPflow, the reference the paper's learned weights are compared
    with. The tree spec may carry weights of its own (the generated Franka tree starts learners' MLPs there): a
    node's own weight is removed (absent = 1) and every shared weight becomes the constant 1. What the tree still
    draws at random (a learned map's initial parameters) is drawn from the run's seed, so the reference is the same
    tree whenever it is built (before training or after it, which consumes the global generator)."""
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(run.seed)
        return _unit_weight_tree(run, aux_dims)


#: a tree learner block whose every learned weight is the constant 1: RMPflow's combination of the tree's leaves
UNIT_WEIGHT_LEARNER = {"type": "rmp", "weights": {"type": "constant", "value": 1.0}}


def _unit_weight_tree(run: RunConfig, aux_dims: Mapping[str, int]) -> RMPTree:
    tree = plain_data(run.tree)
    own = {
        n: None
        for n, node in (tree.get("nodes") or {}).items()
        if isinstance(node.get("weight"), Mapping) and "shared" not in node["weight"]
    }
    shared = {n: {"type": "constant", "value": 1.0} for n in tree.get("shared_weights") or {}}
    return build_tree(tree_with_weights(tree, {**own, **shared}, where="unit weights"), aux_dims=aux_dims)


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
            with seeded(n) if seeded is not None else nullcontext():
                built[n] = build_learner(
                    blocks[n], tree, aux_dims, run.tree.root.dim, expert=expert, built=built, where=f"learners.{n}"
                )
        except ConfigError as e:
            issues += e.issues
        except (ValueError, KeyError, TypeError) as e:
            issues.append(Issue(f"learners.{n}", str(e)))
    if issues:
        raise ConfigError(issues)
    return built


def learner_over_sets(
    run: RunConfig, name: str, trained: Learner, sets: list[ObstacleSet]
) -> tuple[Learner, list[ObstacleSet]]:
    """Learner ``name`` of ``run`` rebuilt on its Fig. 1b tree with the fixed-obstacle edges replaced by run-time
    obstacle ``sets`` (``with_obstacle_sets``), carrying ``trained``'s weights (``copy_weights``, by name), in
    float64; and the sets as its control points read them (``sets_read``), which its aux is made for."""
    spec = with_obstacle_sets(run.tree.model_dump(), sets)
    read = sets_read(sets, sum(1 for n in spec["nodes"] if n.startswith("cp") and n[2:].isdigit()))
    expert = {k: plain_data(w) for k, w in run.expert.items()}
    aux_dims = {"goal": 3, **set_dims(read)}
    learner = build_learner(run.learners[name].model_dump(), spec, aux_dims, run.tree.root.dim, expert=expert)
    assert learner.tree is not None and trained.tree is not None, "a tree learner, built on the run's tree spec"
    copy_weights(trained.tree, learner.tree)
    return learner.to(torch.float64).eval(), read


def build_all(run: RunConfig):
    """``(env, expert_tree, learners)`` for a validated config: everything an experiment runs on. A run with no
    expert (recorded demonstrations) has the configured tree with every weight 1 as its reference."""
    env = make_env(run)
    aux_dims = dict(env.aux_dims())
    return env, build_expert(run, aux_dims), build_learners(run, aux_dims)
