"""Self-collision: the distance between two control spheres on two links of one robot, and which link pairs need one.

``link_sphere_distance`` maps the joint space to ``|p_a(q) − p_b(q)| − r_a − r_b``: the gap between sphere a
(centre ``p_a`` fixed in link a) and sphere b, negative when they overlap. With ``d = p_a − p_b`` and ``n = d/|d|``,

    J = nᵀ (J_a − J_b),      J̇q̇ = nᵀ (J̇_a q̇ − J̇_b q̇) + (|ḋ|² − (n·ḋ)²)/|d|,

where the point Jacobians and ``J̇q̇`` of each centre are those of ``forward_kinematics`` (the map holds one per
sphere, sharing one chain). The ``collision_avoidance`` barrier on this coordinate keeps the spheres apart
(``conf/rmp/self_collision.yaml``). Spheres on links that an actuated joint connects directly touch by
construction, so ``non_adjacent_link_pairs`` lists the link pairs that should be checked.
"""
from __future__ import annotations

import itertools
from typing import Mapping, Sequence

import torch
from pydantic import Field

from ..core.taskmap import TaskMap
from ..registry import TASK_MAPS, Params
from .distances import _radial
from .kinematics import Chain, ForwardKinematics
from .robot import RobotParams, Vector3, rigid_body_of, robot_chain


class LinkSphere(Params):
    """A control sphere: a centre fixed in a link and a radius."""

    link: str
    offset: Vector3 = Field(default_factory=lambda: [0.0, 0.0, 0.0], description="centre in the link frame (m)")
    radius: float = Field(0.0, ge=0, description="sphere radius (m); 0: the distance is taken from the centre point")


def non_adjacent_link_pairs(chain: Chain, links: Sequence[str] | None = None,
                            min_separation: int = 2) -> list[tuple[str, str]]:
    """The pairs of ``links`` (default: all) that at least ``min_separation`` actuated joints apart: the pairs a
    self-collision check needs (2, the default, leaves out links one joint apart, which touch at that joint).

    Links that no actuated joint separates (fixed joints, or movable joints the chain freezes) are one rigid body:
    their distance never changes, so they are never listed. Pairs come in the order of ``links``.
    """
    if min_separation < 1:
        raise ValueError(f"min_separation must be ≥ 1 (the number of actuated joints between two links); "
                         f"given {min_separation}")
    names = chain.link_names() if links is None else list(links)
    for name in names:
        chain.check_link(name)
    body = rigid_body_of(chain)
    parent = _body_parents(chain, body)
    return [(a, b) for a, b in itertools.combinations(names, 2)
            if _joints_between(body[a], body[b], parent) >= min_separation]


def _body_parents(chain: Chain, body: Mapping[str, int]) -> dict[int, int]:
    """Rigid body -> the body its actuated joint hangs from (the root's body has none)."""
    return {body[j.child]: body[j.parent] for j in chain.model.joints if j.name in chain.actuated}


def _joints_between(a: int, b: int, parent: Mapping[int, int]) -> int:
    """Number of actuated joints on the path between bodies a and b of the body tree."""
    up_a = _ancestors(a, parent)
    depth_b = {n: i for i, n in enumerate(_ancestors(b, parent))}
    for i, n in enumerate(up_a):
        if n in depth_b:
            return i + depth_b[n]
    raise AssertionError("bodies of one chain share its root")  # pragma: no cover


def _ancestors(n: int, parent: Mapping[int, int]) -> list[int]:
    out = [n]
    while out[-1] in parent:
        out.append(parent[out[-1]])
    return out


@TASK_MAPS.register("link_sphere_distance")
class LinkSphereDistance(TaskMap):
    """y = |p_a(q) − p_b(q)| − r_a − r_b: the gap between control spheres ``a`` and ``b`` on two links of the robot.

    The two links must move relative to each other (not one rigid body). Siblings of this type under one parent
    share one forward-kinematics pass (``prepare``). J and J̇ẋ are analytic (module docstring).
    """

    class Params(RobotParams):
        a: LinkSphere
        b: LinkSphere

    def __init__(self, params: Params, in_dim: int, aux_dims: Mapping[str, int] | None = None):
        super().__init__(in_dim, aux_dims)
        self.chain = robot_chain(params, in_dim, "link_sphere_distance")
        for key in ("a", "b"):
            self.chain.check_link(getattr(params, key).link)
        body = rigid_body_of(self.chain)
        if body[params.a.link] == body[params.b.link]:
            raise ValueError(f"link_sphere_distance: links '{params.a.link}' and '{params.b.link}' move as one rigid "
                             f"body (no actuated joint between them), so the distance of their spheres never changes; "
                             f"pick spheres on links that move relative to each other (non_adjacent_link_pairs)")
        robot = params.model_dump(include={"robot", "urdf", "joints"}, exclude_unset=True)
        self.point_a = self._point(params.a, robot, in_dim)
        self.point_b = self._point(params.b, robot, in_dim)
        self.radii = params.a.radius + params.b.radius
        self.shared_key = ("link_sphere_distance", *self.point_a.shared_key[1:])
        self.out_dim = 1

    def _point(self, sphere: LinkSphere, robot: dict, in_dim: int) -> ForwardKinematics:
        point = ForwardKinematics(ForwardKinematics.Params(**robot, link=sphere.link, offset=list(sphere.offset)),
                                  in_dim, self.aux_dims)
        point.chain = self.chain  # one set of robot constants for both centres
        return point

    def _gap(self, a, b):
        """(y, ẏ, J, J̇ẋ) of the gap from the two centres' (p, ṗ, J, J̇ẋ)."""
        d, dd = a[0] - b[0], a[1] - b[1]
        r, n, curv = _radial(d, dd, 1.0)
        J = (n.unsqueeze(-1) * (a[2] - b[2])).sum(1, keepdim=True)  # nᵀ(J_a − J_b), (B, 1, dof)
        c = (n * (a[3] - b[3])).sum(-1, keepdim=True) + curv
        return r - self.radii, (n * dd).sum(-1, keepdim=True), J, c

    def psi(self, x, aux):
        return (self.point_a.psi(x, aux) - self.point_b.psi(x, aux)).norm(dim=-1, keepdim=True) - self.radii

    def forward(self, x, xd, aux=None):
        return self._gap(self.point_a(x, xd, aux), self.point_b(x, xd, aux))

    def jacobian(self, x, aux=None):
        return self.forward(x, torch.zeros_like(x), aux)[2]

    def curvature(self, x, xd, aux=None, J=None):
        return self.forward(x, xd, aux)[3]

    def prepare(self, x, xd, aux=None):
        return self.point_a.prepare(x, xd, aux)

    def adopt_shared(self, other: "LinkSphereDistance") -> None:
        self.chain = self.point_a.chain = self.point_b.chain = other.chain

    def from_prepared(self, prepared, x, xd, aux=None):
        return self._gap(self.point_a.from_prepared(prepared, x, xd, aux),
                         self.point_b.from_prepared(prepared, x, xd, aux))
