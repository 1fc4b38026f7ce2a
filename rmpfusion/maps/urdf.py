"""A minimal URDF reader: only the kinematic tree, so forward kinematics needs no robotics dependency.

Visuals, collisions and inertias other than the inertial frame are ignored; the inertial frame is kept
because simulators such as pybullet report some quantities relative to it.
"""

from __future__ import annotations

import functools
import math
import os
import sys
import xml.etree.ElementTree as ET
from dataclasses import dataclass

Vec3 = tuple[float, float, float]

JOINT_TYPES = ("revolute", "continuous", "prismatic", "fixed")
#: A URDF inside an installed Python package: ``pkg://<package>/<path inside it>`` (Hydra's spelling of the same idea).
PACKAGE_SCHEME = "pkg://"
XACRO_NAMESPACE = "{http://www.ros.org/wiki/xacro}"


@dataclass(frozen=True)
class Mimic:
    """A URDF ``<mimic joint= multiplier= offset=>``: the joint's value is ``multiplier · q_leader + offset``."""

    leader: str
    multiplier: float = 1.0
    offset: float = 0.0


@dataclass(frozen=True)
class Joint:
    name: str
    type: str  # one of JOINT_TYPES
    parent: str
    child: str
    xyz: Vec3 = (0.0, 0.0, 0.0)
    rpy: Vec3 = (0.0, 0.0, 0.0)
    axis: Vec3 = (1.0, 0.0, 0.0)  # unit vector in the joint frame (URDF default is x)
    lower: float = -math.inf
    upper: float = math.inf
    velocity: float = math.inf
    effort: float = math.inf
    mimic: Mimic | None = None  # this joint follows another: q = multiplier · q_leader + offset

    @property
    def movable(self) -> bool:
        return self.type != "fixed"


@dataclass(frozen=True)
class Link:
    name: str
    inertial_xyz: Vec3 = (0.0, 0.0, 0.0)
    inertial_rpy: Vec3 = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class URDFModel:
    """A kinematic tree; joints are kept in topological order (parents before children)."""

    name: str
    links: tuple[Link, ...]
    joints: tuple[Joint, ...]
    root: str

    def link(self, name: str) -> Link:
        for l in self.links:
            if l.name == name:
                return l
        raise KeyError(f"URDF '{self.name}' has no link '{name}'; links: {', '.join(self.link_names())}")

    def joint(self, name: str) -> Joint:
        for j in self.joints:
            if j.name == name:
                return j
        raise KeyError(f"URDF '{self.name}' has no joint '{name}'; joints: {', '.join(j.name for j in self.joints)}")

    def link_names(self) -> list[str]:
        return [l.name for l in self.links]

    def movable_joint_names(self) -> list[str]:
        return [j.name for j in self.joints if j.movable]

    def parent_joint(self, link: str) -> Joint | None:
        for j in self.joints:
            if j.child == link:
                return j
        return None

    def path_to(self, link: str) -> list[Joint]:
        """Joints from the root down to ``link``."""
        self.link(link)
        path = []
        j = self.parent_joint(link)
        while j is not None:
            path.append(j)
            j = self.parent_joint(j.parent)
        return path[::-1]


def _vec(text: str | None, default: Vec3, what: str) -> Vec3:
    if text is None:
        return default
    vals = [float(v) for v in text.split()]
    if len(vals) != 3:
        raise ValueError(f"URDF {what}: expected 3 numbers, got '{text}'")
    return (vals[0], vals[1], vals[2])


def _origin(el: ET.Element | None) -> tuple[Vec3, Vec3]:
    o = None if el is None else el.find("origin")
    if o is None:
        return (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)
    return _vec(o.get("xyz"), (0.0, 0.0, 0.0), "origin xyz"), _vec(o.get("rpy"), (0.0, 0.0, 0.0), "origin rpy")


def _required(el: ET.Element, key: str, what: str) -> str:
    """An attribute the URDF format requires (a joint's or link's name, the link a joint's parent names): without it
    the element means nothing, so the file is refused rather than read with a name of None."""
    value = el.get(key)
    if value is None:
        raise ValueError(f'URDF {what} has no {key}="..."')
    return value


def _parse_joint(el: ET.Element) -> Joint:
    name, jtype = _required(el, "name", "<joint>"), el.get("type")
    if jtype not in JOINT_TYPES:
        raise ValueError(f"URDF joint '{name}': type '{jtype}' is not supported (supported: {', '.join(JOINT_TYPES)})")
    parent, child = el.find("parent"), el.find("child")
    if parent is None or child is None:
        raise ValueError(f"URDF joint '{name}' needs <parent> and <child>")
    xyz, rpy = _origin(el)
    axis_el = el.find("axis")
    axis = _vec(None if axis_el is None else axis_el.get("xyz"), (1.0, 0.0, 0.0), f"joint '{name}' axis")
    n = math.sqrt(sum(a * a for a in axis))
    if jtype != "fixed":
        if n == 0.0:
            raise ValueError(f"URDF joint '{name}' has a zero axis")
        axis = (axis[0] / n, axis[1] / n, axis[2] / n)
    lim = el.find("limit")

    def get(key: str, default: float) -> float:
        value = None if lim is None else lim.get(key)
        return default if value is None else float(value)

    lower, upper = -math.inf, math.inf
    if jtype in ("revolute", "prismatic"):
        lower, upper = get("lower", -math.inf), get("upper", math.inf)
        if not lower <= upper:  # NaN included: every joint-limit barrier and start range is built from these
            raise ValueError(
                f"URDF joint '{name}': limit lower={lower} is above upper={upper} (the joint could take "
                f"no angle at all); fix the <limit> of the joint"
            )
    return Joint(
        name=name,
        type=jtype,
        parent=_required(parent, "link", f"joint '{name}' <parent>"),
        child=_required(child, "link", f"joint '{name}' <child>"),
        xyz=xyz,
        rpy=rpy,
        axis=axis,
        lower=lower,
        upper=upper,
        velocity=get("velocity", math.inf),
        effort=get("effort", math.inf),
        mimic=_mimic(el, name, jtype),
    )


def _mimic(el: ET.Element, name: str, jtype: str) -> Mimic | None:
    m = el.find("mimic")
    if m is None or jtype == "fixed":
        return None
    leader = m.get("joint")
    if not leader:
        raise ValueError(f"URDF joint '{name}': <mimic> needs joint=\"<the joint it follows>\"")
    return Mimic(leader, float(m.get("multiplier", 1.0)), float(m.get("offset", 0.0)))


def parse_urdf_string(text: str) -> URDFModel:
    """Parse URDF XML text into a kinematic tree (checked: one root, every link with at most one parent)."""
    root_el = ET.fromstring(text)
    if any(el.tag.startswith(XACRO_NAMESPACE) for el in root_el.iter()):
        raise ValueError(
            "this is a xacro file (it holds xacro: elements), not a URDF: run xacro first "
            "(`xacro robot.urdf.xacro > robot.urdf`, with the xacro package) and give the URDF it writes"
        )
    if root_el.tag != "robot":
        raise ValueError(f"URDF root element must be <robot>, got <{root_el.tag}>")
    links = {}
    for el in root_el.findall("link"):
        xyz, rpy = _origin(el.find("inertial"))
        name = _required(el, "name", "<link>")
        links[name] = Link(name, xyz, rpy)
    joints = [_parse_joint(el) for el in root_el.findall("joint")]
    by_child: dict[str, Joint] = {}
    for j in joints:
        for l in (j.parent, j.child):
            if l not in links:
                raise ValueError(f"URDF joint '{j.name}' refers to unknown link '{l}'")
        if j.child in by_child:
            raise ValueError(f"URDF link '{j.child}' has two parent joints ('{by_child[j.child].name}', '{j.name}')")
        by_child[j.child] = j
    roots = [l for l in links if l not in by_child]
    if len(roots) != 1:
        raise ValueError(f"URDF must have exactly one root link, found {roots or 'none (a cycle)'}")
    # breadth-first from the root, children in document order
    ordered_links, ordered_joints, frontier = [roots[0]], [], [roots[0]]
    while frontier:
        nxt = []
        for parent in frontier:
            for j in joints:
                if j.parent == parent:
                    ordered_joints.append(j)
                    ordered_links.append(j.child)
                    nxt.append(j.child)
        frontier = nxt
    if len(ordered_links) != len(links):
        raise ValueError("URDF link graph is not a tree (unreachable links or a cycle)")
    _check_mimics(joints)
    return URDFModel(
        name=root_el.get("name", "robot"),
        links=tuple(links[l] for l in ordered_links),
        joints=tuple(ordered_joints),
        root=roots[0],
    )


def _check_mimics(joints: list[Joint]) -> None:
    """Every mimic follows a movable joint, and following leads to a joint that follows none (no cycle)."""
    by_name = {j.name: j for j in joints}
    for j in joints:
        seen, k = [j.name], j
        while k.mimic is not None:
            leader = by_name.get(k.mimic.leader)
            if leader is None or not leader.movable:
                raise ValueError(f"URDF joint '{k.name}': <mimic joint='{k.mimic.leader}'> names no movable joint")
            if leader.name in seen:
                raise ValueError(
                    f"URDF joints {' -> '.join(seen + [leader.name])}: mimic joints follow each other in a cycle"
                )
            seen.append(leader.name)
            k = leader


@functools.lru_cache(maxsize=16)
def _parse_cached(path: str, mtime: float) -> URDFModel:
    with open(path, encoding="utf-8") as f:
        text = f.read()
    try:
        return parse_urdf_string(text)
    except ValueError as e:  # the file to fix, not only what is wrong in it
        raise ValueError(f"{path}: {e}") from None


def parse_urdf(path: str | os.PathLike) -> URDFModel:
    """Parse a URDF file (a path or ``pkg://``, see ``resolve_urdf_path``); cached per path and modification time
    since every task map on a robot reads it."""
    path = resolve_urdf_path(path)
    if not os.path.isfile(path):
        raise FileNotFoundError(f"URDF file not found: {path}")
    if path.endswith(".xacro"):
        raise ValueError(
            f"{path} is a xacro file, not a URDF: run xacro first (`xacro {os.path.basename(path)} > "
            f"{os.path.basename(path)[: -len('.xacro')] or 'robot'}.urdf`, with the xacro package) and "
            f"give the URDF it writes"
        )
    return _parse_cached(path, os.path.getmtime(path))


def resolve_urdf_path(location: str | os.PathLike) -> str:
    """The file a robot's ``urdf`` names: a path (relative to the working directory), or ``pkg://<package>/<path>``,
    a file inside an installed Python package (``pkg://pybullet_data/kuka_iiwa/model.urdf``), so a config names
    the URDF it means on every machine without an absolute path."""
    text = os.fspath(location)
    if text.startswith("file://"):
        return os.path.abspath(text[len("file://") :])
    if not text.startswith(PACKAGE_SCHEME):
        return os.path.abspath(text)
    package, _, inside = text[len(PACKAGE_SCHEME) :].partition("/")
    root = package_data_dir(package) if package else None
    if root is None or not inside:
        raise FileNotFoundError(
            f"URDF {text!r}: no installed Python package {package!r} to look in; write "
            f"pkg://<package>/<path inside it> for a package that is installed, or a file path"
        )
    return os.path.join(root, inside)


def package_data_dir(package: str) -> str | None:
    """The folder of an installed package (or of any data folder installed beside packages, such as a wheel's
    ``cmeel.prefix``): the first ``sys.path`` entry holding it. Found by looking, never by importing: importing a
    package to find its files runs its code (and its parents'), which a path lookup must not."""
    parts = [package] if "." not in package else [package, *([package.replace(".", os.sep)])]
    for entry in sys.path:
        base = entry or os.getcwd()
        for part in parts:
            candidate = os.path.join(base, part)
            if os.path.isdir(candidate):
                return candidate
    return None
