"""A robot written as ROS packages publish them, made here (no file of it is committed): ``testarm_description/``
with ``package.xml``, ``urdf/testarm.urdf`` and ``meshes/`` holding an STL, a COLLADA and a millimetre STL mesh,
all named ``package://testarm_description/meshes/...``.

The arm: a base box on the ground; ``spin`` (continuous, about z) turns ``link1``, whose lowest point sits 2 cm above
the ground whatever the angle (it only spins, like a UR5's shoulder); ``lift`` (revolute) raises ``link2`` (DAE);
``slide`` (prismatic) moves ``link3`` (an STL drawn in millimetres, ``scale="0.001 0.001 0.001"``); ``wrist``
(revolute) turns ``link4`` (a cylinder primitive); ``thumb`` (revolute, actuated) turns ``link5``, and ``finger``
follows it (``<mimic multiplier="0.5" offset="0.1"/>``), turning ``link6``, which has visual geometry only; ``tool``
is a fixed end-effector frame.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

PACKAGE = "testarm_description"
JOINTS = ["spin", "lift", "slide", "wrist", "thumb"]
MOUNT = {"xyz": [0.1, -0.2, 0.0], "rpy": [0.0, 0.0, 0.3]}

URDF = """<?xml version="1.0"?>
<robot name="testarm">
  <link name="base"><inertial><mass value="2"/><inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/>
  </inertial><collision><origin xyz="0 0 0.01"/><geometry><box size="0.2 0.2 0.02"/></geometry></collision></link>
  <joint name="spin" type="continuous"><parent link="base"/><child link="link1"/>
    <origin xyz="0 0 0.02"/><axis xyz="0 0 1"/><limit effort="50" velocity="2"/></joint>
  <link name="link1">{inertia}
    <collision><geometry><mesh filename="package://testarm_description/meshes/link1.stl"/></geometry></collision>
    <visual><geometry><mesh filename="package://testarm_description/meshes/link1.stl"/></geometry></visual></link>
  <joint name="lift" type="revolute"><parent link="link1"/><child link="link2"/>
    <origin xyz="0 0 0.1"/><axis xyz="0 1 0"/><limit lower="-1.2" upper="1.2" effort="50" velocity="2"/></joint>
  <link name="link2">{inertia}
    <collision><geometry><mesh filename="package://testarm_description/meshes/link2.dae"/></geometry></collision></link>
  <joint name="slide" type="prismatic"><parent link="link2"/><child link="link3"/>
    <origin xyz="0 0 0.3"/><axis xyz="0 0 1"/><limit lower="0" upper="0.2" effort="50" velocity="0.5"/></joint>
  <link name="link3">{inertia}
    <collision><geometry><mesh filename="package://testarm_description/meshes/link3_mm.stl" scale="0.001 0.001 0.001"/>
    </geometry></collision></link>
  <joint name="wrist" type="revolute"><parent link="link3"/><child link="link4"/>
    <origin xyz="0 0 0.15" rpy="0 0.3 0"/><axis xyz="1 0 0"/><limit lower="-2" upper="2" effort="20" velocity="2"/></joint>
  <link name="link4">{inertia}
    <collision><origin xyz="0 0 0.04"/><geometry><cylinder radius="0.03" length="0.08"/></geometry></collision></link>
  <joint name="thumb" type="revolute"><parent link="link4"/><child link="link5"/>
    <origin xyz="0 0 0.08"/><axis xyz="0 1 0"/><limit lower="-1" upper="1" effort="10" velocity="2"/></joint>
  <link name="link5">{inertia}
    <collision><origin xyz="0 0 0.03"/><geometry><box size="0.04 0.04 0.06"/></geometry></collision></link>
  <joint name="finger" type="revolute"><parent link="link5"/><child link="link6"/>
    <origin xyz="0.02 0 0.06"/><axis xyz="0 1 0"/><limit lower="-1" upper="1" effort="10" velocity="2"/>
    <mimic joint="thumb" multiplier="0.5" offset="0.1"/></joint>
  <link name="link6">{inertia}
    <visual><origin xyz="0 0 0.025"/><geometry><box size="0.02 0.02 0.05"/></geometry></visual></link>
  <joint name="tool_joint" type="fixed"><parent link="link5"/><child link="tool"/><origin xyz="0 0 0.1"/></joint>
  <link name="tool"/>
</robot>
""".replace(
    "{inertia}",
    '<inertial><mass value="0.5"/><inertia ixx="0.001" iyy="0.001" izz="0.001" ixy="0" ixz="0" iyz="0"/></inertial>',
)

PACKAGE_XML = f"""<?xml version="1.0"?>
<package format="3"><name>{PACKAGE}</name><version>0.0.1</version><description>test arm</description>
<maintainer email="a@b.c">a</maintainer><license>MIT</license></package>
"""


def _box(size, centre):
    import trimesh

    m = trimesh.creation.box(extents=size)
    m.apply_translation(centre)
    return m


def write_package(root: Path) -> Path:
    """Write the package under ``root``; returns the URDF's path."""
    import trimesh

    pkg = root / PACKAGE
    (pkg / "urdf").mkdir(parents=True, exist_ok=True)
    (pkg / "meshes").mkdir(exist_ok=True)
    (pkg / "package.xml").write_text(PACKAGE_XML)
    link1 = trimesh.creation.cylinder(radius=0.05, height=0.1)
    link1.apply_translation([0.0, 0.0, 0.05])  # from the joint (2 cm above the ground) up
    link1.export(pkg / "meshes" / "link1.stl")
    _box([0.05, 0.05, 0.3], [0.0, 0.0, 0.15]).export(pkg / "meshes" / "link2.dae")
    _box([40.0, 40.0, 150.0], [0.0, 0.0, 75.0]).export(pkg / "meshes" / "link3_mm.stl")  # millimetres
    urdf = pkg / "urdf" / "testarm.urdf"
    urdf.write_text(URDF)
    return urdf


def random_q(n: int, seed: int = 0) -> np.ndarray:
    """(n, 5) configurations inside the joints' limits (spin over one turn each way)."""
    lo = np.array([-3.0, -1.2, 0.0, -2.0, -1.0])
    hi = np.array([3.0, 1.2, 0.2, 2.0, 1.0])
    return lo + (hi - lo) * np.random.default_rng(seed).random((n, 5))
