"""MuJoCo as a simulator backend (``sim: {type: mujoco}``, ``pip install rmpfusion[mujoco]``): the robot compiled
from its resolved URDF (``mujoco_model.py``), obstacle slots as mocap bodies, signed distances from
``mj_geomDistance``, computed torque by ``mj_rne`` (no contact, like pybullet's inverse dynamics) applied through
``qfrc_applied``, pictures from MuJoCo's offscreen renderer (``MUJOCO_GL=egl`` unless set otherwise).

What differs from pybullet, by construction: MuJoCo's soft contact model (pybullet's is a hard LCP), a convex hull
per mesh part (pybullet: per file's convex pieces), its own semi-implicit Euler with its default solver settings.
Held joints are driven by the task's computed torque as in pybullet; mimic joints get no equality constraint
(their leader's torque carries them).
"""

from __future__ import annotations

import functools
import math
import os
from collections.abc import Sequence
from typing import Any, Literal

import numpy as np
from pydantic import Field

from ..registry import SIMULATORS
from ..robots import URDFRobot
from .camera import FAR, NEAR, Camera
from .config import SimulatorParams
from .mujoco_model import ROBOT_CONAFFINITY, ROBOT_CONTYPE, WORLD_CONAFFINITY, WORLD_CONTYPE, mujoco_urdf
from .protocol import (
    BACKGROUND,
    GOAL_MARKER,
    GROUND,
    ROBOT,
    Images,
    Obstacle,
    ShapeKind,
    SimulationError,
    SimWorld,
    WorldSettings,
)

_OBSTACLE_RGBA = [0.8, 0.2, 0.2, 1]
_GROUND_RGBA = [0.85, 0.85, 0.8, 1]
_FLOOR_RGBA = [0.6, 0.6, 0.65, 1]
_GOAL_RGBA = [1.0, 0.6, 0.0, 1]
_ROBOT_RGBA = [0.75, 0.75, 0.78, 1]


if "MUJOCO_GL" not in os.environ and not os.environ.get("DISPLAY"):
    # MuJoCo picks its OpenGL platform when it is imported: with no display to open a window on, offscreen through
    # EGL (set MUJOCO_GL yourself, before mujoco is imported, for another)
    os.environ["MUJOCO_GL"] = "egl"


def import_mujoco() -> Any:
    """The mujoco module, imported when a world opens."""
    try:
        import mujoco  # when a world opens: the package imports without MuJoCo
    except ImportError as e:
        raise SimulationError(
            "sim=mujoco needs the mujoco package: pip install 'rmpfusion[mujoco]' (or pip install mujoco)"
        ) from e
    return mujoco


@functools.lru_cache(maxsize=16)
def _robot_xml(urdf_path: str) -> str:
    return mujoco_urdf(urdf_path)


class MuJoCoParams(SimulatorParams):
    """MuJoCo's own settings (the step, gravity come from the environment)."""

    integrator: Literal["Euler", "implicitfast", "RK4"] = Field(
        "Euler", description="MuJoCo's integrator; Euler is semi-implicit, as pybullet's"
    )


_KIND = {"sphere": "mjGEOM_SPHERE", "box": "mjGEOM_BOX", "cylinder": "mjGEOM_CYLINDER", "capsule": "mjGEOM_CAPSULE"}


def _size(o: Obstacle) -> tuple[list[float], float, list[float]]:
    """(MuJoCo's size, bounding radius, local half box) of an obstacle's geom."""
    if o.kind == "sphere":
        return [o.radius, 0.0, 0.0], o.radius, [o.radius] * 3
    if o.kind == "box":
        h = list(o.half_extents)
        return h, float(np.linalg.norm(h)), h
    if o.kind == "cylinder":
        return [o.radius, o.half_length, 0.0], math.hypot(o.radius, o.half_length), [o.radius, o.radius, o.half_length]
    return [o.radius, o.half_length, 0.0], o.radius + o.half_length, [o.radius, o.radius, o.radius + o.half_length]


@SIMULATORS.register("mujoco")
class MuJoCoWorld(SimWorld):
    """One MuJoCo model and its data; the model is recompiled only when the obstacles' shapes change."""

    Params = MuJoCoParams

    def __init__(self, robot: URDFRobot, settings: WorldSettings, params: MuJoCoParams | None = None):
        self.options = params or MuJoCoParams(type="mujoco")
        super().__init__(robot, settings, self.options)
        if settings.gui:
            raise SimulationError("sim=mujoco opens no window (env.gui=true): run it headless")
        self.mj = import_mujoco()
        self.kinds: tuple[ShapeKind, ...] = ()
        self.ground_height: float | None = None
        self._renderers: dict[tuple[int, int], Any] = {}
        self._compile()

    # ---------------------------------------------------------------- the model
    def _compile(self) -> None:
        """Build the model for the current obstacle kinds; joint state carries over."""
        mj, robot = self.mj, self.robot
        try:
            spec = mj.MjSpec.from_string(_robot_xml(robot.urdf_path))
        except Exception as e:
            raise SimulationError(f"mujoco: could not compile {robot.urdf_path}: {e}") from e
        spec.option.timestep = self.settings.timestep
        spec.option.gravity = [0.0, 0.0, self.settings.gravity]
        spec.option.integrator = getattr(mj.mjtIntegrator, f"mjINT_{self.options.integrator.upper()}")
        spec.visual.global_.fovy = 60.0
        spec.visual.headlight.ambient = [0.4, 0.4, 0.4]
        spec.visual.headlight.diffuse = [0.6, 0.6, 0.6]
        self._mount(spec)
        for geom in spec.geoms:
            geom.contype, geom.conaffinity, geom.rgba = ROBOT_CONTYPE, ROBOT_CONAFFINITY, _ROBOT_RGBA
        world = spec.worldbody
        world.add_light(pos=[0.0, 0.0, 3.0], dir=[0.0, 0.0, -1.0], type=mj.mjtLightType.mjLIGHT_DIRECTIONAL)
        world.add_geom(
            name="rmpfusion_ground",
            type=mj.mjtGeom.mjGEOM_PLANE,
            size=[0, 0, 1],
            rgba=_GROUND_RGBA,
            contype=WORLD_CONTYPE,
            conaffinity=WORLD_CONAFFINITY,
        )
        world.add_geom(
            name="rmpfusion_floor",
            type=mj.mjtGeom.mjGEOM_PLANE,
            size=[0, 0, 1],
            rgba=_FLOOR_RGBA,
            contype=0,
            conaffinity=0,
        )
        marker = world.add_body(name="rmpfusion_goal", mocap=True)
        marker.add_geom(type=mj.mjtGeom.mjGEOM_SPHERE, size=[0.03, 0, 0], rgba=_GOAL_RGBA, contype=0, conaffinity=0)
        for k, kind in enumerate(self.kinds):
            body = world.add_body(name=f"rmpfusion_obstacle{k}", mocap=True)
            body.add_geom(
                name=f"rmpfusion_obstacle{k}",
                type=getattr(mj.mjtGeom, _KIND[kind]),
                size=[0.01, 0.01, 0.01],
                rgba=_OBSTACLE_RGBA,
                contype=WORLD_CONTYPE,
                conaffinity=WORLD_CONAFFINITY,
            )
        old = getattr(self, "data", None)
        self.model = spec.compile()
        self.data = mj.MjData(self.model)
        self.scratch = mj.MjData(self.model)  # inverse dynamics at a state of its own
        self._index_model()
        if old is not None:
            self.data.qpos[:], self.data.qvel[:] = old.qpos, old.qvel
        self._renderers.clear()
        self.set_ground(self.ground_height)
        mj.mj_kinematics(self.model, self.data)

    def _mount(self, spec: Any) -> None:
        """Every body on the world (the URDF's root link, or its children when the root is named ``world``) moved
        by the robot's mount."""
        mj = self.mj
        position, q = self.robot.base_pose()
        mount = np.array([q[3], q[0], q[1], q[2]])
        for body in spec.worldbody.bodies:
            moved, turned = np.empty(3), np.empty(4)
            mj.mju_rotVecQuat(moved, np.asarray(body.pos, dtype=float), mount)
            mj.mju_mulQuat(turned, mount, np.asarray(body.quat, dtype=float))
            body.pos, body.quat = moved + np.asarray(position), turned

    def _id(self, kind: str, name: str) -> int:
        i = self.mj.mj_name2id(self.model, getattr(self.mj.mjtObj, kind), name)
        if i < 0:
            raise SimulationError(f"mujoco: the compiled model has no {kind.removeprefix('mjOBJ_').lower()} '{name}'")
        return i

    def _index_model(self) -> None:
        m, mj = self.model, self.mj
        joints = [self._id("mjOBJ_JOINT", j) for j in (*self.robot.params.joints, *self.robot.held_joints())]
        self.qpos_index = np.array([m.jnt_qposadr[j] for j in joints], dtype=int)
        self.dof_index = np.array([m.jnt_dofadr[j] for j in joints], dtype=int)
        self.ground_geom = self._id("mjOBJ_GEOM", "rmpfusion_ground")
        self.floor_geom = self._id("mjOBJ_GEOM", "rmpfusion_floor")
        self.goal_body = m.body_mocapid[self._id("mjOBJ_BODY", "rmpfusion_goal")]
        self.goal_geom = int(np.flatnonzero(m.geom_bodyid == self._id("mjOBJ_BODY", "rmpfusion_goal"))[0])
        self.obstacle_geoms = [self._id("mjOBJ_GEOM", f"rmpfusion_obstacle{k}") for k in range(len(self.kinds))]
        self.obstacle_mocap = [
            m.body_mocapid[self._id("mjOBJ_BODY", f"rmpfusion_obstacle{k}")] for k in range(len(self.kinds))
        ]
        robot_bodies = {
            i
            for i in range(1, m.nbody)
            if not (mj.mj_id2name(m, mj.mjtObj.mjOBJ_BODY, i) or "").startswith("rmpfusion_")
        }
        self.body_names = {i: mj.mj_id2name(m, mj.mjtObj.mjOBJ_BODY, i) for i in sorted(robot_bodies)}
        self.robot_geoms = [g for g in range(m.ngeom) if m.geom_bodyid[g] in robot_bodies]
        self.link_geoms: dict[str, list[int]] = {}
        for g in self.robot_geoms:
            self.link_geoms.setdefault(self.body_names[m.geom_bodyid[g]], []).append(g)
        self.floor_visible = self.settings.pictures

    # ---------------------------------------------------------------- the scene
    def set_obstacles(self, obstacles: Sequence[Obstacle]) -> None:
        kinds = tuple(o.kind for o in obstacles)
        if kinds != self.kinds:
            self.kinds = kinds
            self._compile()
        m, d = self.model, self.data
        for o, geom, mocap in zip(obstacles, self.obstacle_geoms, self.obstacle_mocap):
            size, rbound, half = _size(o)
            m.geom_size[geom], m.geom_rbound[geom] = size, rbound
            m.geom_aabb[geom] = [0.0, 0.0, 0.0, *half]
            d.mocap_pos[mocap] = o.center
            quat = np.empty(4)
            self.mj.mju_mat2Quat(quat, np.ascontiguousarray(o.rotation, dtype=float).reshape(-1))
            d.mocap_quat[mocap] = quat
        self.mj.mj_kinematics(m, d)

    def move_obstacle(self, slot: int, center: np.ndarray) -> None:
        self.data.mocap_pos[self.obstacle_mocap[slot]] = center
        self.mj.mj_kinematics(self.model, self.data)

    def set_ground(self, height: float | None) -> None:
        self.ground_height = height
        m = self.model
        on = height is not None
        m.geom_pos[self.ground_geom] = [0.0, 0.0, height if on else 0.0]
        m.geom_conaffinity[self.ground_geom] = WORLD_CONAFFINITY if on else 0
        m.geom_rgba[self.ground_geom][3] = 1.0 if on and self.settings.pictures else 0.0
        m.geom_rgba[self.floor_geom][3] = 1.0 if self.settings.pictures and not on else 0.0
        self.mj.mj_kinematics(m, self.data)

    def set_goal_marker(self, position: np.ndarray | None) -> None:
        shown = position is not None and self.settings.pictures
        self.model.geom_rgba[self.goal_geom][3] = 1.0 if shown else 0.0
        if position is not None:
            self.data.mocap_pos[self.goal_body] = position
            self.mj.mj_kinematics(self.model, self.data)

    # ---------------------------------------------------------------- the robot
    def reset(self, q: np.ndarray, qd: np.ndarray) -> None:
        d = self.data
        d.qpos[self.qpos_index], d.qvel[self.dof_index] = q, qd
        d.qacc_warmstart[:] = 0.0
        d.qfrc_applied[:] = 0.0
        self.mj.mj_kinematics(self.model, d)

    def state(self) -> tuple[np.ndarray, np.ndarray]:
        d = self.data
        return d.qpos[self.qpos_index].copy(), d.qvel[self.dof_index].copy()

    def inverse_dynamics(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
        mj, m, s = self.mj, self.model, self.scratch
        s.qpos[self.qpos_index], s.qvel[self.dof_index] = q, qd
        s.qacc[:] = 0.0
        s.qacc[self.dof_index] = qdd
        mj.mj_kinematics(m, s)
        mj.mj_comPos(m, s)
        mj.mj_comVel(m, s)
        out = np.zeros(m.nv)
        mj.mj_rne(m, s, 1, out)
        return out[self.dof_index]

    def step(self, torque: np.ndarray) -> None:
        d = self.data
        d.qfrc_applied[:] = 0.0
        d.qfrc_applied[self.dof_index] = torque
        self.mj.mj_step(self.model, d)
        if d.warning[self.mj.mjtWarning.mjWARN_BADQACC].number > 0 or not np.isfinite(d.qpos).all():
            raise SimulationError(f"mujoco: the simulation diverged at t={d.time:.4f}s (bad accelerations)")
        self.mj.mj_kinematics(self.model, d)

    # ---------------------------------------------------------------- geometry
    def _distance(self, a: int, b: int, query: float) -> float:
        return float(self.mj.mj_geomDistance(self.model, self.data, a, b, query, None))

    def obstacle_distance(self, query: float) -> float:
        best = query
        for obstacle in self.obstacle_geoms:
            for g in self.robot_geoms:
                best = min(best, self._distance(g, obstacle, query))
        return best

    def ground_distance(self, link: str, query: float) -> float:
        if self.ground_height is None:
            return query
        return min([query, *(self._distance(g, self.ground_geom, query) for g in self.link_geoms.get(link, []))])

    def link_frames(self) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        d = self.data
        return {name: (d.xpos[i].copy(), d.xmat[i].reshape(3, 3).copy()) for i, name in self.body_names.items()}

    def link_boxes(self) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        out = {}
        for link, geoms in self.link_geoms.items():
            points = np.concatenate([self._geom_points(g) for g in geoms])
            out[link] = (points.min(0), points.max(0))
        return out

    def _geom_points(self, g: int) -> np.ndarray:
        """World points bounding geom ``g``: a mesh's vertices, else its local box's corners."""
        m, d = self.model, self.data
        R, p = d.geom_xmat[g].reshape(3, 3), d.geom_xpos[g]
        mesh = m.geom_dataid[g]
        if int(m.geom_type[g]) == int(self.mj.mjtGeom.mjGEOM_MESH) and mesh >= 0:
            start, count = m.mesh_vertadr[mesh], m.mesh_vertnum[mesh]
            local = m.mesh_vert[start : start + count]
        else:
            half = m.geom_aabb[g][3:]
            local = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]) * half + m.geom_aabb[g][:3]
        return local @ R.T + p

    # ---------------------------------------------------------------- pictures and the end
    def render(self, camera: Camera, width: int, height: int) -> Images:
        mj, m = self.mj, self.model
        m.vis.global_.fovy = camera.fov
        m.vis.map.znear, m.vis.map.zfar = NEAR / m.stat.extent, FAR / m.stat.extent
        renderer = self._renderer(width, height)
        cam = mj.MjvCamera()
        cam.type = mj.mjtCamera.mjCAMERA_FREE
        cam.lookat[:] = camera.target
        cam.distance, cam.azimuth, cam.elevation = camera.distance, camera.yaw + 90.0, camera.pitch
        renderer.update_scene(self.data, camera=cam)
        rgb = renderer.render().copy()
        renderer.enable_depth_rendering()
        renderer.update_scene(self.data, camera=cam)
        depth = renderer.render().astype(float)
        renderer.disable_depth_rendering()
        renderer.enable_segmentation_rendering()
        renderer.update_scene(self.data, camera=cam)
        seg = renderer.render()
        renderer.disable_segmentation_rendering()
        depth[depth >= FAR * 0.999] = np.inf
        return Images(rgb, depth, self._labels(seg[..., 0], seg[..., 1]))

    def _renderer(self, width: int, height: int) -> Any:
        if (width, height) not in self._renderers:
            m = self.model
            m.vis.global_.offwidth = max(m.vis.global_.offwidth, width)
            m.vis.global_.offheight = max(m.vis.global_.offheight, height)
            try:
                self._renderers[(width, height)] = self.mj.Renderer(m, height, width)
            except Exception as e:
                raise SimulationError(
                    f"mujoco: no offscreen rendering ({e}); MUJOCO_GL={os.environ.get('MUJOCO_GL')} needs libEGL "
                    "(Debian: libegl1), or MUJOCO_GL=osmesa libosmesa6; MuJoCo reads MUJOCO_GL when it is first "
                    "imported: set it before that"
                ) from e
        return self._renderers[(width, height)]

    def _labels(self, ids: np.ndarray, types: np.ndarray) -> np.ndarray:
        """MuJoCo's (object id, object type) per pixel as the protocol's segmentation labels."""
        labels = np.full(ids.shape, BACKGROUND, dtype=int)
        geom = (types == int(self.mj.mjtObj.mjOBJ_GEOM)) & (ids >= 0)
        table = np.full(self.model.ngeom, BACKGROUND, dtype=int)
        table[self.robot_geoms] = ROBOT
        table[[self.ground_geom, self.floor_geom]] = GROUND
        table[self.goal_geom] = GOAL_MARKER
        for k, g in enumerate(self.obstacle_geoms):
            table[g] = k + 1
        labels[geom] = table[ids[geom]]
        return labels

    def close(self) -> None:
        for renderer in self._renderers.values():
            renderer.close()
        self._renderers.clear()
