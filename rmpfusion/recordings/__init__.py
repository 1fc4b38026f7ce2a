"""Recorded demonstrations: files a person recorded (CSV, NPZ, HDF5, the LASA handwriting dataset) read into
one :class:`Recording` type, resampled onto a step grid, differentiated by one smoothing filter, trimmed of the
rest at either end, and split by whole demonstration."""
from .lasa import SHAPES, SINGLE_PATTERN_SHAPES, lasa_file, read_lasa
from .readers import UNITS, read_csv, read_hdf5, read_npz
from .recording import Recording, RecordingError
from .signals import States, moving_span, resample, savgol_derivatives, to_states
from .dataset import recorded_dataset
from .joints import check_joint_recordings
from .splits import Split, holdout, leave_one_out

__all__ = ["Recording", "RecordingError", "read_csv", "read_npz", "read_hdf5", "read_lasa", "lasa_file", "SHAPES",
           "SINGLE_PATTERN_SHAPES", "UNITS", "States", "resample", "savgol_derivatives", "moving_span", "to_states",
           "Split", "holdout", "leave_one_out", "recorded_dataset", "check_joint_recordings"]
