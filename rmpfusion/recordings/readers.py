"""Reading demonstrations from the files people record them in: CSV, NPZ, HDF5 (robomimic-style groups).

Each reader returns a list of :class:`Recording`, one per demonstration, in the order the file holds them, with
positions converted to SI units (``units``). A file may hold one demonstration or many (a demonstration-id column
in a CSV, a leading demonstration axis in an NPZ, one group per demonstration in an HDF5 file). Every problem is
one :class:`RecordingError` naming the file, and the row and column where there is one.
"""

from __future__ import annotations

import csv
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from .recording import Recording, RecordingError, where

#: the factor that takes a value in these units to SI (metres, radians)
UNITS = {"m": 1.0, "cm": 1e-2, "mm": 1e-3, "rad": 1.0, "deg": np.pi / 180.0}


def unit_scale(units: str, source: str) -> float:
    try:
        return UNITS[units]
    except KeyError:
        raise RecordingError(f"{source}: unknown units {units!r}; one of {', '.join(UNITS)}") from None


def _scaled(rec_kwargs: dict, scale: float) -> dict:
    for key in ("pos", "vel", "acc"):
        if rec_kwargs.get(key) is not None:
            rec_kwargs[key] = rec_kwargs[key] * scale
    return rec_kwargs


# ------------------------------------------------------------------------------------------------ CSV
def _float(text: str, source: str, row: int, column: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise RecordingError(f"{where(source, row, column)}: {text!r} is not a number") from None


def read_csv(
    path: str | Path,
    columns: Sequence[str] | None = None,
    time_column: str = "t",
    velocity_columns: Sequence[str] | None = None,
    demo_column: str | None = None,
    aux_columns: Mapping[str, Sequence[str]] | None = None,
    units: str = "m",
) -> list[Recording]:
    """Demonstrations from a CSV file whose header names ``time_column`` and the coordinates.

    ``columns``: the coordinates, in order (default: every column that is not time, a demonstration id, a
    velocity or an aux column). ``demo_column``: a column whose value says which demonstration a row belongs to
    (rows of one demonstration need not be adjacent). ``aux_columns``: aux name -> its columns, read from the
    demonstration's first row (it must be constant over the demonstration)."""
    path = Path(path)
    source = str(path)
    with open(path, newline="") as fh:
        reader = csv.reader(fh)
        try:
            header = [h.strip() for h in next(reader)]
        except StopIteration:
            raise RecordingError(
                f"{source}: the file is empty; it needs a header row naming {time_column!r} and the coordinates"
            ) from None
        body = list(reader)
    aux_columns = dict(aux_columns or {})
    used = {time_column, demo_column, *(velocity_columns or ()), *(c for cs in aux_columns.values() for c in cs)}
    columns = list(columns) if columns is not None else [h for h in header if h not in used]
    for name in [
        time_column,
        *columns,
        *(velocity_columns or ()),
        *(c for cs in aux_columns.values() for c in cs),
        *([demo_column] if demo_column else []),
    ]:
        if name not in header:
            raise RecordingError(f"{where(source, 1)}: the header has no column {name!r}; it has {', '.join(header)}")
    index = {h: k for k, h in enumerate(header)}
    groups: dict[str, list[int]] = {}
    for r, line in enumerate(body):
        if not any(cell.strip() for cell in line):
            continue  # a blank line (a trailing newline) is not a sample
        if len(line) != len(header):
            raise RecordingError(f"{where(source, r + 2)}: {len(line)} values for the header's {len(header)} columns")
        key = line[index[demo_column]].strip() if demo_column else ""
        groups.setdefault(key, []).append(r)
    scale = unit_scale(units, source)

    def numbers(rows: list[int], names: Sequence[str]) -> np.ndarray:
        """The cells of ``rows`` in the columns ``names`` as numbers; one that is not a number names its place."""
        return np.array([[_float(body[r][index[c]], source, r + 2, c) for c in names] for r in rows], dtype=np.float64)

    out = []
    for key, rows in groups.items():
        label = f"{source} [{demo_column}={key}]" if demo_column else source
        kwargs = {
            "t": numbers(rows, [time_column])[:, 0],
            "pos": numbers(rows, columns),
            "vel": numbers(rows, velocity_columns) if velocity_columns else None,
        }
        aux = {name: numbers(rows, cs)[0] for name, cs in aux_columns.items()}
        out.append(
            Recording(
                **_scaled(kwargs, scale), aux=aux, source=label, columns=tuple(columns), rows=np.asarray(rows) + 2
            )
        )
    if not out:
        raise RecordingError(f"{source}: no samples below the header")
    return out


# ------------------------------------------------------------------------------------------------ NPZ
def read_npz(
    path: str | Path,
    time_key: str = "t",
    position_key: str = "pos",
    velocity_key: str | None = None,
    columns: Sequence[str] | None = None,
    units: str = "m",
) -> list[Recording]:
    """Demonstrations from an NPZ file: ``t`` (T,) and ``pos`` (T, d) for one, or a leading demonstration axis
    (N, T) and (N, T, d) for several of equal length."""
    path = Path(path)
    source = str(path)
    try:
        data = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as e:
        raise RecordingError(f"{source}: not a readable NPZ file ({e})") from None
    with data:
        for key in (time_key, position_key, *([velocity_key] if velocity_key else [])):
            if key not in data.files:
                raise RecordingError(f"{source}: no array {key!r}; it holds {', '.join(data.files)}")
        t, pos = data[time_key], data[position_key]
        vel = data[velocity_key] if velocity_key else None
    if t.ndim == 1:
        t, pos, vel = t[None], pos[None], (vel[None] if vel is not None else None)
    if pos.ndim == 2:  # (N, T) of one coordinate
        pos = pos[..., None]
    if t.ndim != 2 or pos.ndim != 3 or pos.shape[:2] != t.shape:
        raise RecordingError(
            f"{source}: {time_key!r} {t.shape} and {position_key!r} {pos.shape} do not match; "
            "expected (T,) and (T, d), or (N, T) and (N, T, d)"
        )
    columns = tuple(columns) if columns is not None else tuple(f"{position_key}[{k}]" for k in range(pos.shape[2]))
    scale = unit_scale(units, source)
    return [
        Recording(
            **_scaled({"t": t[n], "pos": pos[n], "vel": vel[n] if vel is not None else None}, scale),
            source=f"{source} [demonstration {n}]" if t.shape[0] > 1 else source,
            columns=columns,
            rows=np.arange(t.shape[1]) + 1,
        )
        for n in range(t.shape[0])
    ]


# ------------------------------------------------------------------------------------------------ HDF5
def _h5py():
    try:
        import h5py
    except ImportError:
        raise RecordingError("reading HDF5 recordings needs h5py: pip install h5py") from None
    return h5py


def read_hdf5(
    path: str | Path,
    position_key: str,
    group: str = "data",
    time_key: str | None = None,
    rate: float | None = None,
    columns: Sequence[str] | None = None,
    units: str = "m",
) -> list[Recording]:
    """Demonstrations from an HDF5 file laid out as robomimic does: one subgroup of ``group`` per demonstration
    (``data/demo_0``, ``data/demo_1``, … in natural order), positions at ``position_key`` inside it (e.g.
    ``obs/robot0_joint_pos``), times at ``time_key`` or, where the layout stores none, a fixed ``rate`` (Hz)."""
    h5py = _h5py()
    path = Path(path)
    source = str(path)
    if (time_key is None) == (rate is None):
        raise RecordingError(
            f"{source}: give either a time dataset (time_key) or a sampling rate (rate), not "
            f"{'both' if rate is not None else 'neither'}"
        )
    try:
        fh = h5py.File(path, "r")
    except OSError as e:
        raise RecordingError(f"{source}: not a readable HDF5 file ({e})") from None
    scale = unit_scale(units, source)
    out = []
    with fh:
        if group not in fh:
            raise RecordingError(f"{source}: no group {group!r}; top level holds {', '.join(fh.keys())}")
        names = sorted(fh[group].keys(), key=lambda s: (len(s), s))  # demo_2 before demo_10
        for name in names:
            demo = fh[group][name]
            label = f"{source} [{group}/{name}]"
            if position_key not in demo:
                raise RecordingError(f"{label}: no dataset {position_key!r}")
            pos = np.asarray(demo[position_key], dtype=np.float64)
            if time_key is not None:
                if time_key not in demo:
                    raise RecordingError(f"{label}: no dataset {time_key!r}")
                t = np.asarray(demo[time_key], dtype=np.float64).reshape(-1)
            else:
                assert rate is not None  # one of the two is given (checked above)
                t = np.arange(pos.shape[0]) / float(rate)
            cols = (
                tuple(columns)
                if columns is not None
                else tuple(f"{position_key}[{k}]" for k in range(pos.shape[1] if pos.ndim > 1 else 1))
            )
            out.append(Recording(t=t, pos=pos * scale, source=label, columns=cols, rows=np.arange(t.shape[0]) + 1))
    if not out:
        raise RecordingError(f"{source}: group {group!r} holds no demonstrations")
    return out
