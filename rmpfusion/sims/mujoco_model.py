"""A robot's URDF made ready for MuJoCo's compiler, and the scene around it.

MuJoCo reads URDF itself, but not as labs publish it: it takes ``package://`` literally (the resolved copy has
absolute paths, ``robots/packages.py``), fuses links joined by fixed joints away (the end effector's frame would
vanish), refuses some published inertias, reads binary STL and OBJ only, and collides with one convex hull per
mesh, so a mesh of several parts would fill the space between them. Here every collision mesh is converted by
trimesh into binary STL files, one per connected part (cached by content), visuals are dropped (the collision
model is what is drawn), joint damping and friction are zeroed (as pybullet's environment does: computed torque
must realise the commanded acceleration), and ``<compiler fusestatic="false" balanceinertia="true">`` keeps every
link. The world then gets a ground plane, a floor for pictures, a goal marker, lights, and obstacle slots as mocap
bodies of the scene's shapes.
"""

from __future__ import annotations

import hashlib
import os
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from ..files import atomic_write_bytes
from ..robots.packages import cache_dir

#: collision classes: robot geoms touch the world's (obstacles, ground) but never each other (as in pybullet, where
#: a fixed-base robot's links do not collide with one another)
ROBOT_CONTYPE, ROBOT_CONAFFINITY = 1, 0
WORLD_CONTYPE, WORLD_CONAFFINITY = 0, 1


#: a connected part of a mesh becomes a geom of its own when its convex hull holds at least this share of the whole
#: mesh's hull's volume (screws and bolt heads are left to the parts around them); at most MAX_PARTS, largest first
PART_SHARE, MAX_PARTS = 1e-3, 32


def mesh_parts(path: str, scale: tuple[float, float, float]) -> list[str]:
    """Binary STL files, one per connected part of the mesh at ``path`` scaled by ``scale`` (``PART_SHARE``,
    ``MAX_PARTS``; cached under ``$RMPFUSION_CACHE/mujoco`` by the file's content, the scale and these rules)."""
    source = Path(path).read_bytes()
    key = hashlib.sha256(source + repr((tuple(scale), PART_SHARE, MAX_PARTS)).encode()).hexdigest()[:16]
    folder = cache_dir().parent / "mujoco" / key
    done = folder / "parts.txt"
    if done.is_file():
        return [str(folder / name) for name in done.read_text().split()]
    import trimesh  # the mesh reader rmpfusion-fit-spheres uses too

    mesh = trimesh.load(path, force="mesh", process=True)
    assert isinstance(mesh, trimesh.Trimesh)  # force="mesh" concatenates a scene into one
    mesh.apply_scale(np.asarray(scale, dtype=float))
    mesh.merge_vertices(merge_tex=True, merge_norm=True)  # faces that share a corner are one part, whatever its UVs
    with np.errstate(invalid="ignore", divide="ignore"):  # a flat piece has no centre of mass
        pieces = [(p, _volume(p)) for p in mesh.split(only_watertight=False) if len(p.vertices) >= 4]
    whole = _volume(mesh)
    pieces = sorted((pv for pv in pieces if pv[1] >= PART_SHARE * whole), key=lambda pv: -pv[1])[:MAX_PARTS]
    parts = [p for p, _ in pieces] or [mesh]  # nothing big enough: the whole mesh, hulled
    names = []
    for i, part in enumerate(parts):
        name = f"part{i}.stl"
        data = part.export(file_type="stl")
        assert isinstance(data, bytes)  # STL is written binary
        atomic_write_bytes(folder / name, data)
        names.append(name)
    atomic_write_bytes(done, " ".join(names).encode())
    return [str(folder / name) for name in names]


def _volume(part) -> float:
    from scipy.spatial import QhullError  # trimesh hulls with scipy's qhull

    try:
        return float(part.convex_hull.volume)
    except QhullError:  # a flat or degenerate piece
        return 0.0


def mujoco_urdf(urdf_path: str) -> str:
    """The URDF text MuJoCo compiles: collision meshes as convex parts, no visuals (removed here: the compiler's
    discardvisual would also drop the world's drawn-only geoms), no joint damping or friction,
    every link kept."""
    root = ET.parse(urdf_path).getroot()
    base = os.path.dirname(os.path.abspath(urdf_path))
    for link in root.findall("link"):
        for visual in link.findall("visual"):
            link.remove(visual)
        for collision in list(link.findall("collision")):
            mesh = collision.find("geometry/mesh")
            if mesh is None:
                continue
            filename = mesh.get("filename", "")
            path = filename if os.path.isabs(filename) else os.path.join(base, filename.removeprefix("file://"))
            scale = tuple(float(s) for s in (mesh.get("scale") or "1 1 1").split())
            at = list(link).index(collision)
            link.remove(collision)
            for k, part in enumerate(mesh_parts(path, scale)):  # type: ignore[arg-type]  # three scale factors
                copy = ET.fromstring(ET.tostring(collision))
                part_mesh = copy.find("geometry/mesh")
                assert part_mesh is not None
                part_mesh.set("filename", part)
                part_mesh.attrib.pop("scale", None)
                link.insert(at + k, copy)
    for joint in root.findall("joint"):
        for dynamics in joint.findall("dynamics"):
            joint.remove(dynamics)
    extension = ET.SubElement(root, "mujoco")
    ET.SubElement(
        extension, "compiler", fusestatic="false", balanceinertia="true", discardvisual="false", strippath="false"
    )
    return ET.tostring(root, encoding="unicode")
