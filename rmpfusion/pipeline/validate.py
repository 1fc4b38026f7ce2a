"""From a composed Hydra config to validated, built objects, with every problem reported at once.

Hydra only merges YAML; nothing it composes is trusted. ``resolve_and_validate`` resolves the config
once, checks it against :class:`RunConfig`, re-checks every registry-typed block with its entry's own
model, and runs the cross-field checks that need several blocks together (aux names against the chosen
environment, expert nodes against the tree, map dimensions against RMP dimensions by building the
tree). All issues are collected into one :class:`ConfigError` whose lines name config paths, so a user
fixes a config in one pass and nothing is ever run on a config that would fail later.
"""
from __future__ import annotations

import copy
import difflib
import re
from typing import Any, Mapping, Sequence

from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import OmegaConfBaseException
from pydantic import ValidationError

from ..registry import ENVS, LEAF_RMPS, LEARNERS, TASK_MAPS, WEIGHTS, Registry
from ..build.errors import ConfigError, Issue, allowed_keys_hint, issues_from_pydantic
from .config import RENAMED_KEYS, RunConfig
from ..build.spec import check_typed, validate_tree_spec

#: Weight-spec keys whose string values (or lists of strings) name aux state.
_AUX_LIST_KEYS = ("aux",)


def _listing(names: Sequence[str], limit: int = 12) -> str:
    names = list(names)
    more = f", ... ({len(names) - limit} more)" if len(names) > limit else ""
    return ", ".join(names[:limit]) + more


def _close(name: str, options: Sequence[str]) -> str:
    close = difflib.get_close_matches(str(name), list(options), n=3, cutoff=0.5)
    return f"did you mean {', '.join(map(repr, close))}? " if close else ""


def _to_container(cfg: DictConfig | Mapping[str, Any]) -> dict[str, Any]:
    if not isinstance(cfg, DictConfig):
        return copy.deepcopy(dict(cfg))
    if "hydra" in cfg:  # Hydra's own node (composed with return_hydra_config) is not the experiment's
        cfg = OmegaConf.masked_copy(cfg, [k for k in cfg if k != "hydra"])
    try:
        data = OmegaConf.to_container(cfg, resolve=True, throw_on_missing=True)
    except OmegaConfBaseException as e:
        key = getattr(e, "full_key", None) or "<config>"
        raise ConfigError([Issue(str(key), f"cannot resolve: {getattr(e, 'msg', None) or e}")]) from None
    return data


def _weight_shorthand(spec: Any, path: str, issues: list[Issue]) -> Any:
    """A bare number is a constant weight; Theorem 2 needs it strictly positive."""
    if isinstance(spec, bool) or not isinstance(spec, (int, float)):
        return spec
    if spec <= 0:
        issues.append(Issue(path, f"constant weight must be > 0 (positive weights are what keep the policy "
                                  f"Lyapunov-stable, Theorem 2); given {spec}"))
    return {"type": "constant", "value": float(spec)}


def _positive_constant(spec: Any, path: str) -> list[Issue]:
    """A friendlier message than pydantic's for the most common weight mistake."""
    if isinstance(spec, Mapping) and spec.get("type") == "constant":
        v = spec.get("value", 1.0)
        if isinstance(v, (int, float)) and not isinstance(v, bool) and v <= 0:
            return [Issue(f"{path}.value", f"constant weight must be > 0 (positive weights are what keep the "
                                           f"policy Lyapunov-stable, Theorem 2); given {v}")]
    return []


def _aux_refs(spec: Any, registry: Registry, path: str) -> list[tuple[str, str]]:
    """(path, aux name) for every parameter of a typed block that names aux state rather than a constant."""
    if not isinstance(spec, Mapping) or spec.get("type") not in registry:
        return []
    fields = registry.get(spec["type"]).params.model_fields
    out = []
    for key, value in spec.items():
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


def _accepts_aux(annotation: Any) -> bool:
    from ..core.auxstate import AuxOrValue

    return annotation == AuxOrValue or annotation == (AuxOrValue | None)


def _check_aux(refs: list[tuple[str, str]], aux_dims: Mapping[str, int], env_type: str) -> list[Issue]:
    issues = []
    for path, name in refs:
        if name == "all" and path.endswith(".aux"):
            continue
        if name not in aux_dims:
            issues.append(Issue(path, f"aux name '{name}' is not provided by the environment '{env_type}'; "
                                      f"{_close(name, list(aux_dims))}it provides: {', '.join(aux_dims) or 'none'}"))
    return issues


def _suggest_key(i: Issue) -> Issue:
    """A misspelt key gets the closest allowed key, like an unknown type gets the closest name."""
    m = re.search(r"\(allowed: ([^)]*)\)", i.message)
    if "unknown key" not in i.message or not m:
        return i
    hint = _close(i.path.rsplit(".", 1)[-1], [k.strip() for k in m.group(1).split(",")])
    return Issue(i.path, f"{i.message}; {hint.strip()}") if hint else i


def _dedupe(issues: list[Issue]) -> list[Issue]:
    out: list[Issue] = []
    for i in map(_suggest_key, issues):
        if any(i.path == o.path or i.path.startswith(o.path + ".") for o in out):
            continue
        out.append(i)
    return out


def _env_aux_dims(run: RunConfig, issues: list[Issue]) -> tuple[Any, dict[str, int] | None]:
    block = run.env.model_dump()
    entry, env_issues = check_typed(block, ENVS, "env")
    issues += env_issues
    if entry is None or env_issues:
        return None, None
    try:
        env = entry.obj(entry.validate({k: v for k, v in block.items() if k != "type"}))
        return env, dict(env.aux_dims())
    except Exception as e:  # noqa: BLE001 - reported with its path
        issues.append(Issue("env", f"could not be created: {e}"))
        return None, None


def _learner_weight_blocks(name: str, block: Mapping[str, Any]) -> list[tuple[str, Any]]:
    """Weight specs a learner will put on the tree: validated against WEIGHTS like the tree's own."""
    w = block.get("weights")
    if isinstance(w, Mapping) and w.get("aux") == "all":  # the learner expands it to every env aux name
        w = {**w, "aux": []}
    return [(f"learners.{name}.weights", w)] if isinstance(w, Mapping) else []


def resolve_and_validate(cfg: DictConfig | Mapping[str, Any]) -> RunConfig:
    """Resolve a composed config once and check everything that can be checked without running.

    Raises one ConfigError listing every problem, each with its config path; returns the frozen
    RunConfig otherwise. Building the trees is part of the check (dimensions are only known then).
    """
    data = _to_container(cfg)
    issues: list[Issue] = []
    # bare-number weights in the expert are shorthand for constants
    if isinstance(data.get("expert"), Mapping):
        data["expert"] = {k: _weight_shorthand(v, f"expert.{k}", issues) for k, v in data["expert"].items()}
    if isinstance(data.get("tree"), Mapping) and isinstance(data["tree"].get("nodes"), Mapping):
        for n, nd in data["tree"]["nodes"].items():
            if isinstance(nd, Mapping) and "weight" in nd:
                nd["weight"] = _weight_shorthand(nd["weight"], f"tree.nodes.{n}.weight", issues)
    for block, names in RENAMED_KEYS.items():  # an old name gets the new one, not "unknown key"
        for old, new in names.items():
            if isinstance(data.get(block), Mapping) and old in data[block]:
                issues.append(Issue(f"{block}.{old}", f"was renamed {block}.{new}; write {block}.{new}="
                                                      f"{data[block][old]!r} instead"))
                data[block] = {k: v for k, v in data[block].items() if k != old}
    if "device" in data and data["device"] != "cpu":  # accepted and never used would be a silent ignore
        issues.append(Issue("device", f"{data['device']!r} is not supported yet: rmpfusion runs on the CPU only "
                                      "(device=cpu); set device=cpu or leave the key out"))
        data["device"] = "cpu"  # the rest of the config is still checked, so every problem is reported at once
    try:
        run = RunConfig.model_validate(data)
    except ValidationError as e:
        found = [Issue(i.path.lstrip(".") or "<config>", i.message) for i in issues_from_pydantic(e, "")]
        found = [Issue(i.path, f"{i.message} (allowed: {', '.join(RunConfig.model_fields)})")
                 if "unknown key" in i.message and "." not in i.path else i for i in found]
        raise ConfigError(_dedupe(issues + found)) from None

    env, aux_dims = _env_aux_dims(run, issues)
    env_type = run.env.type

    # the tree alone: structure and per-entry parameters
    tree_ok = True
    try:
        validate_tree_spec(run.tree, "tree")
    except ConfigError as e:
        issues += e.issues
        tree_ok = False
    nodes = run.tree.get("nodes") if isinstance(run.tree.get("nodes"), Mapping) else {}
    root = (run.tree.get("root") or {}).get("name", "q") if isinstance(run.tree.get("root"), Mapping) else "q"

    # expert: names are edges (nodes) or shared weights of the tree; weights valid
    shared = run.tree.get("shared_weights") if isinstance(run.tree.get("shared_weights"), Mapping) else {}
    for n, w in run.expert.items():
        p = f"expert.{n}"
        if n not in nodes and n not in shared:
            why = "is the root, which has no incoming edge to weight" if n == root else "is not a node of the tree"
            names = [*nodes, *shared]
            issues.append(Issue(p, f"'{n}' {why}; {_close(n, names)}nodes and shared weights: {_listing(names)}"))
            continue
        const = _positive_constant(w, p)
        issues += const or check_typed(w, WEIGHTS, p)[1]

    # learners: each by its own entry's model, plus the weight specs they carry
    for name, block in run.learners.items():
        b = block.model_dump()
        entry, li = check_typed(b, LEARNERS, f"learners.{name}")
        issues += li
        if entry is None or li:
            continue
        for path, w in _learner_weight_blocks(name, b):
            issues += _positive_constant(w, path) or check_typed(w, WEIGHTS, path)[1]
        ref = b.get("match_parameters_of")
        if ref is not None and ref not in run.learners:
            issues.append(Issue(f"learners.{name}.match_parameters_of",
                                f"no learner named '{ref}'; {_close(ref, list(run.learners))}"
                                f"learners: {_listing(run.learners)}"))
        edges = b.get("edges")
        for i, e in enumerate(edges or []):
            if e not in nodes:
                issues.append(Issue(f"learners.{name}.edges[{i}]", f"'{e}' is not a node of the tree; "
                                                                    f"{_close(e, list(nodes))}nodes: {_listing(nodes)}"))

    # aux names against the environment
    if aux_dims is not None:
        refs: list[tuple[str, str]] = []
        bind_names = {k for nd in nodes.values() if isinstance(nd, Mapping) and isinstance(nd.get("weight"), Mapping)
                      for k in (nd["weight"].get("bind") or {})}
        for name, d in (run.tree.get("aux") or {}).items() if isinstance(run.tree.get("aux"), Mapping) else []:
            if name in bind_names and name not in aux_dims:  # a shared weight's placeholder, renamed per edge
                continue
            if name not in aux_dims:
                issues.append(Issue(f"tree.aux.{name}", f"the environment '{env_type}' does not provide aux '{name}'; "
                                                        f"{_close(name, list(aux_dims))}it provides: {', '.join(aux_dims)}"))
            elif int(d) != aux_dims[name]:
                issues.append(Issue(f"tree.aux.{name}", f"declared with dimension {d}, the environment gives {aux_dims[name]}"))
        for n, nd in nodes.items():
            if not isinstance(nd, Mapping):
                continue
            p = f"tree.nodes.{n}"
            refs += _aux_refs(nd.get("map"), TASK_MAPS, f"{p}.map")
            refs += _aux_refs(nd.get("rmp"), LEAF_RMPS, f"{p}.rmp")
            refs += _aux_refs(nd.get("weight"), WEIGHTS, f"{p}.weight")
        for n, w in run.expert.items():
            refs += _aux_refs(w, WEIGHTS, f"expert.{n}")
        for name, block in run.learners.items():
            for path, w in _learner_weight_blocks(name, block.model_dump()):
                refs += _aux_refs(w, WEIGHTS, path)
        placeholders = {n: d for n, d in (run.tree.get("aux") or {}).items() if n in bind_names}
        issues += _check_aux(refs, {**aux_dims, **placeholders}, env_type)

    # dimensions: only knowable by building (maps report their output dimension)
    if tree_ok and aux_dims is not None and not issues:
        issues += _build_issues(run, aux_dims)
    if issues:
        raise ConfigError(_dedupe(issues))
    return run


def expert_spec(run: RunConfig) -> dict:
    """The tree with the expert's weights: on edges by node name, or replacing a shared weight by its name."""
    from ..build.weighting import tree_with_weights

    return tree_with_weights(run.tree, run.expert, where="expert")


def _build_issues(run: RunConfig, aux_dims: Mapping[str, int]) -> list[Issue]:
    """Build the expert tree and the learners once, turning build errors into path-named issues."""
    from ..build.tree import build_tree

    issues: list[Issue] = []
    try:
        build_tree(expert_spec(run), aux_dims=aux_dims)
    except ConfigError as e:
        for i in e.issues:  # an expert weight's problem belongs to expert.<node>, not the tree
            head = i.path.split(".weight")[0]
            if i.path.startswith("tree.nodes.") and i.path.endswith(".weight") and head[len("tree.nodes."):] in run.expert:
                issues.append(Issue(f"expert.{head[len('tree.nodes.'):]}", i.message))
            else:
                issues.append(i)
    if issues:
        return issues
    try:
        _build_learners(run, aux_dims)
    except ConfigError as e:
        issues += e.issues
    return issues


def _build_learners(run: RunConfig, aux_dims: Mapping[str, int]) -> dict:
    from ..learn.learners import build_learner, build_order

    blocks = {n: b.model_dump() for n, b in run.learners.items()}
    built: dict = {}
    issues: list[Issue] = []
    dim = int(run.tree["root"]["dim"])
    for n in build_order(blocks):
        try:
            built[n] = build_learner(blocks[n], run.tree, aux_dims, dim, expert=run.expert, built=built,
                                     where=f"learners.{n}")
        except ConfigError as e:
            for i in e.issues:  # the learner's weights on an edge: name the learner's own key
                if i.path.startswith("tree.nodes.") and i.path.endswith(".weight"):
                    edge = i.path[len("tree.nodes."):-len(".weight")]
                    issues.append(Issue(f"learners.{n}.weights", f"on edge '{edge}': {i.message}"))
                else:
                    issues.append(i)
        except (ValueError, KeyError, TypeError) as e:
            issues.append(Issue(f"learners.{n}", str(e)))
    if issues:
        raise ConfigError(issues)
    return built


def build_all(run: RunConfig):
    """``(env, expert_tree, learners)`` for a validated config: everything an experiment runs on."""
    from ..build.tree import build_tree

    entry = ENVS.get(run.env.type)
    block = run.env.model_dump()
    env = entry.obj(entry.validate({k: v for k, v in block.items() if k != "type"}))
    aux_dims = dict(env.aux_dims())
    expert = build_tree(expert_spec(run), aux_dims=aux_dims)
    learners = _build_learners(run, aux_dims)
    return env, expert, learners

