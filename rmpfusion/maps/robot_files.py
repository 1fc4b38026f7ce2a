"""The robots the examples of the joint-space maps are checked on (``rmpfusion.examples``), as data: a robot file of
conf/robot/ (the one the experiments use), read for its ``urdf``, ``joints`` and ``mount``, the keys a map names
its robot by. The file is read when an example's parameters are first read, never on import."""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

from omegaconf import OmegaConf

from ..confdir import conf_dir

#: the keys of a robot file that a joint-space map reads (``robot_params.py::RobotParams``)
MAP_KEYS = ("urdf", "joints", "mount")


def robot_file_params(name: str) -> dict[str, Any]:
    """The ``urdf``, ``joints`` and ``mount`` of ``conf/robot/<name>.yaml`` (those it gives)."""
    path = Path(conf_dir()) / "robot" / f"{name}.yaml"
    if not path.is_file():
        raise FileNotFoundError(f"no robot file {path}: the maps' examples read their robots from conf/robot/")
    data = OmegaConf.to_container(OmegaConf.load(path), resolve=True)
    assert isinstance(data, dict), f"{path} is not a mapping"
    return {k: data[k] for k in MAP_KEYS if data.get(k) is not None}


class RobotFile(Mapping[str, Any]):
    """A map's parameters on the robot of ``conf/robot/<name>.yaml``: that file's ``urdf``, ``joints`` and
    ``mount``, and the map's own parameters ``more`` (``link``, ``offset``, ...). A mapping like any example's
    parameters; the file is read on first use."""

    def __init__(self, name: str, **more: Any):
        self.name, self.more = name, more
        self._params: dict[str, Any] | None = None

    def __call__(self, **more: Any) -> RobotFile:
        """The same robot with further parameters: ``PANDA(link="panda_hand")``."""
        return RobotFile(self.name, **{**self.more, **more})

    def _read(self) -> dict[str, Any]:
        if self._params is None:
            self._params = {**robot_file_params(self.name), **self.more}
        return self._params

    def __getitem__(self, key: str) -> Any:
        return self._read()[key]

    def __iter__(self) -> Iterator[str]:
        return iter(self._read())

    def __len__(self) -> int:
        return len(self._read())

    def __repr__(self) -> str:
        more = "".join(f", {k}={v!r}" for k, v in self.more.items())
        return f"RobotFile({self.name!r}{more})"


#: pybullet_data's Panda arm (conf/robot/panda.yaml: its 7 arm joints, the fingers frozen) and KUKA iiwa
#: (conf/robot/iiwa.yaml)
PANDA = RobotFile("panda")
IIWA = RobotFile("iiwa")
