"""A URDF's collision geometry as surface samples in each link's frame: what control spheres must cover.

Meshes are read with trimesh, in every format it reads (STL, OBJ, PLY, GLB, and COLLADA ``.dae`` through pycollada),
scaled by the URDF's ``scale`` (meshes drawn in millimetres carry ``scale="0.001 0.001 0.001"``); boxes, cylinders
and spheres are built by trimesh as well, so every element is sampled the same way. Mesh files are found as
``robots/packages.py`` says, and only those of the links asked for are read. A link with visual geometry but no
collision geometry is covered by its visual geometry, and the caller is told which links those are.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from ..maps.kinematics import rpy_matrix
from ..maps.urdf import resolve_urdf_path
from .packages import mesh_path


class MeshUnreadable(ValueError):
    """A mesh file trimesh cannot read (a format it lacks a reader for, or a damaged file)."""


def _floats(text: str | None, default: list[float]) -> list[float]:
    return default if text is None else [float(v) for v in text.split()]


def _required(element: ET.Element, key: str, link: str) -> str:
    """An attribute URDF requires of an element (a cylinder's radius): a URDF without it is named, with the link."""
    value = element.get(key)
    if value is None:
        raise ValueError(f"link {link!r}: <{element.tag}> has no {key!r}, which URDF requires")
    return value


def _read_mesh(path: str, link: str):
    import trimesh

    try:
        m = trimesh.load(path, force="mesh")
    except BaseException as e:
        if isinstance(e, (KeyboardInterrupt, SystemExit)):
            raise
        cause = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise MeshUnreadable(
            f"link {link!r}: mesh {path} could not be read ({cause}); convert it to STL or OBJ, "
            f"or install the reader trimesh asks for"
        ) from None
    if not hasattr(m, "faces") or len(m.faces) == 0:
        raise MeshUnreadable(f"link {link!r}: mesh {path} holds no triangles")
    return m


def _element_mesh(geometry: ET.Element, link: str, urdf_path: str, packages: Mapping[str, str | None] | None):
    import trimesh

    mesh, box, cyl, sph = (geometry.find(t) for t in ("mesh", "box", "cylinder", "sphere"))
    if mesh is not None:
        m = _read_mesh(mesh_path(mesh.get("filename") or "", link, urdf_path, packages), link)
        m.apply_scale(_floats(mesh.get("scale"), [1.0, 1.0, 1.0]))
        return m
    if box is not None:
        return trimesh.creation.box(extents=_floats(box.get("size"), [0.0, 0.0, 0.0]))
    if cyl is not None:
        return trimesh.creation.cylinder(
            radius=float(_required(cyl, "radius", link)), height=float(_required(cyl, "length", link))
        )
    if sph is not None:
        return trimesh.creation.icosphere(radius=float(_required(sph, "radius", link)))
    return None


def _link_mesh(link: ET.Element, kind: str, urdf_path: str, packages: Mapping[str, str | None] | None):
    """One link's ``kind`` (collision or visual) geometry as one mesh in its frame, or None without any."""
    import trimesh

    parts = []
    for element in link.findall(kind):
        geometry = element.find("geometry")
        m = None if geometry is None else _element_mesh(geometry, link.get("name", ""), urdf_path, packages)
        if m is None:
            continue
        o = element.find("origin")
        T = np.eye(4)
        T[:3, :3] = rpy_matrix(_floats(None if o is None else o.get("rpy"), [0.0, 0.0, 0.0])).numpy()
        T[:3, 3] = _floats(None if o is None else o.get("xyz"), [0.0, 0.0, 0.0])
        parts.append(m.apply_transform(T))
    return trimesh.util.concatenate(parts) if parts else None


@dataclass
class LinkGeometry:
    """Links' geometry as meshes in their frames, and which of them had only visual geometry to give."""

    meshes: dict[str, object] = field(default_factory=dict)
    from_visual: list[str] = field(default_factory=list)


def link_geometry(
    urdf: str,
    links: Sequence[str] | None = None,
    packages: Mapping[str, str | None] | None = None,
    use_visual: bool = True,
) -> LinkGeometry:
    """The collision geometry of ``links`` (default: every link), read from their meshes only; a link with none
    takes its visual geometry when ``use_visual``. Links with neither are left out."""
    path = resolve_urdf_path(urdf)
    out = LinkGeometry()
    for link in ET.parse(path).getroot().findall("link"):
        name = link.get("name", "")
        if links is not None and name not in links:
            continue
        m = _link_mesh(link, "collision", path, packages)
        if m is None and use_visual:
            m = _link_mesh(link, "visual", path, packages)
            if m is not None:
                out.from_visual.append(name)
        if m is not None:
            out.meshes[name] = m
    return out


def links_with_geometry(urdf: str) -> dict[str, str]:
    """Link -> ``collision`` or ``visual``: which geometry each link that has some would be covered with, read
    from the URDF alone (no mesh file opened)."""
    out: dict[str, str] = {}
    for link in ET.parse(resolve_urdf_path(urdf)).getroot().findall("link"):
        for kind in ("collision", "visual"):
            if any((g := e.find("geometry")) is not None and len(g) for e in link.findall(kind)):
                out[link.get("name", "")] = kind
                break
    return out


def collision_meshes(
    urdf: str, links: Sequence[str] | None = None, packages: Mapping[str, str | None] | None = None
) -> dict[str, object]:
    """Link name -> its collision geometry (else its visual geometry) as one trimesh mesh in the link's frame."""
    return link_geometry(urdf, links, packages).meshes


def surface_samples(mesh, n: int, seed: int) -> np.ndarray:
    """(n, 3) points drawn uniformly (by area) on a mesh's surface, reproducibly."""
    import trimesh

    points, _ = trimesh.sample.sample_surface(mesh, n, seed=seed)
    return np.asarray(points, dtype=np.float64)
