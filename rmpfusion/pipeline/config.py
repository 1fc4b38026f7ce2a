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
from ..registry import ENVS, LEAF_RMPS, LEARNERS, TASK_MAPS, TRAIN_METHODS, WEIGHTS


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


#: the data keys each recorded format reads; the others must keep their defaults under that format
_FILE_KEYS = {"files", "units", "time_units", "columns", "time_column", "cut_at_rest", "keep_motions"}
_ARRAY_KEYS = _FILE_KEYS | {"position_key", "velocity_key", "acceleration_key", "aux_keys"}
_FORMAT_KEYS = {
    "lasa": {"shape"},
    "csv": _FILE_KEYS | {"demo_column", "velocity_columns", "acceleration_columns", "aux_columns"},
    "npz": _ARRAY_KEYS,
    "hdf5": _ARRAY_KEYS | {"group", "rate"},
    "rosbag": {"files", "units", "columns", "topic", "cut_at_rest", "keep_motions", "aux_topics"},
}
_FORMAT_KEYS_ALL = set().union(*_FORMAT_KEYS.values())
#: the data keys each split reads
_SPLIT_KEYS = {"holdout": {"val", "test"}, "leave_one_out": {"fold"}, "all": set()}
_SPLIT_KEYS_ALL = set().union(*_SPLIT_KEYS.values())


class RecordedDataConfig(_Frozen):
    """Demonstrations a person recorded (``source: recorded``): files read by ``rmpfusion.recordings``, resampled
    onto the environment's step, differentiated by one Savitzky–Golay filter (or the file's own derivatives),
    trimmed of the rest at either end and split by whole demonstration. No expert exists: learners are trained on
    the demonstrations and evaluated against the held-out ones (``pipeline/recorded.py``)."""

    source: Literal["recorded"]
    format: Literal["lasa", "csv", "npz", "hdf5", "rosbag"] = Field(description="how the files are laid out")
    shape: str | None = Field(None, description="format lasa: the handwriting shape (e.g. Angle, Sshape)")
    files: list[str] = Field(
        default_factory=list,
        description="csv / npz / hdf5: the files, one or many demonstrations each; rosbag: ROS 1 .bag files or ROS "
        "2 bag directories, one demonstration each; wildcards (episodes/*.hdf5) name every match, in natural order",
    )
    units: Literal["m", "cm", "mm", "rad", "deg"] = Field(
        "m",
        description="the files' position units (rad / deg: joint angles, for an arm's joint-space env); LASA: "
        "the dataset's own mm, not a setting",
    )
    time_units: Literal["s", "ms", "us", "ns"] = Field(
        "s", description="csv / npz / hdf5: the time stamps' unit (a csv's dates and times carry their own: keep s)"
    )
    columns: list[str] | None = Field(
        None,
        description="the coordinates' names, in order (csv: the columns read, default every column but time, "
        "demonstration id, derivatives and aux; npz / hdf5: names for the position array's columns; rosbag: the "
        "joints read by name, default the robot's, or a point's coordinates among x, y, z, default all three)",
    )
    time_column: str = Field(
        "t", description="csv: the time column; npz: the time array's key; hdf5: the time dataset in each demo group"
    )
    demo_column: str | None = Field(None, description="csv: a column naming each row's demonstration")
    topic: str | None = Field(
        None,
        description="rosbag: the topic read, sensor_msgs/JointState (or, for an environment of positions, a "
        "geometry_msgs PoseStamped, PointStamped or TransformStamped); default the bag's only topic of those types",
    )
    cut_at_rest: float | None = Field(
        None,
        gt=0,
        description="a recording holding several demonstrations with the arm at rest between them (a whole "
        "teaching session in one log): cut in the middle of every rest lasting at least this long (s) between two "
        "motions; rest as trimming finds it (data.rest_fraction of the recording's peak speed); null: no cutting",
    )
    keep_motions: Literal["all", "odd", "even"] = Field(
        "all",
        description="with data.cut_at_rest, which motions of each recording are demonstrations: all, or the odd "
        "(1st, 3rd, ...) or even ones, for a session that recorded the arm's return to the start between them",
    )
    aux_columns: dict[str, list[str]] | None = Field(
        None,
        description="csv: aux state that differs between demonstrations (an obstacle where it stood, the goal), "
        "name -> its columns, one value per demonstration, in the environment's units (m: data.units is the "
        "positions'), e.g. {obstacle1_center: [ox, oy, oz]}; the names are the environment's aux state "
        "(rmpfusion-validate lists them). The rest comes from the scene and each demonstration's final rest",
    )
    aux_keys: dict[str, str] | None = Field(
        None,
        description="npz / hdf5: the same, name -> array key: (k,) or (N, k) for N demonstrations in an NPZ; (k,) "
        "or a constant (T, k) in each HDF5 demonstration group",
    )
    aux_to_policy: bool = Field(
        True,
        description="false: the aux columns (data.aux_columns / data.aux_keys) place each held-out demonstration's "
        "obstacles in evaluation, where collisions count against them, but the policy is trained and rolled out "
        "with the scene's values, as if where they stood had not been recorded (the baseline that does not know)",
    )
    aux_topics: dict[str, str] | None = Field(
        None,
        description="rosbag: the same, name -> a topic of a point (geometry_msgs PoseStamped, PointStamped or "
        "TransformStamped, e.g. a motion-capture system's tracked obstacle): its x, y, z in m, averaged over the "
        "bag, e.g. {obstacle1_center: /mocap/cylinder/pose}",
    )
    position_key: str = Field("pos", description="npz / hdf5: the positions' key (hdf5: inside each demo group)")
    velocity_columns: list[str] | None = Field(None, description="csv: the velocity columns (derivatives: file)")
    acceleration_columns: list[str] | None = Field(
        None, description="csv: the acceleration columns (derivatives: file)"
    )
    velocity_key: str | None = Field(None, description="npz / hdf5: the velocities' key (derivatives: file)")
    acceleration_key: str | None = Field(None, description="npz / hdf5: the accelerations' key (derivatives: file)")
    group: str | None = Field(
        "data",
        description="hdf5: the group holding one subgroup per demonstration (robomimic's); null: each file is one "
        "demonstration (ALOHA's episode files)",
    )
    rate: float | None = Field(
        None, gt=0, description="hdf5 without time stamps (robomimic): the recording rate (Hz), in place of time_column"
    )
    goal: list[float] | None = Field(
        None, description="the goal of every demonstration; default the mean of its final rest"
    )
    derivatives: Literal["filter", "file"] = Field(
        "filter",
        description="velocities and accelerations from the "
        "Savitzky–Golay filter, or from the file (every demonstration)",
    )
    window: int = Field(
        21,
        ge=3,
        le=401,
        description="the filter's window (samples of the step grid, odd); "
        "chosen on validation rollouts (tools/lasa_table.py)",
    )
    polyorder: int = Field(3, ge=2, le=6, description="the filter's polynomial order")
    rest_fraction: float = Field(
        0.02,
        ge=0,
        le=0.25,
        description="speeds below this fraction of the peak at either end are rest, trimmed (above a quarter of "
        "the peak, the motion itself would be cut and the goal taken mid-motion)",
    )
    rest_speed: float | None = Field(
        None,
        ge=0,
        description="speeds below this (rad/s for joint angles, m/s for positions) are rest too, where it is above "
        "data.rest_fraction of the peak: an encoder's noise keeps a still arm's filtered speed above a small "
        "fraction of the peak, so its rests would be kept (1 mrad of noise reads about 0.1 rad/s on a 250 Hz grid)",
    )
    every: int = Field(1, ge=1, le=1000, description="keep every this-many grid samples for training")
    split: Literal["holdout", "leave_one_out", "all"] = Field(
        "holdout",
        description="holdout (val / test counts), leave_one_out (fold), or all: train and test on every "
        "demonstration, the protocol of most published LASA numbers",
    )
    val: int = Field(1, ge=0, le=1000, description="holdout: validation demonstrations")
    test: int = Field(1, ge=1, le=1000, description="holdout: test demonstrations")
    fold: int = Field(0, ge=0, description="leave_one_out: the demonstration tested (the next one validates)")
    starts: int = Field(
        100,
        ge=0,
        le=100000,
        description="starts at rest in the demonstrations' box, enlarged by `enlarge`, for the convergence check",
    )
    enlarge: float = Field(
        0.5,
        ge=0,
        le=10,
        description="the box of those starts: the demonstrations' bounding box, each side longer by this fraction",
    )
    horizon_factor: float = Field(3.0, gt=0, le=100, description="their horizon: this times the longest demonstration")
    tolerance: float = Field(
        0.001,
        gt=0,
        description="converged: within this distance of the goal (m, the positions' SI unit) at the horizon",
    )
    cache_dir: str | None = Field(
        None, description="where the split datasets are cached (keyed by the files' content); default the run directory"
    )

    @field_validator("files", mode="before")
    @classmethod
    def _one_file_is_a_list_of_one(cls, value: Any) -> Any:
        return [value] if isinstance(value, str) else value

    @model_validator(mode="after")
    def _what_the_format_needs(self):
        if self.format == "lasa" and not self.shape:
            raise ValueError("format lasa needs data.shape, one of the dataset's shapes (e.g. data.shape=Angle)")
        if self.format != "lasa" and not self.files:
            raise ValueError(f"format {self.format} needs data.files, the recorded files to read")
        self._no_setting_the_format_ignores()
        self._file_derivatives_named()
        if self.keep_motions != "all" and self.cut_at_rest is None:
            raise ValueError(
                f"data.keep_motions={self.keep_motions} chooses among the motions data.cut_at_rest cuts a recording "
                "into, but data.cut_at_rest is not set; set it (the shortest rest between motions, in s)"
            )
        from_files = self.aux_from_files
        if not self.aux_to_policy and not from_files:
            raise ValueError(
                "data.aux_to_policy=false hides the aux state read from the files from the policy, but no file "
                "gives any: name it in data.aux_columns / data.aux_keys / data.aux_topics, or drop "
                "data.aux_to_policy"
            )
        if not self.aux_to_policy and "goal" in from_files:
            raise ValueError(
                "data.aux_to_policy=false with a goal aux column: a policy is never blind to its own goal (the "
                "demonstrations end there); hide the obstacles only, or drop data.aux_to_policy"
            )
        if self.goal is not None and "goal" in from_files:
            raise ValueError(
                "data.goal and a goal aux column (data.aux_columns / data.aux_keys) both give the goal; keep one"
            )
        if self.window % 2 == 0 or self.window <= self.polyorder:
            raise ValueError(
                f"data.window ({self.window}) must be odd and larger than data.polyorder ({self.polyorder})"
            )
        return self

    @property
    def aux_from_files(self) -> dict[str, Any]:
        """Aux name -> where the files give it (columns, an array key or a topic): whichever the format reads."""
        return {**(self.aux_columns or {}), **(self.aux_keys or {}), **(self.aux_topics or {})}

    def _no_setting_the_format_ignores(self) -> None:
        """A key the chosen format or split does not read, set away from its default, is refused rather than
        ignored (a CSV's files given to a LASA run would otherwise train on the LASA shape; a validation count
        under leave-one-out would be one demonstration whatever it said)."""
        for chosen, table, every, kind in (
            (self.format, _FORMAT_KEYS, _FORMAT_KEYS_ALL, "format"),
            (self.split, _SPLIT_KEYS, _SPLIT_KEYS_ALL, "split"),
        ):
            for key in sorted(every - table[chosen]):
                value, default = getattr(self, key), type(self).model_fields[key].get_default(call_default_factory=True)
                if value != default:
                    readers = ", ".join(f for f, keys in table.items() if key in keys)
                    own = (
                        " (for your own files start from data=recorded: no preset's values)" if kind == "format" else ""
                    )
                    shown = "null" if default is None else default
                    raise ValueError(
                        f"data.{key}={value!r} is not read by {kind} {chosen} (read by: {readers}); set "
                        f"data.{key}={shown}, or a data.{kind} that reads it{own}"
                    )
        if self.format == "hdf5" and self.rate is not None and self.time_column != "t":
            raise ValueError(
                f"data.rate and data.time_column={self.time_column!r} both give the times; keep the file's time "
                "stamps (drop data.rate) or the rate (drop data.time_column)"
            )

    def _file_derivatives_named(self) -> None:
        """``derivatives: file`` with a CSV, NPZ or HDF5 file needs the keys that say where the derivatives are."""
        if self.derivatives != "file" or self.format == "lasa":
            return
        if self.format == "rosbag":
            raise ValueError(
                "data.derivatives=file: a ROS bag's JointState messages carry no accelerations (and the "
                "velocities would then mix with the filter's); use data.derivatives=filter"
            )
        keys = (
            ("velocity_columns", "acceleration_columns")
            if self.format == "csv"
            else ("velocity_key", "acceleration_key")
        )
        missing = [k for k in keys if getattr(self, k) is None]
        if missing:
            raise ValueError(
                f"data.derivatives=file reads the velocities and accelerations from the files: set "
                f"{' and '.join('data.' + k for k in missing)}, or use data.derivatives=filter"
            )


#: the data block's union tags: the separator marks them as schema bookkeeping, left out of error locations
_EXPERT_DATA, _RECORDED_DATA = f"data source{TAG_SEPARATOR}expert", f"data source{TAG_SEPARATOR}recorded"


def _data_source(value: Any) -> str:
    """The data block's kind: ``source`` when given, else ``expert`` (every block before recordings existed)."""
    source = value.get("source", "expert") if isinstance(value, Mapping) else getattr(value, "source", "expert")
    return f"data source{TAG_SEPARATOR}{source}"


#: the data block: the expert's rollouts (default) or recorded demonstrations
DataBlock = Annotated[
    Annotated[DataConfig, Tag(_EXPERT_DATA)] | Annotated[RecordedDataConfig, Tag(_RECORDED_DATA)],
    Discriminator(
        _data_source,
        custom_error_type="data_source",
        custom_error_message="data.source must be expert (the expert tree's rollouts, "
        "the default) or recorded (files of recorded demonstrations)",
    ),
]


def upgrade_run_config(run: Mapping[str, Any]) -> dict[str, Any]:
    """A stored run config (a checkpoint's ``config``, a run directory's config.resolved.yaml) with renamed keys
    under their current names (``RENAMED_KEYS``) and training and recorded-data keys added since at the values it
    was made with (``upgrade_train_config``, ``RECORDED_DATA_ADDED``); anything else is returned unchanged."""
    out = dict(run)
    for block, names in RENAMED_KEYS.items():
        if isinstance(out.get(block), Mapping):
            out[block] = _renamed(out[block], names)
    if isinstance(out.get("train"), Mapping):
        out["train"] = upgrade_train_config(out["train"])
    data = out.get("data")
    if isinstance(data, Mapping) and data.get("source") == "recorded":
        out["data"] = {**RECORDED_DATA_ADDED, **data}
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
    compile: bool = Field(
        False,
        description="roll out through torch.compile'd trees (same numbers, faster after a one-off compile per tree); "
        "expert data only: recorded demonstrations' few rollouts run eagerly",
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
    data: DataBlock = Field(
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
                        f"recordings: {', '.join(able)} (bc: behavior cloning on the recorded accelerations)"
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
    registries = (ENVS, LEARNERS, TASK_MAPS, WEIGHTS, LEAF_RMPS, TRAIN_METHODS)
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
        )
    return _RUN_MODELS[key]
