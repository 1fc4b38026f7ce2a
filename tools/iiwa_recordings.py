#!/usr/bin/env python
"""Recordings of the KUKA iiwa made by a solver that is not rmpfusion's: pybullet's own inverse kinematics
following a Cartesian path around the post of the iiwa_box scene, logged the way robomimic stores teleoperation (an
HDF5 file with one group per demonstration, joint angles at ``data/demo_N/obs/robot0_joint_pos``, a fixed control
rate and no time stamps), for ``experiment=recorded_iiwa`` to read back like a user's file.

    python tools/iiwa_recordings.py                   # rmpfusion/recordings/files/iiwa_post_ik.hdf5
    python tools/iiwa_recordings.py --out my.hdf5 --demos 8 --seed 3

Why another tool: the Panda's recordings (tools/arm_recordings.py) are splines in joint space through
configurations rmpfusion's own kinematics solved for. These are made without rmpfusion's kinematics at all: the
iiwa's URDF loaded in pybullet, the flange moved along a Cartesian curve (start -> a via point over the post
-> goal, one cubic spline in space timed by a minimum-jerk profile), each logged sample's joints solved by
``pybullet.calculateInverseKinematics`` (null space pulled to the start's configuration, seeded by the previous
sample) and checked by pybullet's forward kinematics and its closest-point query against the post (every link at
least ``--clearance`` from it).

The demonstrations: the flange starts in a box on the post's +y side and ends at rest in the mirror box on its -y
side, so the straight reach runs through the post; the via point lies 18-26 cm above the post's top (passing in
front of the post instead bends the iiwa's elbow into its limit or its wrist into the post on most draws). A plan is kept only if the solver reaches every point to 2 mm, the angles stay
inside the limits and the links clear the post; the tool says how many it drew. The log: at rest for a moment before
and after the motion, ``--rate`` Hz, Gaussian noise of ``--noise`` rad on every angle, the joint-position deltas as
``actions`` (what robomimic's joint-velocity controllers log), and robomimic's attributes (``total``, ``env_args``,
``num_samples``).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
from pathlib import Path

import h5py
import numpy as np
import pybullet
import pybullet_data
from scipy.interpolate import CubicSpline

from rmpfusion.recordings.source import SHIPPED_DIR

DEFAULT_OUT = SHIPPED_DIR / "iiwa_post_ik.hdf5"
URDF = "kuka_iiwa/model.urdf"
FLANGE = 6  # lbr_iiwa_link_7, the last link (conf/robot/iiwa.yaml's end-effector link)
HOME = np.array([0.8, 0.6, 0.0, -1.4, 0.0, 0.9, 0.0])  # conf/robot/iiwa.yaml's home
#: the post of conf/scene/iiwa_box.yaml (m): centre and half extents
POST_CENTER, POST_HALF = (0.6, 0.0, 0.3), (0.05, 0.05, 0.3)
#: the flange's start box (x, y, z ranges, m); the goal box is its mirror in y
START_BOX = np.array([[0.50, 0.65], [0.30, 0.45], [0.30, 0.50]])
#: the via point above the post (its top is at 0.6 m): x range, y half range, z range (m)
VIA_X, VIA_Y, VIA_Z = (0.45, 0.58), 0.04, (0.78, 0.86)


class World:
    """The iiwa and the post in a pybullet DIRECT session."""

    def __init__(self) -> None:
        self.client = pybullet.connect(pybullet.DIRECT)
        path = os.path.join(pybullet_data.getDataPath(), URDF)
        self.robot = pybullet.loadURDF(path, useFixedBase=True, physicsClientId=self.client)
        box = pybullet.createCollisionShape(pybullet.GEOM_BOX, halfExtents=POST_HALF, physicsClientId=self.client)
        self.post = pybullet.createMultiBody(0, box, basePosition=POST_CENTER, physicsClientId=self.client)
        info = [pybullet.getJointInfo(self.robot, j, physicsClientId=self.client) for j in range(7)]
        self.names = [i[1].decode() for i in info]
        self.lower = np.array([i[8] for i in info])
        self.upper = np.array([i[9] for i in info])

    def set(self, q: np.ndarray) -> None:
        for j, v in enumerate(q):
            pybullet.resetJointState(self.robot, j, float(v), physicsClientId=self.client)

    def flange(self, q: np.ndarray) -> np.ndarray:
        self.set(q)
        state = pybullet.getLinkState(self.robot, FLANGE, computeForwardKinematics=True, physicsClientId=self.client)
        return np.array(state[4])

    def solve(self, target: np.ndarray, seed: np.ndarray, rest: np.ndarray) -> tuple[np.ndarray, float]:
        """pybullet's inverse kinematics from ``seed`` with the null space pulled to ``rest``; a few restarts from
        its own answer, since one call stops short on large moves. Returns the angles and the flange's miss (m)."""
        q = seed
        for _ in range(5):
            self.set(q)
            q = np.array(
                pybullet.calculateInverseKinematics(
                    self.robot,
                    FLANGE,
                    target.tolist(),
                    lowerLimits=self.lower.tolist(),
                    upperLimits=self.upper.tolist(),
                    jointRanges=(self.upper - self.lower).tolist(),
                    restPoses=rest.tolist(),
                    maxNumIterations=200,
                    residualThreshold=1e-6,
                    physicsClientId=self.client,
                )
            )
            miss = float(np.linalg.norm(self.flange(q) - target))
            if miss < 2e-4:
                break
        return q, miss

    def clear_of_post(self, q: np.ndarray, clearance: float) -> bool:
        self.set(q)
        near = pybullet.getClosestPoints(self.robot, self.post, clearance, physicsClientId=self.client)
        return len(near) == 0


def minimum_jerk(s: np.ndarray) -> np.ndarray:
    return 10 * s**3 - 15 * s**4 + 6 * s**5


def plan(world: World, rng: np.random.Generator, duration: float, rate: float, clearance: float):
    """One demonstration's joint angles at ``rate`` Hz over ``duration`` s, or None where the solver misses, a
    limit is reached or a link comes within ``clearance`` of the post."""
    start = rng.uniform(START_BOX[:, 0], START_BOX[:, 1])
    goal = rng.uniform(START_BOX[:, 0], START_BOX[:, 1]) * np.array([1.0, -1.0, 1.0])
    via = np.array([rng.uniform(*VIA_X), rng.uniform(-VIA_Y, VIA_Y), rng.uniform(*VIA_Z)])
    q_start, miss = world.solve(start, HOME, HOME)
    if miss > 2e-3:
        return None
    curve = CubicSpline([0.0, rng.uniform(0.4, 0.6), 1.0], np.stack([start, via, goal]), bc_type="clamped")
    times = np.arange(int(np.ceil(duration * rate)) + 1) / rate
    q, angles = q_start, []
    for point in curve(minimum_jerk(np.clip(times / duration, 0.0, 1.0))):
        q, miss = world.solve(point, q, q_start)
        inside = bool(((q > world.lower + 0.02) & (q < world.upper - 0.02)).all())
        if miss > 2e-3 or not inside or not world.clear_of_post(q, clearance):
            return None
        angles.append(q)
    return np.stack(angles)


def record(angles: np.ndarray, rate: float, rng: np.random.Generator, noise: float) -> np.ndarray:
    """The motion as the log holds it: at rest before and after, Gaussian noise on every angle."""
    before = np.repeat(angles[:1], int(rng.uniform(0.3, 0.6) * rate), axis=0)
    after = np.repeat(angles[-1:], int(rng.uniform(0.5, 0.8) * rate), axis=0)
    q = np.concatenate([before, angles, after])
    return q + rng.normal(0.0, noise, q.shape)


def write(out: Path, demos: list[np.ndarray], names: list[str], rate: float) -> None:
    """robomimic's layout, written to a temporary file beside ``out`` and moved over it (never a partial file)."""
    out.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=out.parent, suffix=".tmp")
    os.close(fd)
    try:
        with h5py.File(tmp, "w") as fh:
            data = fh.create_group("data")
            data.attrs["total"] = sum(len(q) for q in demos)
            data.attrs["env_args"] = json.dumps(
                {"env_name": "iiwa_post", "type": "pybullet", "env_kwargs": {"control_freq": rate, "joints": names}}
            )
            for n, q in enumerate(demos):
                g = data.create_group(f"demo_{n}")
                g.attrs["num_samples"] = len(q)
                g.create_dataset("obs/robot0_joint_pos", data=q)
                g.create_dataset("actions", data=np.diff(q, axis=0, append=q[-1:]))
        os.chmod(tmp, 0o644)  # mkstemp's 0600 would hide the data from other users of an installed package
        os.replace(tmp, out)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT)
    ap.add_argument("--demos", type=int, default=24)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--rate", type=float, default=20.0, help="the control rate the log is kept at (Hz)")
    ap.add_argument("--noise", type=float, default=0.001, help="std of the angles' noise (rad)")
    ap.add_argument("--duration", type=float, nargs=2, default=(2.5, 3.5), help="the motion's duration range (s)")
    ap.add_argument("--clearance", type=float, default=0.05, help="m between every link and the post")
    a = ap.parse_args(argv)
    world = World()
    rng = np.random.default_rng(a.seed)
    demos: list[np.ndarray] = []
    drawn = 0
    while len(demos) < a.demos:
        drawn += 1
        if drawn > 50 * a.demos:
            print(f"only {len(demos)} of {a.demos} plans clear after {drawn - 1} draws", file=sys.stderr)
            return 1
        angles = plan(world, rng, rng.uniform(*a.duration), a.rate, a.clearance)
        if angles is not None:
            demos.append(record(angles, a.rate, rng, a.noise))
    write(a.out, demos, world.names, a.rate)
    print(
        f"{a.out}: {len(demos)} demonstrations, {sum(len(q) for q in demos)} samples at {a.rate:g} Hz "
        f"({drawn} plans drawn)"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
