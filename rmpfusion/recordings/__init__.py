"""Recorded demonstrations: files a person recorded (CSV, NPZ, HDF5, ROS bags, the LASA handwriting dataset) read into
one :class:`Recording` type, resampled onto a step grid, differentiated by one smoothing filter, trimmed of the
rest at either end, and split by whole demonstration."""

from .dataset import recorded_dataset
from .formats import CsvData, Hdf5Data, LasaData, NpzData, RecordedDataConfig, RosbagData
from .joints import check_joint_recordings, check_units
from .lasa import SHAPES, SINGLE_PATTERN_SHAPES, lasa_file, read_lasa
from .readers import UNITS, read_csv, read_hdf5, read_npz
from .recording import Recording, RecordingError, TimeOrderError
from .rosbag import read_rosbag
from .signals import States, moving_span, resample, savgol_derivatives, to_states
from .splits import Split, holdout, leave_one_out, split_of

__all__ = [
    "SHAPES",
    "SINGLE_PATTERN_SHAPES",
    "UNITS",
    "CsvData",
    "Hdf5Data",
    "LasaData",
    "NpzData",
    "RecordedDataConfig",
    "Recording",
    "RecordingError",
    "RosbagData",
    "Split",
    "States",
    "TimeOrderError",
    "check_joint_recordings",
    "check_units",
    "holdout",
    "lasa_file",
    "leave_one_out",
    "moving_span",
    "read_csv",
    "read_hdf5",
    "read_lasa",
    "read_npz",
    "read_rosbag",
    "recorded_dataset",
    "resample",
    "savgol_derivatives",
    "split_of",
    "to_states",
]
