"""Atomic writes: a failure mid-write leaves the previous file intact and no temporary behind."""

import pytest

from rmpfusion.files import atomic_path, atomic_torch_save, atomic_write_json


def test_failed_write_keeps_the_old_file_and_leaves_no_temporary(tmp_path):
    target = tmp_path / "metrics.json"
    atomic_write_json(target, {"loss": 1.0})
    with pytest.raises(RuntimeError), atomic_path(target) as tmp:
        tmp.write_text('{"loss": 2')  # half written
        raise RuntimeError("killed mid-write")
    assert target.read_text().strip().endswith("}") and '"loss": 1.0' in target.read_text()
    assert [p.name for p in tmp_path.iterdir()] == ["metrics.json"]


def test_torch_save_round_trip(tmp_path):
    import torch

    atomic_torch_save({"w": torch.arange(3)}, tmp_path / "ckpt.pt")
    assert torch.equal(torch.load(tmp_path / "ckpt.pt")["w"], torch.arange(3))
