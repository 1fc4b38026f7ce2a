"""Reading demonstrations from the files people record them in: CSV, NPZ, HDF5 (robomimic-style groups).

Each reader returns a list of :class:`Recording`, one per demonstration, in the order the file holds them, with
positions converted to SI units (``units``). A file may hold one demonstration or many (a demonstration-id column
in a CSV, a leading demonstration axis in an NPZ, one group per demonstration in an HDF5 file). Every problem is
one :class:`RecordingError` naming the file, and the row and column where there is one.
"""

from __future__ import annotations

import csv
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np

from .recording import Recording, RecordingError, TimeOrderError, where

#: what a time going backwards in a file without a demonstration column most often means
MANY_DEMOS_HINT = "; if the file holds several demonstrations, name the column telling them apart in data.demo_column"

#: the factor that takes a value in these units to SI (metres, radians)
UNITS = {"m": 1.0, "cm": 1e-2, "mm": 1e-3, "rad": 1.0, "deg": np.pi / 180.0}
#: the factor that takes a time stamp in these units to seconds
TIME_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}
#: the delimiters a CSV header is sniffed for (spreadsheets in many locales write ';', loggers often tabs)
DELIMITERS = ",;\t"


def unit_scale(units: str, source: str) -> float:
    try:
        return UNITS[units]
    except KeyError:
        raise RecordingError(f"{source}: unknown units {units!r}; one of {', '.join(UNITS)}") from None


def time_scale(time_units: str, source: str) -> float:
    try:
        return TIME_UNITS[time_units]
    except KeyError:
        raise RecordingError(f"{source}: unknown time units {time_units!r}; one of {', '.join(TIME_UNITS)}") from None


def _scaled(rec_kwargs: dict, scale: float, seconds: float) -> dict:
    """Positions and their derivatives in SI units (a derivative's time unit converted too), times in seconds."""
    rec_kwargs["t"] = rec_kwargs["t"] * seconds
    for key, per_time in (("pos", 1.0), ("vel", seconds), ("acc", seconds**2)):
        if rec_kwargs.get(key) is not None:
            rec_kwargs[key] = rec_kwargs[key] * (scale / per_time)
    return rec_kwargs


# ------------------------------------------------------------------------------------------------ aux state
def _constant(values: np.ndarray, label: str, place: Callable[[int, int], str]) -> np.ndarray:
    """An aux entry's one value (k,) from its samples ``values`` (T, k): the tree reads one aux state per
    demonstration, so a value that changes within it (an obstacle moved mid-recording) is refused at the first
    sample that differs (``place(i, k)``: where sample i's k-th value is, for the message)."""
    values = np.asarray(values, dtype=np.float64).reshape(len(values), -1)
    bad = np.argwhere(values != values[0])
    if bad.size:
        i, k = (int(v) for v in bad[0])
        raise RecordingError(
            f"{place(i, k)}: {values[i, k]:.6g} differs from {values[0, k]:.6g} earlier in "
            f"{label}; aux state (data.aux_columns / data.aux_keys) holds one value per demonstration"
        )
    return values[0]


def _cells(source: str, rows: Sequence[int], columns: Sequence[str]) -> Callable[[int, int], str]:
    """Where a CSV demonstration's i-th sample of its k-th aux column is (the header is row 1)."""
    return lambda i, k: where(source, rows[i] + 2, columns[k])


# ------------------------------------------------------------------------------------------------ CSV
def _float(text: str, source: str, row: int, column: str, hint: str = "") -> float:
    try:
        return float(text)
    except ValueError:
        if not text.strip():
            raise RecordingError(
                f"{where(source, row, column)}: the cell is empty (a sample the logger missed?); fill it in, or drop "
                f"the row (the samples need not be evenly spaced){hint}"
            ) from None
        if "," in text and "." not in text:
            hint = "; a decimal comma? write the numbers with a decimal point"
        raise RecordingError(f"{where(source, row, column)}: {text!r} is not a number{hint}") from None


@dataclass
class _Table:
    """A CSV file's header (names stripped), the line it stands on (1-based), and its rows, where ``body[r]`` is
    line ``r + 2`` of the file: blank rows stand in for comment lines and the lines above the header."""

    header: list[str]
    header_row: int
    body: list[list[str]]


def _is_number(cell: str) -> bool:
    try:
        float(cell)
    except ValueError:
        return False
    return True


def _table(path: Path, source: str, time_column: str) -> _Table:
    """The CSV's table in any of the common delimiters. A byte-order mark (Excel's "CSV UTF-8") is not part of the
    first name; lines starting with ``#`` are comments (a logger's notes), except that where numbers follow the
    comments at once the last comment is the header (``numpy.savetxt(..., header="t,x,y")`` writes ``# t,x,y``);
    a trailing delimiter on every line (an empty last column) is not a column."""
    try:
        with open(path, newline="", encoding="utf-8-sig") as fh:
            lines = fh.read().splitlines()
    except UnicodeDecodeError:
        raise RecordingError(
            f"{source}: not a text CSV file (its bytes are not UTF-8); an NPZ or HDF5 file needs data.format=npz or "
            "hdf5, a CSV saved in another encoding needs saving as UTF-8"
        ) from None
    comment = [line.lstrip().startswith("#") for line in lines]
    h = comment.index(False) if False in comment else len(lines)
    if h == len(lines) or not lines[h].strip():
        raise RecordingError(
            f"{source}: the file is empty{' but for # comments' if h else ''}; it needs a header row naming "
            f"{time_column!r} and the coordinates"
        )
    try:
        dialect: Any = csv.Sniffer().sniff(lines[h], delimiters=DELIMITERS)
    except csv.Error:
        dialect = csv.excel  # one column, or no delimiter to tell: a comma
    rows = [[] if c else row for c, row in zip(comment, csv.reader(lines, dialect))]
    if h > 0 and all(_is_number(cell) for cell in rows[h] if cell.strip()):
        h -= 1  # numpy.savetxt's header: the comment right above the numbers
        rows[h] = next(csv.reader([lines[h].lstrip()[1:]], dialect))
    header = [name.strip() for name in rows[h]]
    body: list[list[str]] = [[] for _ in range(h)] + rows[h + 1 :]
    while header and not header[-1] and all(len(r) < len(header) or not r[-1].strip() for r in body):
        header = header[:-1]  # a trailing delimiter on every line
        body = [r[: len(header)] if len(r) > len(header) else r for r in body]
    return _Table(header, h + 1, body)


def _coordinate_columns(header: list[str], used: set, source: str, header_row: int = 1) -> list[str]:
    """Every column that is not time, a demonstration id, a derivative or aux, in the header's order; an unnamed
    one (pandas' index, written by ``to_csv`` unless ``index=False``) is refused rather than read as a coordinate."""
    unnamed = [k + 1 for k, h in enumerate(header) if not h]
    if unnamed:
        raise RecordingError(
            f"{where(source, header_row)}: column {unnamed[0]} of the header has no name (pandas writes its index so: "
            "to_csv(..., index=False)); name it, or list the coordinates in data.columns"
        )
    return [h for h in header if h not in used]


def _joint_columns(
    candidates: list[str], joints: Sequence[str] | None, source: str, header_row: int
) -> tuple[list[str], list[str]]:
    """(coordinates, ignored columns) of a header whose coordinates were not listed (``data.columns`` null): where
    it names the robot's joints (``joints``, in the robot file's order), those joints in that order, every other
    column ignored (a gripper's fingers, a wall clock, a logger's counters: what a lab's log holds beside the arm);
    otherwise every candidate column, none ignored (the robot check then says what the columns should be named)."""
    if not joints or not any(j in candidates for j in joints):
        return candidates, []
    missing = [j for j in joints if j not in candidates]
    if missing:
        raise RecordingError(
            f"{where(source, header_row)}: the header names some of the robot's joints but not "
            f"{', '.join(missing)}; it has {', '.join(candidates)}. Name each joint's column as the robot file does "
            f"({', '.join(joints)}), or list the columns to read, in the robot's joint order, in data.columns"
        )
    return list(joints), [c for c in candidates if c not in joints]


def _clock_times(
    body: list[list[str]], rows: list[int], at: int, source: str, column: str, time_units: str
) -> np.ndarray | None:
    """Seconds since the epoch when the time column (index ``at``) holds dates and times, ISO 8601 as pandas
    writes a DatetimeIndex (``2024-05-01 12:00:00.010000``, with or without an offset); None when it holds numbers.
    Only differences between stamps matter, so times without an offset are read as UTC."""
    first = body[rows[0]][at].strip()
    if _is_number(first):
        return None
    try:
        datetime.fromisoformat(first)
    except ValueError:
        return None  # neither: the number reader names the cell
    if time_units != "s":
        raise RecordingError(
            f"{where(source, rows[0] + 2, column)}: the times are dates and times ({first!r}), which carry their "
            f"own unit; drop data.time_units={time_units}"
        )
    seconds = []
    for r in rows:
        cell = body[r][at].strip()
        try:
            stamp = datetime.fromisoformat(cell)
        except ValueError:
            raise RecordingError(
                f"{where(source, r + 2, column)}: {cell!r} is not a date and time like the first sample's {first!r}"
            ) from None
        seconds.append((stamp if stamp.tzinfo else stamp.replace(tzinfo=timezone.utc)).timestamp())
    return np.asarray(seconds)


def _time_column_hint(header: Sequence[str]) -> str:
    """The fix when one column's name says it holds the time (``time``, ``timestamp``, rostopic's ``%time``)."""
    timed = [h for h in header if "time" in h.lower() or h.lower() in ("stamp", "sec", "secs", "seconds")]
    return f"; set data.time_column={timed[0]}" if len(timed) == 1 else ""


def _check_header(
    header: Sequence[str], source: str, header_row: int, time_column: str, demo_column: str | None, named: list[str]
) -> None:
    """Every column the settings name is in the header; otherwise one message naming the setting and the header."""
    if time_column not in header:
        raise RecordingError(
            f"{where(source, header_row)}: the header has no time column {time_column!r} (data.time_column); it has "
            f"{', '.join(header)}{_time_column_hint(header)}"
        )
    for name in named:
        if name not in header:
            raise RecordingError(
                f"{where(source, header_row)}: the header has no column {name!r}; it has {', '.join(header)}"
            )
    if demo_column and demo_column not in header:
        raise RecordingError(
            f"{where(source, header_row)}: the header has no column {demo_column!r} (data.demo_column); it has "
            f"{', '.join(header)}; name the column telling the demonstrations apart, or set data.demo_column=null "
            "if each file holds one demonstration"
        )


def _rows_by_demonstration(
    body: Sequence[Sequence[str]], width: int, demo_index: int | None, source: str
) -> dict[str, list[int]]:
    """{demonstration id: its rows} (one id, "", without a demonstration column); blank lines are no samples, and a
    row of another width than the header's names its line."""
    groups: dict[str, list[int]] = {}
    for r, line in enumerate(body):
        if not any(cell.strip() for cell in line):
            continue  # a blank line (a trailing newline) is not a sample
        if len(line) != width:
            raise RecordingError(f"{where(source, r + 2)}: {len(line)} values for the header's {width} columns")
        key = line[demo_index].strip() if demo_index is not None else ""
        groups.setdefault(key, []).append(r)
    return groups


def read_csv(
    path: str | Path,
    columns: Sequence[str] | None = None,
    time_column: str = "t",
    velocity_columns: Sequence[str] | None = None,
    demo_column: str | None = None,
    aux_columns: Mapping[str, Sequence[str]] | None = None,
    units: str = "m",
    acceleration_columns: Sequence[str] | None = None,
    time_units: str = "s",
    joints: Sequence[str] | None = None,
) -> list[Recording]:
    """Demonstrations from a CSV file whose header names ``time_column`` and the coordinates.

    ``columns``: the coordinates, in order (default: every column that is not time, a demonstration id, a
    derivative or an aux column; where ``joints``, a robot's joints, are named in the header, those joints in the
    robot's order, and the other columns are ignored and listed in each recording's ``ignored``). ``demo_column``: a column whose value says which demonstration a row belongs to
    (rows of one demonstration need not be adjacent). ``velocity_columns`` / ``acceleration_columns``: the file's
    own derivatives, one column per coordinate. ``aux_columns``: aux name -> its columns, read from the
    demonstration's first row (it must be constant over the demonstration). The delimiter (comma, semicolon or
    tab) is read from the header."""
    path = Path(path)
    source = str(path)
    table = _table(path, source, time_column)
    header, body = table.header, table.body
    aux_columns = dict(aux_columns or {})
    derivatives = [*(velocity_columns or ()), *(acceleration_columns or ())]
    used_aux = [c for cs in aux_columns.values() for c in cs]
    used = {time_column, demo_column, *derivatives, *used_aux}
    guessed = columns is None
    ignored: list[str] = []
    if columns is None:
        candidates = _coordinate_columns(header, used, source, table.header_row)
        columns, ignored = _joint_columns(candidates, joints, source, table.header_row)
    columns = list(columns)
    _check_header(header, source, table.header_row, time_column, demo_column, [*columns, *derivatives, *used_aux])
    index = {h: k for k, h in enumerate(header)}
    groups = _rows_by_demonstration(body, len(header), index[demo_column] if demo_column else None, source)
    scale, seconds = unit_scale(units, source), time_scale(time_units, source)
    as_coordinate = (
        f"; every column but time{', ' + repr(demo_column) if demo_column else ''} is read as a coordinate unless "
        "data.columns lists them (a column naming each row's demonstration: data.demo_column)"
        if guessed
        else ""
    )

    def numbers(rows: list[int], names: Sequence[str]) -> np.ndarray:
        """The cells of ``rows`` in the columns ``names`` as numbers; one that is not a number names its place."""
        return np.array(
            [[_float(body[r][index[c]], source, r + 2, c, as_coordinate) for c in names] for r in rows],
            dtype=np.float64,
        )

    out = []
    for key, rows in groups.items():
        label = f"{source} [{demo_column}={key}]" if demo_column else source
        clock = _clock_times(body, rows, index[time_column], source, time_column, time_units)
        kwargs = {
            "t": numbers(rows, [time_column])[:, 0] if clock is None else clock,
            "pos": numbers(rows, columns),
            "vel": numbers(rows, velocity_columns) if velocity_columns else None,
            "acc": numbers(rows, acceleration_columns) if acceleration_columns else None,
        }
        aux = {name: _constant(numbers(rows, cs), label, _cells(source, rows, cs)) for name, cs in aux_columns.items()}
        try:
            rec = Recording(
                **_scaled(kwargs, scale, seconds),
                aux=aux,
                source=label,
                columns=tuple(columns),
                rows=np.asarray(rows) + 2,
                ignored=tuple(ignored),
            )
        except TimeOrderError as e:
            raise TimeOrderError(f"{e}{'' if demo_column else MANY_DEMOS_HINT}") from None
        out.append(rec)
    if not out:
        raise RecordingError(f"{source}: no samples below the header")
    return out


# ------------------------------------------------------------------------------------------------ NPZ
NPZ_LAYOUTS = (
    "rmpfusion reads t (T,) and positions (T, d) for one demonstration, or (N, T) and (N, T, d) for N of equal "
    "length; demonstrations of unequal length go one per file (list them in data.files)"
)


def _npz_array(data: Any, key: str, source: str) -> np.ndarray:
    if key not in data.files:
        raise RecordingError(f"{source}: no array {key!r}; it holds {', '.join(data.files)}. {NPZ_LAYOUTS}")
    try:
        return np.asarray(data[key], dtype=np.float64)
    except ValueError:  # object arrays (ragged demonstrations) need pickle, which a data file never gets
        raise RecordingError(
            f"{source}: the array {key!r} is stored as Python objects (ragged arrays), which rmpfusion does not "
            f"unpickle. {NPZ_LAYOUTS}"
        ) from None


def read_npz(
    path: str | Path,
    time_key: str = "t",
    position_key: str = "pos",
    velocity_key: str | None = None,
    columns: Sequence[str] | None = None,
    units: str = "m",
    acceleration_key: str | None = None,
    time_units: str = "s",
    aux_keys: Mapping[str, str] | None = None,
) -> list[Recording]:
    """Demonstrations from an NPZ file: ``t`` (T,) and ``pos`` (T, d) for one, or a leading demonstration axis
    (N, T) and (N, T, d) for several of equal length; the file's own derivatives at ``velocity_key`` and
    ``acceleration_key``, shaped like the positions; aux state per demonstration at ``aux_keys`` (name -> key of
    a (k,) array for one demonstration, (N, k) for N)."""
    path = Path(path)
    source = str(path)
    try:
        data = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as e:
        raise RecordingError(f"{source}: not a readable NPZ file ({e})") from None
    with data:
        t, pos = _npz_array(data, time_key, source), _npz_array(data, position_key, source)
        vel = _npz_array(data, velocity_key, source) if velocity_key else None
        acc = _npz_array(data, acceleration_key, source) if acceleration_key else None
        aux = {name: (key, _npz_array(data, key, source)) for name, key in (aux_keys or {}).items()}
    if t.ndim == 1:
        t, pos = t[None], pos[None]
        vel, acc = (a[None] if a is not None else None for a in (vel, acc))
    if pos.ndim == 2:  # (N, T) of one coordinate
        pos = pos[..., None]
        vel, acc = (a[..., None] if a is not None and a.ndim == 2 else a for a in (vel, acc))
    if t.ndim != 2 or pos.ndim != 3 or pos.shape[:2] != t.shape:
        raise RecordingError(
            f"{source}: {time_key!r} {t.shape} and {position_key!r} {pos.shape} do not match; "
            "expected (T,) and (T, d), or (N, T) and (N, T, d)"
        )
    columns = tuple(columns) if columns is not None else tuple(f"{position_key}[{k}]" for k in range(pos.shape[2]))
    per_demo = {
        name: _per_demonstration(arr, t.shape[0], f"{source}: aux array {key!r}") for name, (key, arr) in aux.items()
    }
    scale, seconds = unit_scale(units, source), time_scale(time_units, source)
    return [
        Recording(
            **_scaled(
                {
                    "t": t[n],
                    "pos": pos[n],
                    "vel": vel[n] if vel is not None else None,
                    "acc": acc[n] if acc is not None else None,
                },
                scale,
                seconds,
            ),
            source=f"{source} [demonstration {n}]" if t.shape[0] > 1 else source,
            aux={name: arr[n] for name, arr in per_demo.items()},
            columns=columns,
            rows=np.arange(t.shape[1]) + 1,
        )
        for n in range(t.shape[0])
    ]


def _per_demonstration(arr: np.ndarray, n: int, label: str) -> np.ndarray:
    """An NPZ aux array as (N, k): (k,) or a scalar for a file of one demonstration, (N, k) for N."""
    if n == 1 and arr.ndim <= 1:
        return arr.reshape(1, -1)
    if arr.ndim == 2 and arr.shape[0] == n:
        return arr
    if arr.ndim == 1 and arr.shape[0] == n:
        return arr[:, None]
    raise RecordingError(
        f"{label} has shape {arr.shape}; aux state holds one value per demonstration: (k,) for a file of one, "
        f"(N, k) for N (this file holds {n})"
    )


# ------------------------------------------------------------------------------------------------ HDF5
def _h5py():
    try:
        import h5py
    except ImportError:
        raise RecordingError("reading HDF5 recordings needs h5py: pip install h5py") from None
    return h5py


def _datasets(group: Any) -> list[str]:
    """Every dataset's path inside ``group`` (what a missing key's message lists)."""
    found: list[str] = []
    group.visititems(lambda name, obj: found.append(name) if hasattr(obj, "shape") else None)
    return found


def _h5_array(demo: Any, key: str, label: str, what: str) -> np.ndarray:
    if key not in demo:
        raise RecordingError(
            f"{label}: no dataset {key!r} ({what}); the group holds {', '.join(_datasets(demo)) or 'nothing'}"
        )
    obj = demo[key]
    if not hasattr(obj, "shape"):
        raise RecordingError(
            f"{label}: {key!r} is a group, not a dataset ({what}); it holds {', '.join(_datasets(obj)) or 'nothing'}"
        )
    return np.asarray(obj, dtype=np.float64)


def read_hdf5(
    path: str | Path,
    position_key: str,
    group: str | None = "data",
    time_key: str | None = None,
    rate: float | None = None,
    columns: Sequence[str] | None = None,
    units: str = "m",
    velocity_key: str | None = None,
    acceleration_key: str | None = None,
    time_units: str = "s",
    aux_keys: Mapping[str, str] | None = None,
) -> list[Recording]:
    """Demonstrations from an HDF5 file laid out as robomimic does: one subgroup of ``group`` per demonstration
    (``data/demo_0``, ``data/demo_1``, … in natural order; datasets beside them, such as statistics, are not
    demonstrations), positions at ``position_key`` inside it (e.g. ``obs/robot0_joint_pos``), times at
    ``time_key`` or, where the layout stores none, a fixed ``rate`` (Hz); a group holding time stamps while a rate
    is given is refused (one of the two would be ignored). ``group=None`` reads the whole file as one demonstration,
    as ALOHA's and ACT's episode files hold one (``observations/qpos`` at the top level, one file per episode).
    Aux state per demonstration at ``aux_keys`` (name -> dataset in each group: (k,), or (T, k) constant)."""
    h5py = _h5py()
    path = Path(path)
    source = str(path)
    if (time_key is None) == (rate is None):
        raise RecordingError(
            f"{source}: give either the time dataset's key (data.time_column) or a sampling rate (data.rate), not "
            f"{'both' if rate is not None else 'neither'}"
        )
    try:
        fh = h5py.File(path, "r")
    except OSError as e:
        raise RecordingError(f"{source}: not a readable HDF5 file ({e})") from None
    scale, seconds = unit_scale(units, source), time_scale(time_units, source)
    out = []
    with fh:
        for label, demo in _demonstration_groups(fh, group, source):
            pos = _h5_array(demo, position_key, label, "data.position_key")
            if time_key is not None:
                t = _h5_array(demo, time_key, label, "data.time_column, or data.rate for a fixed rate").reshape(-1)
            else:
                assert rate is not None  # one of the two is given (checked above)
                if "t" in demo or "timestamp" in demo:
                    raise RecordingError(
                        f"{label}: the group holds time stamps, but data.rate={rate} would replace them; name them "
                        "in data.time_column instead of giving a rate"
                    )
                t = np.arange(pos.shape[0]) / (float(rate) * seconds)  # in the time unit: scaled to s below
            cols = (
                tuple(columns)
                if columns is not None
                else tuple(f"{position_key}[{k}]" for k in range(pos.shape[1] if pos.ndim > 1 else 1))
            )
            kwargs = {
                "t": t,
                "pos": pos,
                "vel": _h5_array(demo, velocity_key, label, "data.velocity_key") if velocity_key else None,
                "acc": _h5_array(demo, acceleration_key, label, "data.acceleration_key") if acceleration_key else None,
            }
            aux = {name: _h5_aux(demo, key, label) for name, key in (aux_keys or {}).items()}
            out.append(
                Recording(
                    **_scaled(kwargs, scale, seconds),
                    source=label,
                    columns=cols,
                    aux=aux,
                    rows=np.arange(t.shape[0]) + 1,
                )
            )
    if not out:
        raise RecordingError(f"{source}: group {group!r} holds no demonstrations")
    return out


def _h5_aux(demo: Any, key: str, label: str) -> np.ndarray:
    """A demonstration group's aux entry: a (k,) dataset (or a scalar), or a (T, k) one constant over the samples."""
    arr = _h5_array(demo, key, label, "data.aux_keys")
    if arr.ndim <= 1:
        return arr.reshape(-1)
    return _constant(arr.reshape(len(arr), -1), label, lambda i, k: f"{label}, {key}[{i}, {k}]")


def _demonstration_groups(fh: Any, group: str | None, source: str) -> list[tuple[str, Any]]:
    """Each demonstration's group with the label its errors name: the subgroups of ``group`` in natural order
    (demo_2 before demo_10), or the file's top level where ``group`` is None (one demonstration per file)."""
    if group is None:
        return [(source, fh)]
    if group not in fh or hasattr(fh[group], "shape"):
        raise RecordingError(
            f"{source}: no group {group!r} (data.group); top level holds {', '.join(fh.keys())}. rmpfusion reads "
            "robomimic's layout, one group per demonstration inside data.group, or one demonstration per file "
            "(ALOHA's episodes) with data.group=null"
        )
    demos = [name for name in fh[group] if not hasattr(fh[group][name], "shape")]
    return [(f"{source} [{group}/{name}]", fh[group][name]) for name in sorted(demos, key=lambda s: (len(s), s))]
