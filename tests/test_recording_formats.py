"""The recorded data block is one typed block per format (``RECORDING_FORMATS``): a key of another format is refused
by the chosen format's model, naming the key, the format and the formats that read it; the reader is looked up by
format; a stored run's block, which listed every format's keys, reads as the block it ran with."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

import numpy as np
import pytest
from pydantic import ValidationError

from rmpfusion.assembly.errors import ConfigError
from rmpfusion.pipeline.config import upgrade_run_config
from rmpfusion.pipeline.validate import parse_run_config
from rmpfusion.recordings import CsvData, LasaData, NpzData, RecordedDataConfig, Recording, RosbagData
from rmpfusion.recordings.formats import _FileData, flat_dump
from rmpfusion.recordings.source import read_recordings
from rmpfusion.registry import RECORDING_FORMATS


def block(**keys):
    return RecordedDataConfig.model_validate({"source": "recorded", **keys})


@pytest.mark.parametrize(
    ("keys", "refused"),
    [
        # a CSV's keys given to an NPZ run
        (
            {"format": "npz", "files": ["d.npz"], "demo_column": "demo"},
            r"data\.demo_column='demo' is not read by format npz \(read by: csv\); set data\.demo_column=null",
        ),
        (
            {"format": "npz", "files": ["d.npz"], "aux_columns": {"goal": ["gx", "gy"]}},
            r"data\.aux_columns=\{'goal': \['gx', 'gy'\]\} is not read by format npz \(read by: csv\)",
        ),
        # a ROS bag's topic given to a CSV run
        (
            {"format": "csv", "files": ["d.csv"], "topic": "/joint_states"},
            r"data\.topic='/joint_states' is not read by format csv \(read by: rosbag\); set data\.topic=null",
        ),
        # a file format's key given to LASA, an array's to a bag
        (
            {"format": "lasa", "shape": "Angle", "time_units": "ms"},
            r"data\.time_units='ms' is not read by format lasa \(read by: csv, hdf5, npz\); set data\.time_units=s",
        ),
        (
            {"format": "rosbag", "files": ["b.bag"], "position_key": "q"},
            r"data\.position_key='q' is not read by format rosbag \(read by: hdf5, npz\)",
        ),
    ],
)
def test_a_key_of_another_format_is_refused_by_name(keys, refused):
    with pytest.raises(ValidationError, match=refused):
        block(**keys)


def test_the_refusal_names_the_key_in_a_whole_run_config():
    """Through the run config's schema (what every command validates), the message says the key and the fix."""
    run = {
        "env": {"type": "plane"},
        "tree": {"root": {"dim": 2}, "nodes": {}},
        "data": {"source": "recorded", "format": "npz", "files": ["d.npz"], "demo_column": "demo"},
    }
    with pytest.raises(ConfigError) as e:
        parse_run_config(run)
    assert any(
        i.path == "data" and "data.demo_column='demo' is not read by format npz (read by: csv)" in i.message
        for i in e.value.issues
    ), e.value.issues


def test_each_format_is_its_own_model():
    assert isinstance(block(format="csv", files="d.csv"), CsvData)
    assert isinstance(block(format="npz", files=["d.npz"]), NpzData)
    assert isinstance(block(format="rosbag", files=["b.bag"]), RosbagData)
    lasa = block(format="lasa", shape="Angle")
    assert isinstance(lasa, LasaData) and "files" not in lasa.model_dump()
    assert set(RECORDING_FORMATS.names()) >= {"csv", "hdf5", "lasa", "npz", "rosbag"}


def test_a_key_no_format_reads_is_an_unknown_key():
    with pytest.raises(ValidationError, match="Extra inputs are not permitted"):
        block(format="csv", files="d.csv", time_colum="t")
    with pytest.raises(ValidationError, match="unknown recording format"):
        block(format="parquet", files="d.parquet")


def test_the_presets_listing_of_other_formats_keys_is_no_setting():
    """conf/data/recorded.yaml lists every format's keys at their defaults: under npz, the CSV's and the bag's keys
    at those values are dropped, and the block is the NPZ block."""
    listed = {"demo_column": None, "topic": None, "shape": None, "time_column": "t", "group": "data"}
    d = block(format="npz", files=["d.npz"], **listed)
    assert isinstance(d, NpzData) and "demo_column" not in d.model_dump() and "group" not in d.model_dump()


def test_a_stored_flat_block_reads_as_the_block_it_ran_with():
    """A run stored when the block listed every key of every format (its config.resolved.yaml) upgrades to the
    format's block, so rerunning the same command resumes it; the dataset cache key is the flat form, as before."""
    d = block(format="csv", files=["d.csv"], demo_column="demo")
    stored = flat_dump(d)
    assert {"shape", "topic", "group", "aux_keys"} <= set(stored)
    upgraded = upgrade_run_config({"data": stored})["data"]
    assert upgraded == d.model_dump()
    assert block(**{k: v for k, v in upgraded.items() if k != "source"}) == d


class _TxtData(_FileData):
    """A toy format: one demonstration per text file of x y rows sampled at ``rate``."""

    format: Literal["txt"] = "txt"
    rate: float = 10.0


def test_a_registered_format_is_validated_and_read_by_its_reader(tmp_path: Path):
    f = tmp_path / "demo.txt"
    np.savetxt(f, np.c_[np.linspace(0, 1, 11), np.linspace(0, 2, 11)])

    def read_txt(d, path, joints):
        pos = np.loadtxt(path)
        return [Recording(t=np.arange(len(pos)) / d.rate, pos=pos, source=str(path), columns=("x", "y"))]

    RECORDING_FORMATS.register("txt", params=_TxtData)(read_txt)
    try:
        d = block(format="txt", files=[str(f)], rate=5.0)
        assert isinstance(d, _TxtData)
        (rec,) = read_recordings(d)
        assert rec.duration == pytest.approx(2.0)
        with pytest.raises(ValidationError, match=r"data\.rate=5\.0 is not read by format csv \(read by: hdf5, txt\)"):
            block(format="csv", files=[str(f)], rate=5.0)
    finally:
        RECORDING_FORMATS.unregister("txt")
