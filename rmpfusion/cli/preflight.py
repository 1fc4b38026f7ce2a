"""Before a Hydra app runs: compose the command line's config once and say what is wrong in a line or two.

Hydra reports a misspelt config group, a missing config file, a YAML syntax error or an override it cannot
parse in its own words (a traceback for YAML, "use +key" for a misspelt group). This module composes the same
config first, through Hydra's public compose API, and turns those failures into messages naming the file,
key or path and the fix, with the closest names where one was misspelt. A sweep (``-m a=1,2``) is checked on
its first job. Only then does the app start, so nothing is created for a command that cannot run.
"""

from __future__ import annotations

import difflib
import functools
import re
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml
from hydra import compose, initialize_config_dir
from hydra.core.override_parser.overrides_parser import OverridesParser
from hydra.core.override_parser.types import Glob
from hydra.errors import ConfigCompositionException, HydraException, MissingConfigException, OverrideParseException

from ..assembly.errors import closest

#: Hydra's flags that take a value, and those that ask Hydra for something else than a run (help, the config).
_VALUED_FLAGS = {"--config-dir", "-cd", "--config-path", "-cp", "--config-name", "-cn", "--experimental-rerun"}
_INFO_FLAGS = {"-h", "--help", "--hydra-help", "--info", "-i", "--cfg", "-c", "--shell-completion", "-sc", "--version"}


class CommandLineError(ValueError):
    """The command line cannot compose into a config; the message says where and what to write instead."""


_PLAIN_FLAGS = {"-m", "--multirun", "--resolve", "-p", "--package"}


@dataclass
class CommandLine:
    overrides: list[str]
    config_dir: str | None = None
    informational: bool = False
    unknown_flags: list[str] = field(default_factory=list)  # "--experiment 2d1level": an argparse habit


def split_argv(argv: list[str]) -> CommandLine:
    """Hydra's flags apart from the overrides."""
    out, i = CommandLine([]), 0
    while i < len(argv):
        arg, value = argv[i], None
        name = arg.split("=", 1)[0]
        if name in _INFO_FLAGS:
            out.informational = True
        elif name in _VALUED_FLAGS:
            value = arg.split("=", 1)[1] if "=" in arg else (argv[i + 1] if i + 1 < len(argv) else None)
            i += 0 if "=" in arg else 1
            if name in ("--config-dir", "-cd"):
                out.config_dir = value
        elif arg.startswith("-") and name not in _PLAIN_FLAGS and not re.fullmatch(r"-\d.*", arg):
            taken = "=" not in arg and i + 1 < len(argv) and not argv[i + 1].startswith("-") and "=" not in argv[i + 1]
            out.unknown_flags.append(f"{arg} {argv[i + 1]}" if taken else arg)
            i += 1 if taken else 0
        elif not arg.startswith("-"):
            out.overrides.append(arg)
        i += 1
    return out


def _flag_message(flag: str) -> str:
    """``--experiment 2d1level`` -> write ``experiment=2d1level``: settings are overrides, not options."""
    name, _, value = flag.lstrip("-").replace("=", " ", 1).partition(" ")
    key = name.replace("-", "_")
    return (
        f"'{flag}' is not an option of rmpfusion's commands: settings are written key=value (Hydra's overrides); "
        f"write {key}={value or '...'}"
    )


def _first_job(overrides: list[str], dirs: list[Path]) -> list[str]:
    """The overrides of a sweep's first job (a sweep ``a=1,2`` becomes ``a=1``, ``experiment=glob(*)`` the first
    option it matches in the config directories); Hydra's own keys left out."""
    try:
        parsed = OverridesParser.create().parse_overrides(overrides)
    except OverrideParseException as e:
        first = str(e).strip().splitlines()[0]
        raise CommandLineError(
            f"cannot read the command line {' '.join(overrides)!r}: {first}; see "
            "https://hydra.cc/docs/advanced/override_grammar/basic/"
        ) from None
    out = []
    for o in parsed:
        if o.key_or_group.split("/")[0].split(".")[0] == "hydra" and o.key_or_group != "hydra.searchpath":
            continue
        value = o.value()
        if isinstance(value, Glob):
            names = sorted({f.stem for d in dirs for f in (d / o.key_or_group.lstrip("+~")).glob("*.yaml")})
            chosen = value.filter(names)
            if chosen:
                out.append(f"{o.get_key_element()}={chosen[0]}")
            continue
        if o.is_interval_sweep():  # a sweeper's search interval: the sweeper picks the values (and checks them)
            continue
        if o.is_sweep_override():
            values = list(o.sweep_string_iterator())
            if not values:
                raise CommandLineError(
                    f"'{o.input_line}' sweeps over no value, so the sweep would launch no job; give "
                    "it at least one (range(0,3) is 0, 1, 2: the end is left out)"
                )
            out.append(f"{o.get_key_element()}={values[0]}")
        else:
            assert o.input_line is not None  # the parser keeps every override's text
            out.append(o.input_line)
    return out


def _groups(dirs: list[Path]) -> list[str]:
    return sorted(
        {p.name for d in dirs if d.is_dir() for p in d.iterdir() if p.is_dir() and not p.name.startswith(".")}
    )


def _close(name: str, options: list[str]) -> str:
    close = closest(name, options)
    return f"did you mean {', '.join(repr(c) for c in close)}? " if close else ""


def _yaml_message(e: yaml.MarkedYAMLError) -> str:
    """Where the YAML went wrong: the construct it was reading (context) and what broke it (problem)."""

    def at(mark) -> str:
        return f"line {mark.line + 1}, column {mark.column + 1}"

    mark = e.context_mark or e.problem_mark
    parts = []
    if e.context:
        parts.append(f"{e.context} ({at(e.context_mark)})" if e.context_mark else e.context)
    if e.problem:
        parts.append(f"{e.problem} ({at(e.problem_mark)})" if e.problem_mark else e.problem)
    where = mark.name if mark else "a config file"
    return f"YAML syntax error in {where}: {', '.join(parts)}; fix the file (every config file must be valid YAML)"


def _override_message(
    e: ConfigCompositionException, groups: list[str], keys: Callable[[], list[str]], base: Callable[[], Any]
) -> str | None:
    m = re.search(r"Could not override '([^']+)'", str(e))
    if not m:
        return None
    key = m.group(1)
    head = key.split(".")[0].split("/")[0]
    deeper = re.search(r"full_key: (\S+)", str(e.__cause__ or ""))
    if deeper and deeper.group(1).startswith(key + "."):
        return _block_merge_message(key, deeper.group(1)[len(key) + 1 :])
    if head in keys() and "." in key:
        return _inner_key_message(key, base())
    hint = _close(head, groups + keys())
    return (
        f"'{key}' is neither a config group nor a key of the config; {hint}config groups: {', '.join(groups)}; "
        f"top-level keys: {', '.join(keys())} (to add a new key on purpose write +{key}=...)"
    )


def _block_merge_message(key: str, inner: str) -> str:
    """``tree.obstacle_weight={type: constant}``: a block given on the command line merges into the config's
    block, which has no such key; replacing the block is a deletion and an addition."""
    return (
        f"'{key}': a block given on the command line is merged into the config's {key}, which has no key "
        f"'{inner}'; to replace the whole block write ~{key} '+{key}={{...}}' (or give the key on its own: "
        f"+{key}.{inner}=...)"
    )


def _inner_key_message(key: str, config: Any) -> str:
    """``train.learning_rate=...``: the block exists, the key in it does not; name the keys it has."""
    parts, node = key.split("."), config
    where: list[str] = []
    for part in parts[:-1]:
        if not hasattr(node, "keys") or part not in node:
            break
        node, where = node[part], where + [part]
    block, missing = ".".join(where), parts[len(where)]
    options = [str(k) for k in node] if hasattr(node, "keys") else []
    close = closest(missing, options)
    hint = f"did you mean {', '.join(repr(f'{block}.{c}') for c in close)}? " if close else ""
    return (
        f"'{key}': {block} has no key '{missing}'; {hint}keys of {block}: {', '.join(options) or 'none'} (to add "
        f"a new key on purpose write +{key}=...)"
    )


def _missing_message(e: MissingConfigException, dirs: list[Path]) -> str:
    m = re.search(r"Could not find '([^']+)'", str(e))
    target = m.group(1) if m else str(e).splitlines()[0]
    group, _, option = target.rpartition("/")
    options = sorted({p.stem for d in dirs for p in (d / group).glob("*.yaml")}) if group else []
    if not options:
        return f"no config '{target}' (looked in {', '.join(str(d) for d in dirs)})"
    return (
        f"no config '{option}' in the group '{group}' ({group}/{option}.yaml); {_close(option, options)}"
        f"options: {', '.join(options)}"
    )


def _added_group(overrides: list[str], groups: list[str], keys: Callable[[], list[str]]) -> str | None:
    """``+experimnt=...`` composes (it adds a key) but was meant as a group: say so before validation does."""
    for o in overrides:
        if not o.startswith("+") or o.startswith("++"):
            continue
        head = o[1:].split("=", 1)[0].split("@", 1)[0].split(".")[0].split("/")[0]  # group@package: the group
        if head in groups or head in keys():
            continue
        close = difflib.get_close_matches(head, groups, n=1, cutoff=0.6)
        if close:
            return (
                f"'{o}' adds a new key '{head}', which the config does not have; did you mean the config group "
                f"'{close[0]}' ({close[0]}={o.split('=', 1)[1] if '=' in o else '...'})?"
            )
    return None


def check_command_line(conf_dir: str, argv: list[str]) -> None:
    """Compose the command line's config as the app will; raise CommandLineError saying what is wrong."""
    cmd = split_argv(argv)
    if cmd.informational:
        return
    if cmd.unknown_flags:
        raise CommandLineError(_flag_message(cmd.unknown_flags[0]))
    dirs = [Path(conf_dir)] + ([Path(cmd.config_dir)] if cmd.config_dir else [])
    groups = _groups(dirs)
    overrides = _first_job(cmd.overrides, dirs)
    if cmd.config_dir:
        overrides.append(f"hydra.searchpath=[file://{Path(cmd.config_dir).resolve()}]")
    with initialize_config_dir(config_dir=conf_dir, version_base="1.3"):
        base = functools.cache(lambda: _chosen_config(overrides, groups))  # only for messages
        _compose(overrides, groups, dirs, lambda: [str(k) for k in base()], base)


def _chosen_config(overrides: list[str], groups: list[str]) -> Any:
    """The config the command line's group choices make (experiment=..., data=...), without its other overrides:
    a misspelt key is then answered with the keys of the blocks the user chose, not the defaults'. The plain
    default config where those choices do not compose on their own."""
    chosen = [o for o in overrides if o.split("=", 1)[0].lstrip("+~").split("@", 1)[0] in groups]
    try:
        return compose("config", overrides=chosen)
    except HydraException:
        return compose("config")


def _compose(
    overrides: list[str], groups: list[str], dirs: list[Path], keys: Callable[[], list[str]], base: Callable[[], Any]
) -> None:
    """Compose as the app will, inside an initialised Hydra; every failure as a CommandLineError."""
    try:
        if (msg := _added_group(overrides, groups, keys)) is not None:
            raise CommandLineError(msg)
        compose("config", overrides=overrides)
    except yaml.MarkedYAMLError as e:
        raise CommandLineError(_yaml_message(e)) from None
    except MissingConfigException as e:
        raise CommandLineError(_missing_message(e, dirs)) from None
    except ConfigCompositionException as e:
        if isinstance(e.__cause__, yaml.MarkedYAMLError):
            raise CommandLineError(_yaml_message(e.__cause__)) from None
        msg = _override_message(e, groups, keys, base)
        raise CommandLineError(msg or _first_lines(e)) from None
    except HydraException as e:
        raise CommandLineError(_first_lines(e)) from None


def _first_lines(e: Exception, n: int = 2) -> str:
    lines = [ln for ln in str(e).strip().splitlines() if ln.strip() and not ln.startswith("Set the environment")]
    return " ".join(lines[:n]) or type(e).__name__


def check_output_dir(argv: list[str]) -> None:
    """The run or sweep directory the command line names can be created (else Hydra fails with a traceback
    after it has started). A directory with interpolations (``${now:...}``) is left to Hydra."""
    for arg in split_argv(argv).overrides:
        key, _, value = arg.partition("=")
        key = key.lstrip("+")
        if key not in ("hydra.run.dir", "hydra.sweep.dir") or not value or "${" in value:
            continue
        try:
            Path(value).expanduser().mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise CommandLineError(
                f"{key}={value} cannot be created ({e.strerror or type(e).__name__}); choose a "
                "directory you can write to"
            ) from None
