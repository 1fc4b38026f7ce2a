"""The run configuration: what a composed Hydra config must be once resolved.

Hydra composes YAML; this model is the contract every entry point validates against (frozen,
unknown keys rejected). Registry-typed blocks (env, learners, weights) are checked again by their
entry's own model in ``validate_run_config``, so errors name paths like ``learners.rmp.weights.hidden``.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import (
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Discriminator,
    Field,
    Tag,
    ValidationError,
    create_model,
    field_validator,
    model_validator,
)
from pydantic_core import InitErrorDetails, PydanticCustomError

from ..assembly.errors import TAG_SEPARATOR
from ..assembly.spec import TreeSpec, TypedBlock, name_keyed, tree_spec_model, typed_union, weight_field
from ..envs.common import time_grid
from ..learn import methods  # noqa: F401  (the built-in training methods register themselves)
from ..learn.config import DEFAULT_METHOD, RENAMED_KEYS, TrainParams, _renamed, upgrade_train_config
from ..recordings.formats import RecordedDataConfig, own_keys, recorded_union
from ..registry import ENVS, LEAF_RMPS, LEARNERS, RECORDING_FORMATS, TASK_MAPS, TRAIN_METHODS, WEIGHTS


class _Frozen(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class DataConfig(_Frozen):
    """Demonstrations (paper §4.1 "Data"): environments × trajectories × equidistant points."""

    source: Literal["expert"] = Field("expert", description="the expert tree's own rollouts (the paper's data)")
    train_envs: int = Field(20, gt=0)
    train_trajectories: int = Field(50, gt=0, description="per environment, from unique initial states")
    test_envs: int = Field(5, gt=0)
    test_trajectories: int = Field(10, gt=0)
    val_envs: int = Field(
        0,
        ge=0,
        description="validation environments, drawn like the training ones (never "
        "trained on): settings are chosen on this split, never on the test set",
    )
    val_trajectories: int = Field(10, gt=0)
    points: int = Field(60, gt=1, description="recorded points per trajectory")
    interval: float = Field(1.0, gt=0, description="seconds between recorded points")
    cache_dir: str | None = Field(None, description="shared, checksummed dataset cache; default: the run directory")

    @field_validator("cache_dir")
    @classmethod
    def _a_directory(cls, v: str | None) -> str | None:
        """A cache that exists as something else than a directory could never hold a dataset: said now, not when
        the first dataset is written."""
        if v is not None:
            blocking = next((p for p in (Path(v), *Path(v).parents) if p.exists()), None)
            if blocking is not None and not blocking.is_dir():
                raise ValueError(
                    f"{blocking} is a file, not a directory, so no dataset can be cached "
                    f"{'in' if blocking == Path(v) else 'below'} it; point data.cache_dir at a directory "
                    "(it is created if missing), or leave it out to keep data in the run directory"
                )
        return v


#: the data block's union tags: the separator marks them as schema bookkeeping, left out of error locations
_EXPERT_DATA, _RECORDED_DATA = f"data source{TAG_SEPARATOR}expert", f"data source{TAG_SEPARATOR}recorded"


def _data_source(value: Any) -> str:
    """The data block's kind: ``source`` when given, else ``expert`` (every block before recordings existed)."""
    source = value.get("source", "expert") if isinstance(value, Mapping) else getattr(value, "source", "expert")
    return f"data source{TAG_SEPARATOR}{source}"


def data_union() -> Any:
    """The data block: the expert's rollouts (default) or recorded demonstrations, a recorded block typed by its
    ``format``'s model (``RECORDING_FORMATS``, regenerated when a format is registered)."""
    return Annotated[
        Annotated[DataConfig, Tag(_EXPERT_DATA)] | Annotated[recorded_union(), Tag(_RECORDED_DATA)],
        Discriminator(
            _data_source,
            custom_error_type="data_source",
            custom_error_message="data.source must be expert (the expert tree's rollouts, "
            "the default) or recorded (files of recorded demonstrations)",
        ),
    ]


class _DataBlock(BaseModel):
    """The model a data block is validated in on its own; ``_typed_data`` types ``data`` by its source and format."""

    data: Any


def _typed_data(value: Any) -> Any:
    """The static ``RunConfig``'s data block, typed by its source and format at validation time (so a plugin's
    format is known once its plugin loads); ``run_config_model`` types it the same way with error locations."""
    if isinstance(value, (DataConfig, RecordedDataConfig)):
        return value
    block = create_model("DataBlock", __base__=_DataBlock, data=(data_union(), ...))
    return block.model_validate({"data": value if value is not None else {}}).data


def upgrade_run_config(run: Mapping[str, Any]) -> dict[str, Any]:
    """A stored run config (a checkpoint's ``config``, a run directory's config.resolved.yaml) with renamed keys
    under their current names (``RENAMED_KEYS``) and training and recorded-data keys added since at the values it
    was made with (``upgrade_train_config``, ``RECORDED_DATA_ADDED``), and a recorded data block without the keys of
    other formats at their defaults (runs stored before each format had its own block listed them all,
    ``recordings.formats.own_keys``); anything else is returned unchanged."""
    out = dict(run)
    for block, names in RENAMED_KEYS.items():
        if isinstance(out.get(block), Mapping):
            out[block] = _renamed(out[block], names)
    if isinstance(out.get("train"), Mapping):
        out["train"] = upgrade_train_config(out["train"])
    data = out.get("data")
    if isinstance(data, Mapping) and data.get("source") == "recorded":
        out["data"] = own_keys({**RECORDED_DATA_ADDED, **data})
    return out


#: keys the recorded data block gained after runs were stored, at the values those runs were made with
RECORDED_DATA_ADDED = {
    "time_units": "s",
    "velocity_columns": None,
    "acceleration_columns": None,
    "velocity_key": None,
    "acceleration_key": None,
    "group": "data",
    "topic": None,
    "aux_columns": None,
    "aux_keys": None,
    "aux_to_policy": True,
    "cut_at_rest": None,
    "keep_motions": "all",
    "rest_speed": None,
    "aux_topics": None,
    "obstacle_entries": "refuse",  # no stored run was checked: one rerun now is, as a new run is
}


def train_union() -> Any:
    """The training block: ``{method: name, ...}`` validated by the named entry of ``TRAIN_METHODS``; a block
    without ``method`` is behavior cloning (``DEFAULT_METHOD``), as every block was before methods existed."""
    return typed_union(TRAIN_METHODS, key="method", default=DEFAULT_METHOD)


def method_of(train: TrainParams) -> str:
    """The TRAIN_METHODS name a validated training block is for: the entry whose parameter model typed it, the
    nearest in its class's ancestry (validation types a block by a model derived from the entry's; a method's model
    may derive from another's, as DAgger's from behavior cloning's; a plugin's need not carry a ``method`` field)."""
    ancestry = type(train).__mro__
    owners = sorted((ancestry.index(e.params), e.name) for e in TRAIN_METHODS.entries() if e.params in ancestry)
    if not owners:
        raise TypeError(f"{type(train).__name__} is the parameter model of no registered training method")
    return owners[0][1]


class _TrainBlock(BaseModel):
    """The model a training block is validated in on its own; ``_typed_train`` types ``train`` by its method."""

    train: Any


def _typed_train(value: Any) -> Any:
    """The static ``RunConfig``'s training block, typed by its method's entry at validation time (so a plugin's
    method is known once its plugin loads); ``run_config_model`` types it the same way with error locations."""
    if isinstance(value, TrainParams):
        return value
    block = create_model("TrainBlock", __base__=_TrainBlock, train=(train_union(), ...))
    return block.model_validate({"train": value if value is not None else {}}).train


class EvalConfig(_Frozen):
    horizon: float | None = Field(None, gt=0, description="rollout length in seconds; default points × interval")
    lyapunov_rtol: float = Field(1e-6, ge=0)
    lyapunov_atol: float = Field(1e-9, ge=0)
    figures: bool = True
    compile: bool | Literal["auto"] = Field(
        False,
        description="roll out through torch.compile'd trees (same numbers, faster after a one-off compile per tree); "
        "auto: on recorded demonstrations, each tree whose rollouts repay a compile (pipeline/experiment.py::compiles); "
        "a tree torch.compile cannot compile runs eagerly, said in the log (and, on recorded demonstrations, in "
        "metrics.json's evaluation)",
    )
    unit_weights: bool = Field(
        False,
        description="also roll out the expert's tree with every weight 1 (RMPflow) "
        "from the test starts: what the expert's weights add; expert data only: with recorded demonstrations that "
        "tree is always rolled out, as the untrained reference",
    )


class LoggerConfig(_Frozen):
    mode: Literal["offline", "online", "disabled"] = "offline"
    project: str = "rmpfusion"
    entity: str | None = None
    tags: list[str] = Field(default_factory=list)
    group: str | None = None


class RunConfig(_Frozen):
    """A whole experiment: environment, tree, expert weights, learners, data, training, evaluation.

    This is the static form (registry-typed blocks as ``{type: name, ...}``); ``run_config_model`` is the same
    schema with every such block a discriminated union over its registry, and validated configs are
    instances of it."""

    name: str = "experiment"
    seed: int = 0
    device: str = Field(
        "cpu",
        description="where trees, learners, training and the 2D environment compute: cpu, "
        "cuda or cuda:<index> (pybullet stays on the CPU; a policy's tensors cross "
        "once a step)",
    )
    env: TypedBlock
    tree: TreeSpec = Field(description="the tree spec (docs/architecture.md §2) without learned weights")
    expert: dict[str, Any] = Field(default_factory=dict, description="node or shared-weight name -> weight spec")
    learners: dict[str, TypedBlock] = Field(
        default_factory=dict, description="learner name -> {type: rmp|unstructured, ...}"
    )
    data: Annotated[Any, BeforeValidator(_typed_data)] = Field(
        default_factory=DataConfig,
        description="the expert's demonstrations (source: expert) or recorded ones (source: recorded)",
    )
    train: Annotated[Any, BeforeValidator(_typed_train)] = Field(
        default_factory=dict,
        validate_default=True,
        description="the training method (method: bc | dagger | apg | pg | a plugin's) and its settings",
    )
    eval: EvalConfig = EvalConfig()
    logger: LoggerConfig = LoggerConfig()

    @field_validator("device")
    @classmethod
    def _device_form(cls, v: str) -> str:
        """cpu, cuda or cuda:<index>; torch's other names for a GPU are answered with torch's (gpu -> cuda)."""
        if re.fullmatch(r"cpu|cuda(:\d+)?", v):
            return v
        guess = re.sub(r"^(gpu|nvidia|cuda)\s*:?\s*(\d*)$", lambda m: "cuda" + (f":{m[2]}" if m[2] else ""), v.lower())
        hint = f"; did you mean {guess!r}?" if re.fullmatch(r"cpu|cuda(:\d+)?", guess) else ""
        raise ValueError(f"{v!r} is not a device torch knows{hint} (devices: cpu, cuda, cuda:<index>)")

    @model_validator(mode="after")
    def _across_blocks(self) -> RunConfig:
        """Checks that need two blocks at once, each reported at the key to change (all of them together)."""
        found: list[InitErrorDetails] = []

        def refuse(loc: tuple[str, ...], given: Any, message: str) -> None:
            found.append(
                InitErrorDetails(
                    type=PydanticCustomError("run_config", "{message}", {"message": message}), loc=loc, input=given
                )
            )

        bad = (
            [s for s in self.train.snapshots if s < 0 or s > self.train.iterations]
            if isinstance(self.train, TrainParams)
            else []
        )
        if bad:
            refuse(
                ("train", "snapshots"),
                bad,
                f"snapshots {bad} lie outside 0..train.iterations={self.train.iterations} (a snapshot is the "
                f"learner after that many iterations); given {self.train.snapshots}",
            )
        step = getattr(self.env, "integration_step", None) if not isinstance(self.env, TypedBlock) else None
        if isinstance(self.data, RecordedDataConfig):
            found += self._recorded_issues()
            step = None
        if callable(step):  # environments that name their fixed step; others are checked when they roll out
            dt, key = step()
            if (too_many := self._too_many_steps(dt, key)) is not None:
                refuse(("env", key.split("env.", 1)[1]), dt, too_many)
            for loc, t, what in (
                (("data", "interval"), self.data.interval, "a positive multiple"),
                (("eval", "horizon"), self.eval.horizon, "a multiple"),
            ):
                if t is not None and not _on_grid(t, dt):
                    refuse(
                        loc,
                        t,
                        f"must be {what} of the environment's step {key} = {dt:.6g} s (rollouts "
                        f"integrate and record on that step's grid only); given {t}",
                    )
        shown = getattr(self.env, "render_trajectory", None) if not isinstance(self.env, TypedBlock) else None
        n_test = self.data.test_envs * self.data.test_trajectories if isinstance(self.data, DataConfig) else 0
        if isinstance(shown, int) and n_test and shown >= n_test:
            refuse(
                ("env", "render_trajectory"),
                shown,
                f"must be < {n_test}, the number of test trajectories (data.test_envs × data.test_trajectories, "
                f"numbered from 0); given {shown}",
            )
        if found:
            raise ValidationError.from_exception_data(type(self).__name__, found)
        return self

    def _recorded_issues(self) -> list[InitErrorDetails]:
        """Recorded demonstrations have no expert: an expert block, or a method that queries one, is refused."""
        issues: list[tuple[str | tuple[str, ...], Any, str]] = []
        if self.expert:
            issues.append(
                (
                    "expert",
                    dict(self.expert),
                    (
                        "recorded demonstrations (data.source=recorded) have no expert "
                        "tree: remove the expert block; the tree with every weight 1 is reported as the untrained "
                        "reference"
                    ),
                )
            )
        method = method_of(self.train) if isinstance(self.train, TrainParams) else None
        if method is not None and not TRAIN_METHODS.get(method).obj.from_recordings:
            able = sorted(e.name for e in TRAIN_METHODS.entries() if e.obj.from_recordings)
            issues.append(
                (
                    ("train", "method"),
                    method,
                    (
                        f"train.method={method} needs an expert or the environment's "
                        "task cost, which recorded demonstrations do not give; use a method that learns from "
                        f"recordings: {', '.join(able)} (field: the first-order field fitted to the recorded "
                        "velocities; bc: behavior cloning on the recorded accelerations)"
                    ),
                )
            )
        if self.eval.horizon is not None:
            issues.append(
                (
                    ("eval", "horizon"),
                    self.eval.horizon,
                    (
                        "recorded demonstrations set how long the evaluation's rollouts last: "
                        "data.horizon_factor times the longest demonstration; remove eval.horizon and set "
                        "data.horizon_factor instead"
                    ),
                )
            )
        return [
            InitErrorDetails(
                type=PydanticCustomError("run_config", "{message}", {"message": m}),
                loc=(loc,) if isinstance(loc, str) else loc,
                input=given,
            )
            for loc, given, m in issues
        ]

    def _too_many_steps(self, dt: float, key: str) -> str | None:
        """Why a rollout on the step ``dt`` (set by ``key``) would never end, or None: its longest rollout (the
        demonstrations', the evaluation's, a training method's) must take at most ``MAX_ROLLOUT_STEPS`` steps."""
        horizons = [
            (
                self.data.points * self.data.interval if isinstance(self.data, DataConfig) else None,
                "data.points × data.interval",
            ),
            (self.eval.horizon, "eval.horizon"),
            (getattr(self.train, "horizon", None), "train.horizon"),
        ]
        horizon, what = max(((h, w) for h, w in horizons if h is not None), key=lambda hw: hw[0])
        steps = horizon / dt
        if steps <= MAX_ROLLOUT_STEPS:
            return None
        rate = f"{1 / dt:.3g} Hz" if 1 / dt < float("inf") else "an infinite rate"
        return (
            f"a step of {dt:.3g} s ({key}, a control rate of {rate}) makes a rollout of {horizon:g} s ({what}) "
            f"take {steps:.3g} integration steps, more than the {MAX_ROLLOUT_STEPS:.0e} a run allows (it would "
            f"never finish); use a step of at least {horizon / MAX_ROLLOUT_STEPS:.3g} s"
        )


#: The most integration steps one rollout may take: a million steps of a 2-D particle take minutes, of an arm in
#: pybullet an hour; beyond it a step is a typo (``env.dt=1e-300``), not a setting.
MAX_ROLLOUT_STEPS = 1_000_000


def _on_grid(t: float, dt: float) -> bool:
    """Whether a rollout can record every ``t`` seconds on the step ``dt``: the rollout's own check, ``time_grid``."""
    try:
        time_grid(t, t, dt)
    except ValueError:
        return False
    return True


_RUN_MODELS: dict[tuple, type[RunConfig]] = {}


def run_config_model() -> type[RunConfig]:
    """``RunConfig`` typed by the registries as they are now: env, tree blocks, expert weights, learners and the
    training method are validated by their entries' own models (regenerated when an entry is registered, plugins included)."""
    registries = (ENVS, LEARNERS, TASK_MAPS, WEIGHTS, LEAF_RMPS, TRAIN_METHODS, RECORDING_FORMATS)
    for r in registries:
        r.load_plugins()  # first: a plugin's entries belong to the schema and to its cache key
    key = tuple((id(r), r.version) for r in registries)
    if key not in _RUN_MODELS:
        _RUN_MODELS[key] = create_model(
            "TypedRunConfig",
            __base__=RunConfig,
            env=(typed_union(ENVS), ...),
            tree=(tree_spec_model(), Field(description="the tree spec without learned weights")),
            expert=(name_keyed(weight_field()), Field(default_factory=dict)),
            learners=(name_keyed(typed_union(LEARNERS)), Field(default_factory=dict)),
            train=(train_union(), Field(default_factory=dict, validate_default=True)),
            data=(
                data_union(),
                Field(
                    default_factory=DataConfig,
                    description="the expert's demonstrations (source: expert) or recorded ones (source: recorded)",
                ),
            ),
        )
    return _RUN_MODELS[key]
