"""Robots described in MuJoCo's MJCF: the ``mjcf`` robot kind (``type: mjcf`` in a robot file).

MuJoCo compiles the file (its defaults, ``<include>``s, frames and orientations of every spelling resolved); the
compiled model is then written out as an equivalent URDF (cached by the file's content), which every other part of
rmpfusion reads as it reads any robot's: the kinematic chain and the maps built from it, sphere fitting, pybullet and
MuJoCo worlds. What the compiled model holds, per body: its pose in its parent (the joint origin), at most one hinge
(revolute, or continuous when unlimited) or slide (prismatic) joint whose axis passes through the body's origin, its
mass and inertia, and its collision geoms (spheres, boxes and cylinders as URDF primitives; capsules and meshes as
STL meshes written beside the URDF). A body with several joints, a joint away from its body's origin, a ball or free
joint is refused with the body's name: URDF cannot say it.
"""

from __future__ import annotations

import hashlib
import math
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any, Literal

import numpy as np
from pydantic import Field, model_validator

from ..files import atomic_write_bytes
from ..maps.urdf import resolve_urdf_path
from ..registry import ROBOTS
from ..robots import RobotDescription, URDFRobot
from ..robots.packages import cache_dir
from .mujoco_backend import import_mujoco
from .protocol import SimulationError

#: the velocity limit (rad/s, m/s) of a joint, which MJCF does not state; override it with the robot file's ``limits``
DEFAULT_VELOCITY = 10.0


class MJCFError(ValueError):
    """An MJCF file whose robot URDF cannot express; the message names the body and what to change."""


def _rpy(R: np.ndarray) -> tuple[float, float, float]:
    """Fixed-axis roll, pitch, yaw of a rotation matrix (URDF's convention, R = Rz(y) Ry(p) Rx(r))."""
    pitch = math.asin(max(-1.0, min(1.0, -R[2, 0])))
    if abs(R[2, 0]) < 1 - 1e-12:
        return math.atan2(R[2, 1], R[2, 2]), pitch, math.atan2(R[1, 0], R[0, 0])
    return 0.0, pitch, math.atan2(-R[0, 1], R[1, 1])


def _origin(parent: ET.Element, pos: np.ndarray, quat: np.ndarray, mj: Any) -> None:
    R = np.empty(9)
    mj.mju_quat2Mat(R, np.asarray(quat, dtype=float))
    ET.SubElement(
        parent,
        "origin",
        xyz=" ".join(repr(float(v)) for v in pos),
        rpy=" ".join(repr(v) for v in _rpy(R.reshape(3, 3))),
    )


def _name(m: Any, mj: Any, kind: Any, i: int, fallback: str) -> str:
    return mj.mj_id2name(m, kind, i) or fallback


def _mesh_file(m: Any, mesh: int, folder: Path) -> str:
    """The compiled mesh ``mesh`` (vertices in its geom's frame) as a binary STL in ``folder``."""
    import trimesh  # the mesh writer rmpfusion-fit-spheres' reader comes from

    v0, nv = m.mesh_vertadr[mesh], m.mesh_vertnum[mesh]
    f0, nf = m.mesh_faceadr[mesh], m.mesh_facenum[mesh]
    data = trimesh.Trimesh(m.mesh_vert[v0 : v0 + nv], m.mesh_face[f0 : f0 + nf], process=False).export(file_type="stl")
    assert isinstance(data, bytes)  # STL is written binary
    path = folder / f"mesh{mesh}.stl"
    atomic_write_bytes(path, data)
    return str(path)


def _capsule_file(radius: float, half: float, folder: Path, g: int) -> str:
    import trimesh

    data = trimesh.creation.capsule(height=2 * half, radius=radius, count=[16, 16]).export(file_type="stl")
    assert isinstance(data, bytes)
    path = folder / f"capsule{g}.stl"
    atomic_write_bytes(path, data)
    return str(path)


def _collision(link: ET.Element, m: Any, mj: Any, g: int, folder: Path) -> None:
    kind, size = int(m.geom_type[g]), m.geom_size[g]
    col = ET.SubElement(link, "collision")
    _origin(col, m.geom_pos[g], m.geom_quat[g], mj)
    geometry = ET.SubElement(col, "geometry")
    if kind == int(mj.mjtGeom.mjGEOM_SPHERE):
        ET.SubElement(geometry, "sphere", radius=repr(float(size[0])))
    elif kind == int(mj.mjtGeom.mjGEOM_BOX):
        ET.SubElement(geometry, "box", size=" ".join(repr(2 * float(s)) for s in size))
    elif kind == int(mj.mjtGeom.mjGEOM_CYLINDER):
        ET.SubElement(geometry, "cylinder", radius=repr(float(size[0])), length=repr(2 * float(size[1])))
    elif kind == int(mj.mjtGeom.mjGEOM_CAPSULE):
        ET.SubElement(geometry, "mesh", filename=_capsule_file(float(size[0]), float(size[1]), folder, g))
    elif kind == int(mj.mjtGeom.mjGEOM_MESH):
        ET.SubElement(geometry, "mesh", filename=_mesh_file(m, m.geom_dataid[g], folder))
    else:
        link.remove(col)  # planes, ellipsoids, height fields: not part of an arm's collision model here


def _joint(root: ET.Element, m: Any, mj: Any, body: int, parent: str, child: str, source: str) -> None:
    count = m.body_jntnum[body]
    if count > 1:
        raise MJCFError(f"{source}: body '{child}' has {count} joints; give each joint a body of its own")
    el = ET.SubElement(root, "joint", name=f"{child}_fixed", type="fixed")
    if count == 1:
        j = m.body_jntadr[body]
        name = _name(m, mj, mj.mjtObj.mjOBJ_JOINT, j, f"joint{j}")
        if np.abs(m.jnt_pos[j]).max() > 1e-12:
            raise MJCFError(
                f"{source}: joint '{name}' sits at pos {m.jnt_pos[j].tolist()} in body '{child}'; URDF turns a joint "
                f"about its child's origin: move the body's pos to the joint and the joint's pos to 0"
            )
        kinds = {int(mj.mjtJoint.mjJNT_HINGE): "revolute", int(mj.mjtJoint.mjJNT_SLIDE): "prismatic"}
        if int(m.jnt_type[j]) not in kinds:
            raise MJCFError(
                f"{source}: joint '{name}' of body '{child}' is a ball or free joint; an arm has hinges or slides"
            )
        limited = bool(m.jnt_limited[j])
        kind = (
            kinds[int(m.jnt_type[j])] if limited or int(m.jnt_type[j]) != int(mj.mjtJoint.mjJNT_HINGE) else "continuous"
        )
        el.set("name", name)
        el.set("type", kind)
    ET.SubElement(el, "parent", link=parent)
    ET.SubElement(el, "child", link=child)
    _origin(el, m.body_pos[body], m.body_quat[body], mj)
    if count == 1:
        ET.SubElement(el, "axis", xyz=" ".join(repr(float(a)) for a in m.jnt_axis[j]))
        lo, hi = (float(x) for x in m.jnt_range[j]) if m.jnt_limited[j] else (0.0, 0.0)
        ET.SubElement(el, "limit", lower=repr(lo), upper=repr(hi), effort="100.0", velocity=repr(DEFAULT_VELOCITY))


def urdf_of_mjcf(mjcf: str) -> str:
    """The path of a URDF equivalent to the MJCF file ``mjcf`` (a path or pkg://), written from MuJoCo's compiled model
    into the cache (``$RMPFUSION_CACHE/mjcf``) once per file content."""
    mj = import_mujoco()
    path = resolve_urdf_path(mjcf)
    source = Path(path).read_bytes()
    folder = cache_dir().parent / "mjcf" / hashlib.sha256(source + path.encode()).hexdigest()[:16]
    out = folder / (Path(path).stem + ".urdf")
    if out.is_file():
        return str(out)
    try:
        m = mj.MjModel.from_xml_path(path)
    except ValueError as e:
        raise MJCFError(f"{mjcf}: MuJoCo cannot compile it: {e}") from None
    root = ET.Element("robot", name=Path(path).stem)
    names = {0: "world"}
    for b in range(1, m.nbody):
        names[b] = _name(m, mj, mj.mjtObj.mjOBJ_BODY, b, f"body{b}")
    for b in range(m.nbody):
        link = ET.SubElement(root, "link", name=names[b])
        if b > 0 and m.body_mass[b] > 0:
            inertial = ET.SubElement(link, "inertial")
            _origin(inertial, m.body_ipos[b], m.body_iquat[b], mj)
            ET.SubElement(inertial, "mass", value=repr(float(m.body_mass[b])))
            ixx, iyy, izz = (float(v) for v in m.body_inertia[b])
            ET.SubElement(inertial, "inertia", ixx=repr(ixx), iyy=repr(iyy), izz=repr(izz), ixy="0", ixz="0", iyz="0")
        for g in np.flatnonzero(m.geom_bodyid == b):
            if b > 0 and (m.geom_contype[g] or m.geom_conaffinity[g]):
                _collision(link, m, mj, int(g), folder)
        if b > 0:
            _joint(root, m, mj, b, names[m.body_parentid[b]], names[b], mjcf)
    atomic_write_bytes(out, ET.tostring(root, encoding="utf-8"))
    return str(out)


class MJCFDescription(RobotDescription):
    """A fixed-base arm described by an MJCF file: as a URDF robot, with ``mjcf`` naming the file and ``urdf`` the
    equivalent written from MuJoCo's compiled model (leave it out)."""

    type: Literal["mjcf"] = "mjcf"  # type: ignore[assignment]  # a robot kind names itself
    mjcf: str = Field(description="an MJCF file (path or pkg://<package>/<path>); MuJoCo compiles it")
    urdf: str = Field("", description="written from the MJCF: leave it out")

    @model_validator(mode="before")
    @classmethod
    def _urdf_from_the_mjcf(cls, data: Any) -> Any:
        if isinstance(data, dict) and data.get("mjcf") and not data.get("urdf"):
            try:
                data = {**data, "urdf": urdf_of_mjcf(str(data["mjcf"]))}
            except FileNotFoundError as e:
                raise ValueError(f"mjcf: {e}; fix mjcf: in the robot's file to name an MJCF that exists") from None
            except SimulationError as e:  # MuJoCo is not installed
                raise ValueError(f"mjcf: {e}") from None
        return data


@ROBOTS.register("mjcf")
class MJCFRobot(URDFRobot):
    """A robot from its MJCF file (through the URDF written from MuJoCo's compiled model)."""

    Params = MJCFDescription  # type: ignore[assignment]  # pydantic's plugin types the constructors apart
