"""Collision checking of a whole batch of kinematic rollouts: every configuration bounded in torch by spheres,
the simulator's closest-point query asked only where the bounds cannot decide.

Why: replaying every configuration of every rollout in the simulator is one closest-point query per sample and step
(600,000 for 100 starts of 5,871 steps), minutes in which nothing else happens. The robot's spheres and the scene's
distance maps (``scenes/distance.py``, the maps the tree itself uses) measure the same configurations for the whole
batch at once.

The sphere bound: every robot link's collision geometry lies inside the spheres that cover it (``cover_spheres``:
the robot's control spheres, and for a link without any, one sphere around its collision mesh), so a sphere's
distance to an obstacle (or the ground) is at most that of the geometry it covers. Hence, for every configuration
clear of the obstacles,

    sphere clearance − SPHERE_SLACK ≤ mesh clearance (the simulator's),

the slack absorbing what the control spheres' fit leaves out (tests/test_collisions.py measures it on every shipped
robot: under a millimetre). A configuration whose bound exceeds 0 cannot collide, and one whose bound is at least the
smallest clearance found cannot lower it. In penetration the simulator reports a penetration depth, which the
spheres do not bound (a sphere may sink 2 cm less deep than the link it covers), so every step whose bound is ≤ 0 is
asked of the simulator, and a sample that collides reports the deepest of them.

Continuity does the rest: no point of the robot moves further between two steps than the joints' motion times their
reach (``joint_reach``), so the spheres are measured at every few steps only, and every answer c_k ≥ 0 of the
simulator bounds the steps around k from below too. The steps are asked in
increasing order of their bound until every bound left is at least the smallest clearance found less
``CLEARANCE_TOLERANCE`` (``check_collisions``): the collision flags and first collision times are the
per-configuration replay's (``replay_collisions``, kept as the reference), the smallest clearances the replay's or
at most ``CLEARANCE_TOLERANCE`` above them.
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from torch import Tensor

from ...registry import TASK_MAPS
from ...robots import URDFRobot
from ...robots.geometry import collision_meshes, links_with_geometry
from ...scenes.distance import distances
from ...sims import SimulationError
from ..protocol import ObstacleDepths
from .task import ManipulatorTask
from .worlds import sample_aux

#: how far (m) a link's collision geometry may reach outside the spheres that cover it; the bound is lowered by it
SPHERE_SLACK = 0.005
#: how far (m) above the smallest clearance the reported one may be: the steps near the closest one need not all be
#: asked (module docstring, continuity)
CLEARANCE_TOLERANCE = 1e-3
#: the sphere bound is measured at every STRIDE-th step, continuity bounds the steps between (``clearance_bounds``)
STRIDE = 8
#: configurations bounded per torch call (memory: configurations × spheres × the aux state's width)
CHUNK = 8192


@dataclass(frozen=True)
class CoverSpheres:
    """Spheres that together contain every link's collision geometry: each in the frame of ``links[i]``."""

    links: list[str]
    offsets: Tensor  # (S, 3), in the link's frame
    radii: Tensor  # (S,)


_COVERS: dict[tuple, CoverSpheres] = {}


def cover_spheres(robot: URDFRobot) -> CoverSpheres:
    """The robot's control spheres, and for every link with collision geometry but no control sphere the smallest
    sphere about its mesh's bounding-box centre holding every vertex (the convex hull a simulator collides with lies
    inside it). Found once per robot in a process (the meshes are read)."""
    p = robot.params
    key = (p.urdf, tuple(p.joints), repr(p.control_points), repr(p.packages))
    if key in _COVERS:
        return _COVERS[key]
    links = [cp.link for cp in p.control_points]
    offsets = [list(cp.offset) for cp in p.control_points]
    radii = [float(cp.radius) for cp in p.control_points]
    bare = [link for link in links_with_geometry(p.urdf) if link not in set(links)]
    for link, mesh in collision_meshes(p.urdf, bare, p.packages).items():
        v = np.asarray(mesh.vertices, dtype=np.float64)  # type: ignore[attr-defined]
        if not len(v):
            continue
        c = (v.min(0) + v.max(0)) / 2
        links.append(link)
        offsets.append(c.tolist())
        radii.append(float(np.linalg.norm(v - c, axis=1).max()))
    cover = CoverSpheres(
        links,
        torch.tensor(offsets, dtype=torch.float64).reshape(-1, 3),
        torch.tensor(radii, dtype=torch.float64),
    )
    _COVERS[key] = cover
    return cover


def _centres(robot: URDFRobot, cover: CoverSpheres, q: Tensor) -> Tensor:
    """(M, S, 3) world centres of the cover spheres at configurations ``q`` (M, dof)."""
    names = sorted(set(cover.links))
    poses = robot.chain.forward_kinematics(q, names)
    which = torch.tensor([names.index(n) for n in cover.links])
    R = torch.stack([poses[n][0] for n in names], 1)[:, which]
    p = torch.stack([poses[n][1] for n in names], 1)[:, which]
    return p + (R @ cover.offsets.to(q).unsqueeze(-1)).squeeze(-1)


_REACH: dict[tuple, Tensor | None] = {}


def joint_reach(robot: URDFRobot) -> Tensor | None:
    """(dof,) ρ: no point of the cover spheres (hence of the robot's geometry) moves more than Σᵢ ρᵢ·|Δqᵢ| between
    two configurations; None for an arm with a sliding joint (no such bound is used then). ρᵢ is, over the spheres
    joint i moves, the farthest any of them reaches from joint i's axis: the fixed distances from each joint's
    origin to the next one's on the sphere's path, then to its centre, plus its radius (the triangle inequality,
    valid in every configuration; a joint that follows joint i adds its gain times its own reach)."""
    p = robot.params
    key = (p.urdf, tuple(p.joints), repr(p.control_points), repr(p.packages), repr(p.mount))
    if key in _REACH:
        return _REACH[key]
    chain, cover = robot.chain, cover_spheres(robot)
    rho: Tensor | None = None
    if not chain.has_slides:
        q = torch.zeros(1, robot.dof, dtype=torch.float64)
        origins_all, centres = chain.frames(q)[1][0], _centres(robot, cover, q)[0]
        rho = torch.zeros(robot.dof, dtype=torch.float64)
        for s, link in enumerate(cover.links):
            joints = [k for k in chain.path_joints(link) if chain._kind[k] != 0]  # the joints that move it
            if not joints:
                continue
            o = origins_all[joints]
            tail = (centres[s] - o[-1]).norm() + cover.radii[s] + SPHERE_SLACK
            reach = torch.cat([(o[1:] - o[:-1]).norm(dim=-1), tail[None]]).flip(0).cumsum(0).flip(0)
            per_q = torch.zeros(robot.dof, dtype=torch.float64)
            for m, k in enumerate(joints):
                per_q[chain._qidx[k]] += abs(chain._gain[k]) * reach[m]
            rho = torch.maximum(rho, per_q)
    _REACH[key] = rho
    return rho


def sphere_clearance(env: ManipulatorTask, q: Tensor, aux: Mapping[str, Tensor]) -> Tensor:
    """(M,) smallest distance from the cover spheres at configurations ``q`` (M, dof) to the obstacles of aux rows
    ``aux`` (one per configuration) and, for the spheres of the links the simulator's clearance checks against the
    ground (``TaskWorld.ground_reach``), to the ground: a lower bound of the simulator's clearance up to
    ``SPHERE_SLACK`` where it is ≥ 0 (module docstring)."""
    cover = cover_spheres(env.robot)
    radii = cover.radii.to(q)
    centres = _centres(env.robot, cover, q)
    M, S = centres.shape[:2]
    best = torch.full((M,), float("inf"), dtype=q.dtype)
    if env.scene.obstacles:
        rows = {k: v.repeat_interleave(S, 0) for k, v in aux.items()}
        d = distances(env.scene, rows, centres.reshape(-1, 3)).reshape(M, S, -1).amin(-1) - radii
        best = d.amin(-1)
    grounded = torch.tensor([link in env.checker().ground_reach for link in cover.links], dtype=torch.bool)
    if env.scene.ground is not None and bool(grounded.any()):
        entry = TASK_MAPS.get("plane_distance")  # the tree's ground map (envs/manipulator_tree.py)
        plane = entry.obj(entry.validate({"normal": [0.0, 0.0, 1.0], "height": env.scene.ground.height}), 3, {})
        above = plane.to(q.dtype).psi(centres[:, grounded].reshape(-1, 3), {}).reshape(M, -1) - radii[grounded]
        best = torch.minimum(best, above.amin(-1))
    return best


def clearance_bounds(
    env: ManipulatorTask, Q: Tensor, aux: Mapping[str, Tensor], stride: int = STRIDE
) -> tuple[Tensor, Tensor | None]:
    """(T, B) lower bounds of the simulator's clearance of the configurations Q (T, B, dof), step k with the
    obstacles where they are at t = k·dt; and (T, B, n, 3) the centres of the n moving obstacles at each step (None
    when none moves). The sphere clearance less ``SPHERE_SLACK`` is measured at every ``stride``-th step (and the
    last); a step between two measured ones k takes the larger of their bounds less how far the spheres can have
    moved from there (``joint_reach``) and the obstacles have (forward kinematics is most of the cost: a rollout
    at rest is bounded as tightly at a stride's fraction of it)."""
    T, B, dof = Q.shape
    Q = Q.to(env.dtype)
    rho = joint_reach(env.robot)
    if rho is None:  # no continuity bound: every step is measured
        stride = 1
    ks = torch.unique(torch.cat([torch.arange(0, T, stride), torch.tensor([T - 1])]))
    moving = [f"obstacle{k}_center" for k, o in enumerate(env.scene.obstacles, start=1) if o.moving]
    where = None
    if moving:  # every step's obstacle centres (cheap: no kinematics)
        at = env.aux_at(
            {n: aux[n].repeat(T, 1) for n in moving}, torch.arange(T, dtype=env.dtype).repeat_interleave(B) * env.dt
        )
        where = torch.stack([at[n] for n in moving], 1).reshape(T, B, len(moving), 3)
    measured = torch.empty(len(ks), B, dtype=env.dtype)
    flat = Q[ks].reshape(-1, dof)
    for lo in range(0, len(flat), CHUNK):
        hi = min(lo + CHUNK, len(flat))
        rows = {k: v[torch.arange(lo, hi) % B] for k, v in aux.items()}
        if moving:
            rows = env.aux_at(rows, ks[torch.arange(lo, hi) // B].to(env.dtype) * env.dt)
        measured.view(-1)[lo:hi] = sphere_clearance(env, flat[lo:hi], rows)
    measured = measured - SPHERE_SLACK
    if len(ks) == T or rho is None:
        return measured, where
    left = torch.div(torch.arange(T), stride, rounding_mode="floor")
    lower = torch.full((T, B), -float("inf"), dtype=env.dtype)
    for side in (left, (left + 1).clamp(max=len(ks) - 1)):
        moved = (Q - Q[ks[side]]).abs() @ rho.to(Q)
        if where is not None:
            moved = moved + (where - where[ks[side]]).norm(dim=-1).amax(-1)
        lower = torch.maximum(lower, measured[side] - moved)
    return lower, where


class _Replay:
    """One sample's configurations asked of the simulator, each at most once."""

    def __init__(self, env: ManipulatorTask, Q: Tensor, aux, b: int):
        self.env, self.Q, self.aux, self.b = env, Q, aux, b
        self.sc = env.checker()
        self.sc.set_env(env.scene, sample_aux(aux, b))
        self.seen: dict[int, float] = {}

    def __call__(self, k: int) -> float:
        if k not in self.seen:
            env, b = self.env, self.b
            if env.moving:
                at = env.aux_at({n: v[b : b + 1] for n, v in self.aux.items()}, k * env.dt)
                self.sc.move_obstacles(env.scene, sample_aux(at, 0))
            self.sc.reset(self.Q[k, b].cpu().numpy())
            self.seen[k] = self.sc.clearance(env.params.clearance_query)
        return self.seen[k]


def check_collisions(
    env: ManipulatorTask,
    Q: Tensor,
    aux,
    n_steps: int,
    death: list[int],
    errors: list[str | None],
    checked: Callable[[int], Any] | None = None,
) -> tuple[Tensor, Tensor]:
    """(smallest clearance, first collision time) of every sample from its configurations Q (n_steps+1, B, dof) up
    to the step it died at, as ``replay_collisions`` finds them (the smallest clearance within
    ``CLEARANCE_TOLERANCE`` above), with the simulator asked only where the bounds cannot decide (``_Bounded``).
    ``checked(b)`` is called once sample b is done."""
    dt, B, query = env.dt, Q.shape[1], float(env.params.clearance_query)
    lower, moved = clearance_bounds(env, Q, aux)
    rho = joint_reach(env.robot)
    min_clear = torch.full((B,), query, dtype=env.dtype)
    first_hit = torch.full((B,), float("inf"), dtype=env.dtype)
    for b in range(B):
        last = n_steps if errors[b] is None else death[b]
        bound = lower[: last + 1, b]
        try:
            if bool((bound < query - CLEARANCE_TOLERANCE).any()):
                where = None if moved is None else moved[: last + 1, b]
                search = _Bounded(_Replay(env, Q, aux, b), bound, Q[: last + 1, b], rho, where)
                min_clear[b], first_hit[b] = search.run(query, dt)
        except SimulationError as e:
            errors[b] = f"simulator error during collision check: {e}"
            env.worlds.discard_checker()  # a broken world is not reused
        if checked is not None:
            checked(b)
    return min_clear, first_hit


class _Bounded:
    """One sample's search: a lower bound of every step's clearance, raised by each answer of the simulator.

    Two bounds: the spheres' (``clearance_bounds``), and continuity: between steps k and j no point of the robot
    moves further than Σᵢ ρᵢ·|qⱼᵢ − qₖᵢ| (``joint_reach``) nor a moving obstacle further than its centre, and a
    clearance changes by no more than what its point sets move, so an answer c_k ≥ 0 gives c_j ≥ c_k − D(k, j).
    Each answer raises the bounds around k, in blocks growing away from it while they still raise some bound."""

    def __init__(self, mesh: _Replay, bound: Tensor, q: Tensor, rho: Tensor | None, moved: Tensor | None):
        # numpy: thousands of small updates per sample, where torch's per-call overhead would dominate
        self.mesh, self.lower = mesh, bound.detach().cpu().numpy().astype(np.float64)
        self.q = q.detach().cpu().numpy().astype(np.float64)
        self.rho = None if rho is None else rho.cpu().numpy()
        self.moved = None if moved is None else moved.detach().cpu().numpy()
        self.open = np.ones(len(self.lower), dtype=bool)

    def ask(self, k: int) -> float:
        c = self.mesh(k)
        self.open[k] = False
        if c > 0 and self.rho is not None:
            for direction in (1, -1):
                edge, size = k, 256
                while 0 <= edge < len(self.lower) and self._raise(k, c, *sorted((edge, edge + direction * size))):
                    edge, size = edge + direction * size, 2 * size
        return c

    def _raise(self, k: int, c: float, a: int, b: int) -> bool:
        """Raise the bounds of steps a..b-1 (clipped) by the answer c at step k; whether any rose."""
        a, b = max(a, 0), min(b, len(self.lower))
        reach = np.abs(self.q[a:b] - self.q[k]) @ self.rho
        if self.moved is not None:
            reach = reach + np.linalg.norm(self.moved[a:b] - self.moved[k], axis=-1).max(-1)
        new = c - reach
        rose = new > self.lower[a:b]
        np.maximum(self.lower[a:b], new, out=self.lower[a:b])
        return bool(rose.any())

    def run(self, query: float, dt: float) -> tuple[float, float]:
        """(smallest clearance capped at ``query``, first collision time). First every step whose bound is ≤ 0, in
        time order (only these can collide, and a penetration depth is not bounded by the spheres, so a colliding
        sample's smallest clearance is among them); then, while nothing collides, the open step of lowest bound
        until every bound is within ``CLEARANCE_TOLERANCE`` of the smallest clearance found, or above it."""
        best, first = query, float("inf")
        for k in np.flatnonzero(self.lower <= 0).tolist():
            if self.lower[k] > 0:  # cleared by continuity from a step asked since
                continue
            c = self.ask(k)
            best = min(best, c)
            if c <= 0 and first == float("inf"):
                first = k * dt
        if best <= 0:
            return best, first
        while True:
            left = np.where(self.open, self.lower, np.inf)
            k = int(left.argmin())
            if left[k] >= best - CLEARANCE_TOLERANCE:
                return best, first
            best = min(best, self.ask(k))


def replay_collisions(
    env: ManipulatorTask,
    Q: Tensor,
    aux,
    n_steps: int,
    death: list[int],
    errors: list[str | None],
    checked: Callable[[int], Any] | None = None,
) -> tuple[Tensor, Tensor]:
    """``check_collisions`` by the simulator alone, one query per sample and step (moving obstacles where they were
    at each step): the reference the bounded check must equal, and the benchmark's baseline."""
    dt, B, query = env.dt, Q.shape[1], float(env.params.clearance_query)
    min_clear = torch.full((B,), query, dtype=env.dtype)
    first_hit = torch.full((B,), float("inf"), dtype=env.dtype)
    for b in range(B):
        try:
            mesh = _Replay(env, Q, aux, b)
            last = n_steps if errors[b] is None else death[b]
            for k in range(last + 1):
                min_clear[b] = min(float(min_clear[b]), mesh(k))
                if min_clear[b] <= 0.0 and first_hit[b].isinf():
                    first_hit[b] = k * dt
        except SimulationError as e:
            errors[b] = f"simulator error during collision check: {e}"
            env.worlds.discard_checker()  # a broken world is not reused
        if checked is not None:
            checked(b)
    return min_clear, first_hit


# ------------------------------------------------------------------ recordings that enter an obstacle
#: what the arm's obstacle depths measure, said beside every entry reported
SPHERE_MEASURE = (
    "the robot's spheres, which contain its links' meshes, against the scene's distance maps; the simulator's "
    "closest points on the meshes confirm each entry"
)


def sphere_names(robot: URDFRobot) -> tuple[str, ...]:
    """What each cover sphere is, in ``cover_spheres`` order: a control point by the tree's node name (``cp3``)
    and its link, or the sphere around a link without control points."""
    cover, n_control = cover_spheres(robot), len(robot.params.control_points)
    return tuple(
        f"cp{s + 1} (control sphere on {link})" if s < n_control else f"{link} (the sphere around its mesh)"
        for s, link in enumerate(cover.links)
    )


def obstacle_names(env: ManipulatorTask) -> tuple[str, ...]:
    """The scene's obstacles as reports name them (``obstacle1 (cylinder)``), then the ground."""
    return (*(f"obstacle{k} ({o.type})" for k, o in enumerate(env.scene.obstacles, start=1)), "the ground")


def _sphere_depth_matrix(env: ManipulatorTask, q: Tensor, aux: Mapping[str, Tensor]) -> Tensor:
    """(M, S, K + 1) clearance of every cover sphere at configurations ``q`` (M, dof) from each of the K obstacles
    of aux rows ``aux`` and, for the spheres of links that can reach it, from the ground (+inf where none)."""
    cover = cover_spheres(env.robot)
    radii = cover.radii.to(q)
    centres = _centres(env.robot, cover, q)
    M, S = centres.shape[:2]
    K = len(env.scene.obstacles)
    out = torch.full((M, S, K + 1), float("inf"), dtype=q.dtype)
    if K:
        rows = {k: v.to(q).repeat_interleave(S, 0) for k, v in aux.items()}
        out[..., :K] = distances(env.scene, rows, centres.reshape(-1, 3)).reshape(M, S, K) - radii[:, None]
    if env.scene.ground is None:
        return out  # the simulator is not asked which links reach the ground: no world is opened
    grounded = torch.tensor([link in env.checker().ground_reach for link in cover.links], dtype=torch.bool)
    if bool(grounded.any()):
        height = centres[:, grounded, 2] - float(env.scene.ground.height)
        out[:, grounded, K] = height - radii[grounded]
    return out


def _nearest_spheres(
    env: ManipulatorTask, q: Tensor, aux: Mapping[str, Tensor], rows: Tensor
) -> tuple[Tensor, Tensor, Tensor]:
    """(clearance, sphere, obstacle) of the configurations ``q[rows]``: the cover sphere nearest an obstacle (or the
    ground, obstacle index K), and its clearance."""
    clearance = torch.empty(len(rows), dtype=q.dtype)
    sphere = torch.empty(len(rows), dtype=torch.long)
    obstacle = torch.empty(len(rows), dtype=torch.long)
    for lo in range(0, len(rows), CHUNK):
        at = rows[lo : lo + CHUNK]
        depth = _sphere_depth_matrix(env, q[at], {k: v[at] for k, v in aux.items()})
        best, which = depth.reshape(len(at), -1).min(-1)
        n = len(at)
        clearance[lo : lo + n], sphere[lo : lo + n], obstacle[lo : lo + n] = (
            best,
            which // depth.shape[-1],
            which % depth.shape[-1],
        )
    return clearance, sphere, obstacle


#: the depths of the last few recordings measured in this process, by their contents and the environment's settings:
#: validation, its summary and the collect stage ask the same question of the same recordings
_DEPTHS: dict[str, ObstacleDepths] = {}
DEPTHS_KEPT = 8


def _depths_key(env: ManipulatorTask, q: Tensor, aux: Mapping[str, Tensor]) -> str:
    h = hashlib.sha256(env.params.model_dump_json().encode())
    for name, v in (("q", q), *sorted(aux.items())):
        h.update(name.encode())
        h.update(v.detach().to(torch.float64).cpu().contiguous().numpy().tobytes())
    return h.hexdigest()


def obstacle_depths(env: ManipulatorTask, q: Tensor, aux: Mapping[str, Tensor]) -> ObstacleDepths:
    """``measured_depths`` of ``q`` and ``aux``, measured once per process for the same recordings and settings."""
    key = _depths_key(env, q, aux)
    if key not in _DEPTHS:
        if len(_DEPTHS) >= DEPTHS_KEPT:
            _DEPTHS.pop(next(iter(_DEPTHS)))
        _DEPTHS[key] = measured_depths(env, q, aux)
    return _DEPTHS[key]


def measured_depths(env: ManipulatorTask, q: Tensor, aux: Mapping[str, Tensor]) -> ObstacleDepths:
    """``envs.protocol.ObstacleDepths`` of configurations ``q`` (M, dof) in the worlds of aux rows ``aux``: per
    configuration the cover sphere nearest an obstacle (or the ground) and its clearance, and the simulator's
    clearance of the configurations where that is below 0 (only there: the spheres contain the meshes, so a
    configuration whose spheres are clear cannot collide).

    The spheres are measured at every ``STRIDE``-th configuration; any other one in the same world is within
    Σᵢ ρᵢ·|Δqᵢ| of the one measured before it (``joint_reach``: no sphere moves further), so only those whose bound
    is not above 0 are measured too. Where the clearance is not below 0, it is that bound or the measure."""
    q = q.to(env.dtype)
    M = q.shape[0]
    anchor = torch.arange(M) // STRIDE * STRIDE
    clearance = torch.full((M,), float("inf"), dtype=env.dtype)
    point = torch.zeros(M, dtype=torch.long)
    obstacle = torch.zeros(M, dtype=torch.long)
    rho = joint_reach(env.robot)
    ask = torch.ones(M, dtype=torch.bool) if rho is None else anchor == torch.arange(M)
    clearance[ask], point[ask], obstacle[ask] = _nearest_spheres(env, q, aux, ask.nonzero().flatten())
    if not bool(ask.all()):
        assert rho is not None  # every row is asked without the continuity bound
        same_world = torch.ones(M, dtype=torch.bool)
        for v in aux.values():
            same_world &= (v == v[anchor]).reshape(M, -1).all(-1)
        bound = clearance[anchor] - (q - q[anchor]).abs() @ rho.to(q)
        rest = (~ask & ((bound <= 0) | ~same_world)).nonzero().flatten()
        clearance[rest], point[rest], obstacle[rest] = _nearest_spheres(env, q, aux, rest)
        bounded = ~ask & (bound > 0) & same_world
        clearance[bounded] = bound[bounded]
    confirmed = torch.full((M,), float("nan"), dtype=env.dtype)
    inside = (clearance < 0).nonzero().flatten()
    confirmed[inside] = _simulator_clearances(env, q, aux, inside.tolist())
    return ObstacleDepths(
        clearance, point, obstacle, sphere_names(env.robot), obstacle_names(env), SPHERE_MEASURE, confirmed
    )


def _simulator_clearances(env: ManipulatorTask, q: Tensor, aux: Mapping[str, Tensor], rows: list[int]) -> Tensor:
    """The simulator's clearance of the configurations ``q[rows]`` in the worlds of their aux rows (≤ 0: the links'
    meshes touch or enter an obstacle or the ground; capped at ``clearance_query``). A recording's samples share
    one world, which is built once for each run of rows holding the same aux state."""
    world, built = env.checker(), None
    out = []
    for b in rows:
        here = sample_aux(aux, b)
        if built is None or any(not np.array_equal(here[k], built[k]) for k in here):
            world.set_env(env.scene, here)
            built = here
        world.reset(q[b].detach().cpu().numpy())
        out.append(world.clearance(env.params.clearance_query))
    return torch.tensor(out, dtype=env.dtype)
