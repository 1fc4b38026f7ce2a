"""A URDF's collision geometry as surface samples in each link's frame: what control spheres must cover.

Meshes are read with trimesh (STL, OBJ and the other formats it reads without extras); boxes, cylinders and
spheres are built by trimesh as well, so every element is sampled the same way. Mesh file names are resolved as
simulators do: ``package://<pkg>/<path>`` and relative paths against the URDF's folder.
"""
from __future__ import annotations

import os
import xml.etree.ElementTree as ET

import numpy as np

from ..maps.kinematics import rpy_matrix
from ..maps.urdf import resolve_urdf_path


def _floats(text: str | None, default: list[float]) -> list[float]:
    return default if text is None else [float(v) for v in text.split()]


def _mesh_file(name: str, urdf_dir: str) -> str:
    rel = name[len("package://"):] if name.startswith("package://") else name
    for candidate in (os.path.join(urdf_dir, rel), os.path.join(urdf_dir, rel.partition("/")[2])):
        if os.path.isfile(candidate):
            return candidate
    raise FileNotFoundError(f"collision mesh {name!r} not found next to the URDF ({urdf_dir})")


def _element_mesh(geometry: ET.Element, urdf_dir: str):
    import trimesh

    mesh, box, cyl, sph = (geometry.find(t) for t in ("mesh", "box", "cylinder", "sphere"))
    if mesh is not None:
        m = trimesh.load(_mesh_file(mesh.get("filename"), urdf_dir), force="mesh")
        m.apply_scale(_floats(mesh.get("scale"), [1.0, 1.0, 1.0]))
        return m
    if box is not None:
        return trimesh.creation.box(extents=_floats(box.get("size"), [0.0, 0.0, 0.0]))
    if cyl is not None:
        return trimesh.creation.cylinder(radius=float(cyl.get("radius")), height=float(cyl.get("length")))
    if sph is not None:
        return trimesh.creation.icosphere(radius=float(sph.get("radius")))
    return None


def collision_meshes(urdf: str) -> dict[str, object]:
    """Link name -> its collision geometry as one trimesh mesh in the link's frame (links without any left out)."""
    import trimesh

    path = resolve_urdf_path(urdf)
    root, urdf_dir, out = ET.parse(path).getroot(), os.path.dirname(path), {}
    for link in root.findall("link"):
        parts = []
        for col in link.findall("collision"):
            geometry = col.find("geometry")
            m = None if geometry is None else _element_mesh(geometry, urdf_dir)
            if m is None:
                continue
            o = col.find("origin")
            T = np.eye(4)
            T[:3, :3] = rpy_matrix(_floats(None if o is None else o.get("rpy"), [0.0, 0.0, 0.0])).numpy()
            T[:3, 3] = _floats(None if o is None else o.get("xyz"), [0.0, 0.0, 0.0])
            parts.append(m.apply_transform(T))
        if parts:
            out[link.get("name")] = trimesh.util.concatenate(parts)
    return out


def surface_samples(mesh, n: int, seed: int) -> np.ndarray:
    """(n, 3) points drawn uniformly (by area) on a mesh's surface, reproducibly."""
    import trimesh

    points, _ = trimesh.sample.sample_surface(mesh, n, seed=seed)
    return np.asarray(points, dtype=np.float64)
