"""Where a URDF's mesh files are: ``package://NAME/…`` found as ROS tools find it, ``file://`` URIs and paths relative
to the URDF, and the resolved copy of a URDF (every mesh an absolute path) that every consumer reads.

``package://NAME/rest`` is looked for in this order, the first place that knows NAME answering:

1. ``packages: {NAME: PATH}`` of the robot file (``env.robot.packages.NAME=PATH`` on the command line,
   ``--package-dir NAME=PATH`` for ``rmpfusion-fit-spheres``); PATH may be ``pkg://<python package>/<folder>``,
   and ``null`` (what ``rmpfusion-fit-spheres`` writes for every package the URDF names, so the key exists to be
   set on a command line) means the steps below;
2. ``ROS_PACKAGE_PATH``: a folder named NAME, or holding a ``package.xml`` that names NAME, in or under each entry;
3. ``AMENT_PREFIX_PATH``: ``<prefix>/share/NAME`` of each prefix;
4. the folders above the URDF: one named NAME, or holding a ``package.xml`` that names NAME;
5. failing all of these, the URI as a path from the URDF's folder (with and without NAME), as pybullet reads it.

Two different folders at the same step are an error naming both (which one is meant cannot be guessed). A mesh that
is not found is one error naming the link, the URI and every place looked in.

The sphere fitter resolves only the meshes of the links it fits; simulators load ``resolved_urdf``: a copy of the
URDF with every mesh an absolute path, cached by content, written atomically, so no consumer relies on a search of
its own (pybullet's would find other files, or none).
"""

from __future__ import annotations

import hashlib
import os
import re
import xml.etree.ElementTree as ET
from collections.abc import Mapping
from pathlib import Path

from ..files import atomic_write_bytes
from ..maps.urdf import resolve_urdf_path

PACKAGE_URI = "package://"
FILE_URI = "file://"
_ROS_SEARCH_DEPTH = 4  # how deep under a ROS_PACKAGE_PATH entry packages are looked for


class MeshNotFound(FileNotFoundError):
    """A mesh a URDF names is nowhere it was looked for."""


class PackageConflict(ValueError):
    """Two different folders claim one ROS package at the same step of the search."""


def _package_xml_names(folder: str) -> str | None:
    """The <name> a folder's package.xml declares (None without one, or unreadable)."""
    path = os.path.join(folder, "package.xml")
    if not os.path.isfile(path):
        return None
    try:
        name = ET.parse(path).getroot().findtext("name")
    except ET.ParseError:
        return None
    return name.strip() if name else None


def _is_package(folder: str, name: str) -> bool:
    return os.path.isdir(folder) and (
        os.path.basename(os.path.normpath(folder)) == name or _package_xml_names(folder) == name
    )


def _under(entry: str, name: str) -> list[str]:
    """Folders in or under ``entry`` that are package ``name`` (a package's own subfolders are not searched)."""
    found, start = [], os.path.normpath(entry)
    for here, subdirs, _ in os.walk(start):
        if _is_package(here, name):
            found.append(here)
        if _package_xml_names(here) is not None or here[len(start) :].count(os.sep) >= _ROS_SEARCH_DEPTH:
            subdirs.clear()
        subdirs[:] = [d for d in subdirs if not d.startswith(".")]
    return found


def package_folder(name: str, given: str) -> str:
    """The folder ``packages: {name: given}`` names (a path, ``file://`` or ``pkg://``), which must exist."""
    try:
        path = resolve_urdf_path(given)
    except FileNotFoundError as e:
        raise FileNotFoundError(f"packages.{name} = {given!r}: {e}") from None
    if not os.path.isdir(path):
        raise FileNotFoundError(
            f"packages.{name} = {given!r}: no folder {path}; give the folder that holds the "
            f"package's files (the one with its package.xml)"
        )
    return path


def _explicit(name: str, given: str) -> list[str]:
    return [package_folder(name, given)]


def _steps(name: str, urdf_path: str, packages: Mapping[str, str | None]) -> list[tuple[str, list[str], list[str]]]:
    """(what the step is, the folders it looked at, the folders it found) for each step of the search, in order."""
    env = os.environ
    ros = [e for e in env.get("ROS_PACKAGE_PATH", "").split(os.pathsep) if e]
    ament = [os.path.join(e, "share", name) for e in env.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if e]
    above = [str(p) for p in Path(urdf_path).resolve().parent.parents] + [str(Path(urdf_path).resolve().parent)]
    above = sorted(set(above), key=len, reverse=True)  # nearest first
    given = packages.get(name)  # None: listed without a folder, to be searched for (and set on a command line)
    return [
        ("packages", [given] if given else [], _explicit(name, given) if given else []),
        ("ROS_PACKAGE_PATH", ros, [f for e in ros if os.path.isdir(e) for f in _under(e, name)]),
        ("AMENT_PREFIX_PATH", ament, [a for a in ament if os.path.isdir(a)]),
        ("above the URDF", above, [a for a in above if _is_package(a, name)][:1]),
    ]


def package_dir(
    name: str, urdf_path: str, packages: Mapping[str, str | None] | None = None
) -> tuple[str | None, list[str]]:
    """(the folder of ROS package ``name`` or None, every place looked in), searched in the module's order."""
    looked: list[str] = []
    for step, places, found in _steps(name, urdf_path, packages or {}):
        looked += [f"{p} ({step})" for p in places]
        distinct = sorted({os.path.realpath(f) for f in found})
        if len(distinct) > 1:
            raise PackageConflict(
                f"package {name!r} is found twice by {step}: {distinct[0]} and {distinct[1]}; say "
                f"which one is meant with packages: {{{name}: PATH}} in the robot file "
                f"(--package-dir {name}=PATH)"
            )
        if distinct:
            return found[0], looked
    return None, looked


def mesh_path(uri: str, link: str, urdf_path: str, packages: Mapping[str, str | None] | None = None) -> str:
    """The file a mesh URI of ``link`` names: ``package://``, ``file://``, absolute, or relative to the URDF."""
    urdf_dir = os.path.dirname(os.path.abspath(urdf_path))
    if uri.startswith(PACKAGE_URI):
        name, _, rest = uri[len(PACKAGE_URI) :].partition("/")
        root, looked = package_dir(name, urdf_path, packages)
        # no package of that name: the URI read as a path from the URDF's folder, as pybullet reads it (some
        # published URDFs write package://meshes/... for meshes beside them)
        candidates = (
            [os.path.join(root, rest)]
            if root is not None
            else [os.path.join(urdf_dir, name, rest), os.path.join(urdf_dir, rest)]
        )
    elif uri.startswith(FILE_URI):
        candidates, looked = [uri[len(FILE_URI) :]], []
    else:
        candidates, looked = [uri if os.path.isabs(uri) else os.path.join(urdf_dir, uri)], []
    for c in candidates:
        if os.path.isfile(c):
            return os.path.abspath(c)
    places = "; ".join(looked + candidates) or "nowhere"
    raise MeshNotFound(
        f"{urdf_path}: link {link!r}: mesh {uri!r} not found; looked in: {places}. Give the package's "
        f"folder as packages: {{NAME: PATH}} in the robot file (--package-dir NAME=PATH), or set "
        f"ROS_PACKAGE_PATH"
    )


def package_names(urdf: str) -> list[str]:
    """The ROS packages a URDF's ``package://`` mesh URIs name, in order of first use."""
    names: list[str] = []
    for _, mesh in link_meshes(ET.parse(resolve_urdf_path(urdf)).getroot()):
        uri = mesh.get("filename") or ""
        if uri.startswith(PACKAGE_URI):
            name = uri[len(PACKAGE_URI) :].partition("/")[0]
            if name not in names:
                names.append(name)
    return names


def link_meshes(root: ET.Element) -> list[tuple[str, ET.Element]]:
    """(link name, <mesh> element) of every mesh of every link, visuals and collisions."""
    return [(link.get("name", ""), mesh) for link in root.findall("link") for mesh in link.iter("mesh")]


def cache_dir() -> Path:
    """Where resolved URDFs are kept: ``$RMPFUSION_CACHE/urdf`` (default ``~/.cache/rmpfusion/urdf``)."""
    base = os.environ.get("RMPFUSION_CACHE") or os.path.join(
        os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache"), "rmpfusion"
    )
    return Path(base) / "urdf"


def resolved_urdf(urdf: str, packages: Mapping[str, str | None] | None = None) -> str:
    """A copy of the URDF with every mesh an absolute path (cached by the URDF's text and where its meshes are;
    written atomically), or the URDF itself when it names no mesh that needs resolving."""
    path = resolve_urdf_path(urdf)
    text = Path(path).read_text(encoding="utf-8")
    root = ET.fromstring(text)
    changed = False
    for link, mesh in link_meshes(root):
        uri = mesh.get("filename") or ""
        found = mesh_path(uri, link, path, packages)
        if found != uri:
            mesh.set("filename", found)
            changed = True
    if not changed:
        return path
    data = ET.tostring(root, encoding="utf-8")
    key = hashlib.sha256(data).hexdigest()[:16]
    stem = re.sub(r"[^A-Za-z0-9_.-]", "_", Path(path).stem)
    out = cache_dir() / f"{stem}-{key}.urdf"
    if not out.is_file():
        atomic_write_bytes(out, data)
    return str(out)
