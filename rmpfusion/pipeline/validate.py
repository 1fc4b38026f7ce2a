"""From a composed Hydra config to validated, built objects, with every problem reported at once.

Hydra only merges YAML; nothing it composes is trusted. ``resolve_and_validate`` resolves the config once,
validates it against the run schema generated from the registries (``run_config_model``: every registry-
typed block by its entry's own model), then runs the cross-field checks that need several blocks together:
aux names against the chosen environment, expert names against the tree, learners against each other and
the tree, map dimensions against RMP dimensions by building the trees. All issues are collected into one
:class:`ConfigError` whose lines name config paths, so a user fixes a config in one pass and nothing is ever
run on a config that would fail later.

Of the three jobs between a composed config and a run, this module is the middle one: ``migrate.py`` answers
keys and names that stored configs still carry, ``construct.py`` builds the experiment's objects.
"""

from __future__ import annotations

import difflib
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import torch
from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import OmegaConfBaseException
from pydantic import BaseModel, ValidationError

from ..assembly.errors import ConfigError, Issue, issues_from_pydantic
from ..assembly.generated import expand_tree
from ..assembly.spec import check_typed, validate_tree_spec
from ..assembly.weighting import own_weights, weights_by_name
from ..core.auxstate import AuxOrValue
from ..envs.protocol import JointSpace, LearnsFromRecordings
from ..recordings.recording import Recording, RecordingError
from ..recordings.source import on_grid_for, read_recordings
from ..recordings.splits import split_of
from ..registry import ENVS, LEAF_RMPS, TASK_MAPS, TRAIN_METHODS, WEIGHTS, Registry
from .config import RunConfig, run_config_model
from .construct import build_expert, build_learners
from .migrate import renamed_issues, retired_issues
from .obstacle_entries import ObstacleEntryError, apply_policy

#: Weight-spec keys whose string values (or lists of strings) name aux state.
_AUX_LIST_KEYS = ("aux",)


def _listing(names: Iterable[str], limit: int = 12) -> str:
    names = list(names)
    more = f", ... ({len(names) - limit} more)" if len(names) > limit else ""
    return ", ".join(names[:limit]) + more


def _close(name: str, options: Sequence[str]) -> str:
    close = difflib.get_close_matches(str(name), list(options), n=3, cutoff=0.5)
    return f"did you mean {', '.join(map(repr, close))}? " if close else ""


def _run_data(container: object) -> dict[str, Any]:
    """The plain container of a resolved config: a dict, as every DictConfig's is. Its keys are the names a YAML
    author wrote; one that is not a string is the schema's to refuse, by its path."""
    assert isinstance(container, dict)
    return container


def _to_container(cfg: DictConfig | Mapping[str, Any]) -> dict[str, Any]:
    if not isinstance(cfg, DictConfig):
        return _run_data(OmegaConf.to_container(OmegaConf.create(dict(cfg)), resolve=True))  # a deep, plain copy
    if "hydra" in cfg:  # Hydra's own node (composed with return_hydra_config) is not the experiment's
        # omegaconf's annotation says string keys; it keeps whichever keys of the config it is given
        cfg = OmegaConf.masked_copy(cfg, [k for k in cfg if k != "hydra"])  # type: ignore[misc]
    try:
        return _run_data(OmegaConf.to_container(cfg, resolve=True, throw_on_missing=True))
    except OmegaConfBaseException as e:
        key = getattr(e, "full_key", None) or "<config>"
        raise ConfigError([Issue(str(key), f"cannot resolve: {getattr(e, 'msg', None) or e}")]) from None


def _device_issues(data: dict[str, Any]) -> list[Issue]:
    """A device this machine does not have is named, never ignored; the rest is checked as on the CPU."""
    missing = device_problem(data.get("device", "cpu"))
    if missing is None:
        return []
    data["device"] = "cpu"
    return [Issue("device", missing)]


def device_problem(device: Any) -> str | None:
    """Why this machine cannot compute on ``device`` (None: it can). The form itself is the schema's to check."""
    if not isinstance(device, str) or not device.startswith("cuda"):
        return None
    if not torch.cuda.is_available():
        why = "this torch has no CUDA build" if torch.version.cuda is None else "no CUDA GPU is visible"
        return f"{device!r} is not available here ({why}); set device=cpu, or run where a GPU is"
    index = int(device.split(":")[1]) if ":" in device else 0
    if index >= torch.cuda.device_count():
        return (
            f"{device!r} is not available here: this machine has {torch.cuda.device_count()} CUDA device(s), "
            f"cuda:0 to cuda:{torch.cuda.device_count() - 1}; choose one of them"
        )
    return None


def _expanded_tree(data: dict[str, Any]) -> list[Issue]:
    """A tree declared as a generator and its parameters becomes the tree it generates."""
    if not isinstance(data.get("tree"), Mapping):
        return []
    try:
        data["tree"] = expand_tree(data["tree"])
    except ConfigError as e:
        return e.issues
    return []


def _dedupe(issues: list[Issue]) -> list[Issue]:
    """One issue per place: a problem found again inside one already reported is left out, and so is a problem
    of the tree's robot or scene that the environment's, which the tree reads (``${env.robot}``), already has."""
    out: list[Issue] = []
    for i in issues:
        if any(i.path == o.path or i.path.startswith(o.path + ".") for o in out):
            continue
        if any(
            i.path.startswith(f"tree.{k}")
            and o.path.startswith(f"env.{k}")
            and o.message.split(" (given")[0] == i.message.split(" (given")[0]
            for o in issues
            for k in ("robot", "scene")
        ):
            continue
        out.append(i)
    return out


def parse_run_config(data: Mapping[str, Any]) -> RunConfig:
    """The typed run config of plain data (a checkpoint's or run directory's stored config, or a resolved
    Hydra config), or one ConfigError naming every schema problem."""
    model = run_config_model()
    try:
        return model.model_validate(dict(data))
    except ValidationError as e:
        raise ConfigError(_dedupe(retired_issues(data) + issues_from_pydantic(e, "", model))) from None


def typed(run: RunConfig) -> RunConfig:
    """``run`` with every registry-typed block its entry's model: a config built in Python as the static
    ``RunConfig`` is validated by the registries here, before anything is built from it."""
    return run if isinstance(run, run_config_model()) else parse_run_config(run.model_dump())


# ------------------------------------------------------------------ cross-field checks
def _make_env(data: Mapping[str, Any]) -> tuple[Any, list[Issue]]:
    """The config's environment (None if it cannot be made: its problems are reported by the schema, or here
    when creating it fails)."""
    block, _ = check_typed(data.get("env"), ENVS, "env")
    if block is None:
        return None, []
    try:
        return ENVS.get(block.type).obj(block), []
    except Exception as e:  # noqa: BLE001 - reported with its path
        return None, [Issue("env", f"could not be created: {e}")]


def _method_issues(run: RunConfig, env: Any, recordings: list[Recording] | None) -> list[Issue]:
    """What the training method needs of the run (an environment it can roll out in, enough demonstrations);
    ``recordings``: the recorded demonstrations read (None when there are none, or when they could not be read)."""
    method = TRAIN_METHODS.get(run.train.method).obj
    if run.data.source == "recorded":
        if not method.from_recordings or recordings is None:  # the config model refuses a method needing an expert
            return []
        # a recorded split is drawn when the run starts: every recording bounds the training ones
        return [Issue(path, message) for path, message in method.requirements(run.train, env, len(recordings))]
    return [
        Issue(path, message)
        for path, message in method.requirements(run.train, env, run.data.train_envs * run.data.train_trajectories)
    ]


def _recordings_checked(run: RunConfig, env: Any) -> tuple[list[Recording] | None, list[Issue]]:
    """Recorded demonstrations read now (they are small), so a bad file is said before anything runs: the
    reader's message names the file, row and column; a dimension unlike the environment's is said too,
    joint-space recordings are checked against the robot file (joint count, names, limits), and recordings that
    enter an obstacle of the run's world are refused unless ``data.obstacle_entries`` says otherwise (said beside a
    split the recordings cannot make, both being problems to fix). Returns the recordings (None for a run on the
    expert's demonstrations, or one whose files cannot be read) and the problems."""
    if run.data.source != "recorded":
        return None, []
    robot = env.robot_description if isinstance(env, JointSpace) else None
    try:
        recordings = read_recordings(run.data, robot.joints if robot is not None else None)
    except RecordingError as e:
        return None, [Issue("data", str(e))]
    issues = []
    try:
        states = on_grid_for(recordings, run.data, env.dt, env.dim, run.env.type, robot, env.aux_dims())
        if isinstance(env, LearnsFromRecordings):  # else the collect stage refuses the environment, naming it
            try:
                states = apply_policy(env, states, run.data.obstacle_entries)[0]
            except ObstacleEntryError as e:  # refused, not dropped: every recording still counts for the split
                issues.append(Issue("data.obstacle_entries", str(e)))
        split_of(run.data, len(states), run.seed)
    except RecordingError as e:
        issues.append(Issue("data", str(e)))
    return recordings, issues


def _expert_issues(run: RunConfig) -> list[Issue]:
    """Expert keys are edges (nodes), shared weights or roles of the tree (already expanded to the names they cover),
    and every weight the tree carries itself is replaced by one of them."""
    nodes, shared, root, roles = run.tree.nodes, run.tree.shared_weights, run.tree.root.name, run.tree.roles
    issues = []
    role_note = f"; roles: {', '.join(roles)}" if roles else ""
    for n in run.expert:
        if n not in nodes and n not in shared:
            why = "is the root, which has no incoming edge to weight" if n == root else "is not a node of the tree"
            names = [*nodes, *shared, *roles]
            issues.append(
                Issue(
                    f"expert.{n}",
                    f"'{n}' {why}; {_close(n, names)}nodes and shared weights: "
                    f"{_listing([*nodes, *shared])}{role_note}",
                )
            )
    missing = [n for n in own_weights(run.tree) if n not in run.expert]
    if missing:
        by_role = {n: r for r, members in roles.items() for n in members}
        said = ", ".join(f"{n} (role {by_role[n]})" if n in by_role else n for n in missing)
        issues.append(
            Issue(
                "expert",
                f"no expert weight for {said}: the tree carries a learnable weight there, which "
                f"the expert would keep at its random initialisation; give each by name or by "
                f"its role",
            )
        )
    return issues


def _learner_weight_blocks(name: str, learner: Any) -> list[tuple[str, Any]]:
    """Weight specs a learner will put on the tree: validated against WEIGHTS like the tree's own."""
    w = (learner if isinstance(learner, Mapping) else learner.model_dump()).get("weights")
    if isinstance(w, Mapping) and w.get("aux") == "all":  # the learner expands it to every env aux name
        w = {**w, "aux": []}
    return [(f"learners.{name}.weights", w)] if isinstance(w, Mapping) else []


def _learner_issues(run: RunConfig) -> list[Issue]:
    """Learners' weight specs, ``match_parameters_of`` targets and edge names."""
    nodes = run.tree.nodes
    issues = []
    for name, learner in run.learners.items():
        block = learner.model_dump()  # learners of different types carry different keys
        for path, w in _learner_weight_blocks(name, block):
            issues += check_typed(w, WEIGHTS, path)[1]
        ref = block.get("match_parameters_of")
        if ref is not None and ref not in run.learners:
            issues.append(
                Issue(
                    f"learners.{name}.match_parameters_of",
                    f"no learner named '{ref}'; {_close(ref, list(run.learners))}learners: {_listing(run.learners)}",
                )
            )
        for i, e in enumerate(block.get("edges") or []):
            if e not in nodes:
                issues.append(
                    Issue(
                        f"learners.{name}.edges[{i}]",
                        f"'{e}' is not a node of the tree; {_close(e, list(nodes))}nodes: {_listing(nodes)}",
                    )
                )
    return issues


def _accepts_aux(annotation: Any) -> bool:
    return annotation == AuxOrValue or annotation == (AuxOrValue | None)


def _aux_refs(block: Any, registry: Registry, path: str) -> list[tuple[str, str]]:
    """(path, aux name) for every parameter of a ``{type: ..., ...}`` block that names aux state rather than a
    constant, read from the entry's own parameter model (raw data: these checks also run when the schema
    found other problems, so every problem is reported at once)."""
    if isinstance(block, BaseModel):
        block = block.model_dump()
    if not isinstance(block, Mapping) or not isinstance(block.get("type"), str) or block["type"] not in registry:
        return []  # no entry to read (a type that is no name, e.g. a list, is the schema's to report)
    fields = registry.get(block["type"]).params.model_fields
    out = []
    for key, value in block.items():
        if key == "type" or key not in fields:
            continue
        if key in _AUX_LIST_KEYS and isinstance(value, list):
            out += [(f"{path}.{key}[{i}]", v) for i, v in enumerate(value) if isinstance(v, str)]
        elif isinstance(value, str) and _accepts_aux(fields[key].annotation):
            out.append((f"{path}.{key}", value))
        elif key == "maps" and isinstance(value, list):  # compose: stages are typed maps themselves
            for i, stage in enumerate(value):
                out += _aux_refs(stage, TASK_MAPS, f"{path}.maps[{i}]")
    return out


def _mapping(x: Any) -> Mapping:
    return x if isinstance(x, Mapping) else {}


def _tree_aux_refs(data: Mapping[str, Any]) -> list[tuple[str, str]]:
    refs = []
    for n, nd in _mapping(_mapping(data.get("tree")).get("nodes")).items():
        for part, registry in (("map", TASK_MAPS), ("rmp", LEAF_RMPS), ("weight", WEIGHTS)):
            refs += _aux_refs(_mapping(nd).get(part), registry, f"tree.nodes.{n}.{part}")
    for n, w in _mapping(data.get("expert")).items():
        refs += _aux_refs(w, WEIGHTS, f"expert.{n}")
    for name, learner in _mapping(data.get("learners")).items():
        for path, w in _learner_weight_blocks(name, _mapping(learner)):
            refs += _aux_refs(w, WEIGHTS, path)
    return refs


def _bind_placeholders(data: Mapping[str, Any]) -> set[str]:
    """Aux names a shared weight reads that each edge renames (``bind``): declared, never provided."""
    nodes = _mapping(_mapping(data.get("tree")).get("nodes")).values()
    return {k for nd in nodes for k in _mapping(_mapping(_mapping(nd).get("weight")).get("bind"))}


def _aux_issues(data: Mapping[str, Any], env_type: str, aux_dims: Mapping[str, int]) -> list[Issue]:
    """Every aux name the tree, the expert and the learners read is one the environment provides."""
    binds, declared = _bind_placeholders(data), _mapping(_mapping(data.get("tree")).get("aux"))
    issues = []
    for name, d in declared.items():
        if name in binds and name not in aux_dims:
            continue
        if name not in aux_dims:
            issues.append(
                Issue(
                    f"tree.aux.{name}",
                    f"the environment '{env_type}' does not provide aux '{name}'; "
                    f"{_close(name, list(aux_dims))}it provides: {', '.join(aux_dims)}",
                )
            )
        elif int(d) != aux_dims[name]:
            issues.append(
                Issue(f"tree.aux.{name}", f"declared with dimension {d}, the environment gives {aux_dims[name]}")
            )
    known = {**aux_dims, **{n: d for n, d in declared.items() if n in binds}}
    for path, name in _tree_aux_refs(data):
        if name == "all" and path.endswith(".aux"):
            continue
        if name not in known:
            issues.append(
                Issue(
                    path,
                    f"aux name '{name}' is not provided by the environment '{env_type}'; "
                    f"{_close(name, list(known))}it provides: {', '.join(known) or 'none'}",
                )
            )
    return issues


def _build_issues(run: RunConfig, aux_dims: Mapping[str, int]) -> list[Issue]:
    """Build the expert tree and the learners once: dimensions are only known then."""
    try:
        build_expert(run, aux_dims)
        build_learners(run, aux_dims)
    except ConfigError as e:
        return e.issues
    return []


def resolve_and_validate(cfg: DictConfig | Mapping[str, Any]) -> RunConfig:
    """Resolve a composed config once and check everything that can be checked without running.

    Raises one ConfigError listing every problem, each with its config path; returns the typed RunConfig
    otherwise. Building the trees is part of the check (dimensions are only known then).
    """
    data = _to_container(cfg)
    retired = retired_issues(data)
    generation = _expanded_tree(data)
    issues = retired + renamed_issues(data) + _device_issues(data) + generation
    env, env_issues = _make_env(data)
    aux_dims = dict(env.aux_dims()) if env is not None else None
    issues += env_issues
    if aux_dims is not None:
        issues += _aux_issues(data, str(_mapping(data.get("env")).get("type")), aux_dims)
    try:
        run = parse_run_config(data)
    except ConfigError as e:
        found = e.issues
        if generation:  # a tree that could not be generated: the schema's view of its declaration is noise
            found = [i for i in found if not (i.path == "tree" or i.path.startswith("tree."))]
        raise ConfigError(_dedupe(issues + found)) from None
    try:
        validate_graph(run)
    except ConfigError as e:
        issues += e.issues
    run = run.model_copy(update={"expert": weights_by_name(run.tree, run.expert)})  # roles -> the names they cover
    # no expert at all (recorded demonstrations): the reference is the tree with every weight 1 (build_expert)
    issues += (_expert_issues(run) if run.expert else []) + _learner_issues(run)
    if env is not None:
        recordings, recording_issues = _recordings_checked(run, env)
        issues += _method_issues(run, env, recordings) + recording_issues
    if aux_dims is not None and not issues:
        issues += _build_issues(run, aux_dims)
    if issues:
        raise ConfigError(_dedupe(issues))
    return run


def validate_graph(run: RunConfig) -> None:
    """The tree's graph checks (rooted, leaves carry rmps, shared weights declared)."""
    validate_tree_spec(run.tree, "tree")
