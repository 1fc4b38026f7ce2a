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
from collections.abc import Mapping, Sequence

import torch
from pydantic import Field
from torch import Tensor

from ..core.auxstate import CONSTANT_DTYPE
from ..core.stacking import shallow_clone, spread, stack_values
from ..core.taskmap import TaskMap
from ..examples import Example
from ..registry import TASK_MAPS, Params, numbers_repr
from .distances import _radial
from .kinematics import Chain, ForwardKinematics, joint_limit_states, rigid_body_of, robot_chain
from .robot_files import IIWA, PANDA
from .robot_params import RobotParams, Vector3


class LinkSphere(Params):
    """A control sphere: a centre fixed in a link and a radius."""

    link: str
    offset: Vector3 = Field(default_factory=lambda: [0.0, 0.0, 0.0], description="centre in the link frame (m)")
    radius: float = Field(0.0, ge=0, description="sphere radius (m); 0: the distance is taken from the centre point")


def non_adjacent_link_pairs(
    chain: Chain, links: Sequence[str] | None = None, min_separation: int = 2
) -> list[tuple[str, str]]:
    """The pairs of ``links`` (default: all) that at least ``min_separation`` actuated joints apart: the pairs a
    self-collision check needs (2, the default, leaves out links one joint apart, which touch at that joint).

    Links that no actuated joint separates (fixed joints, or movable joints the chain freezes) are one rigid body:
    their distance never changes, so they are never listed. Pairs come in the order of ``links``.
    """
    if min_separation < 1:
        raise ValueError(
            f"min_separation must be ≥ 1 (the number of actuated joints between two links); given {min_separation}"
        )
    names = chain.link_names() if links is None else list(links)
    for name in names:
        chain.check_link(name)
    body = rigid_body_of(chain)
    parent = _body_parents(chain, body)
    return [
        (a, b)
        for a, b in itertools.combinations(names, 2)
        if _joints_between(body[a], body[b], parent) >= min_separation
    ]


def _body_parents(chain: Chain, body: Mapping[str, int]) -> dict[int, int]:
    """Rigid body -> the body its actuated joint hangs from (the root's body has none)."""
    return {
        body[j.child]: body[j.parent]
        for j in chain.model.joints
        if j.name in chain.actuated or j.name in chain.followers
    }


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


@TASK_MAPS.register(
    "link_sphere_distance",
    examples=[
        Example(
            PANDA(
                a={"link": "panda_link3", "offset": [0.1, 0.07, 0.0], "radius": 0.1},
                b={"link": "panda_hand", "offset": [0.0, 0.0, 0.09], "radius": 0.09},
            ),
            7,
            joint_limit_states(PANDA),
        ),
        Example(
            IIWA(
                a={"link": "lbr_iiwa_link_2"}, b={"link": "lbr_iiwa_link_6", "offset": [0.0, 0.05, 0.0], "radius": 0.08}
            ),
            7,
            joint_limit_states(IIWA),
        ),
    ],
)
class LinkSphereDistance(TaskMap):
    """y = |p_a(q) − p_b(q)| − r_a − r_b: the gap between control spheres ``a`` and ``b`` on two links of the robot.

    The two links must move relative to each other (not one rigid body). Both centres come from one pass of the
    chain (a group of two ``forward_kinematics`` points), and gaps on one robot stack (``core/stacking.py``): a group
    of G gaps evaluates its 2G centres from one pass. J and J̇ẋ are analytic (module docstring).
    """

    stack_fields = ("radii",)  # and the centres, stacked by ``stacked``

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
            raise ValueError(
                f"link_sphere_distance: links '{params.a.link}' and '{params.b.link}' move as one rigid "
                f"body (no actuated joint between them), so the distance of their spheres never changes; "
                f"pick spheres on links that move relative to each other (non_adjacent_link_pairs)"
            )
        robot = params.model_dump(include={"robot", "urdf", "joints", "mount"}, exclude_unset=True)
        self.point_a = self._point(params.a, robot, in_dim)
        self.point_b = self._point(params.b, robot, in_dim)
        self.radii = params.a.radius + params.b.radius
        self.out_dim = 1
        object.__setattr__(self, "centres", _centres([self.point_a], [self.point_b]))

    def _point(self, sphere: LinkSphere, robot: dict, in_dim: int) -> ForwardKinematics:
        point = ForwardKinematics(
            ForwardKinematics.Params(**robot, link=sphere.link, offset=list(sphere.offset)), in_dim, self.aux_dims
        )
        point.chain = self.chain  # one set of robot constants for both centres
        return point

    def stack_settings(self) -> tuple:
        return self.point_a.stack_settings()  # spheres on one robot model

    @classmethod
    def stacked(cls, members: Sequence[LinkSphereDistance], like: Tensor) -> LinkSphereDistance:
        group = shallow_clone(members[0])
        object.__setattr__(group, "centres", _centres([m.point_a for m in members], [m.point_b for m in members]))
        object.__setattr__(group, "radii", stack_values([m.radii for m in members], like))
        return group

    def forward(self, x, xd, aux=None):
        """(y, ẏ, J, J̇ẋ) of the gap(s): x is (B, m) on its own, (G, B, m) or (1, B, m) in a group of G."""
        alone = x.dim() == 2
        if alone:
            x, xd = x.unsqueeze(0), xd.unsqueeze(0)
        elif x.shape[0] > 1:  # one parent state per member: the a and b centres of member g read row g
            x, xd = torch.cat([x, x]), torch.cat([xd, xd])
        p, pd, Jp, cp = self.centres(x, xd)  # (2G, B, ...): the a centres, then the b centres
        G = p.shape[0] // 2
        d, dd = p[:G] - p[G:], pd[:G] - pd[G:]
        r, n, rate, curv = _radial(d, dd)
        J = (n.unsqueeze(-1) * (Jp[:G] - Jp[G:])).sum(-2, keepdim=True)  # nᵀ(J_a − J_b), (G, B, 1, m)
        c = (n * (cp[:G] - cp[G:])).sum(-1, keepdim=True) + curv
        out = (r - spread(self.radii, 1), rate, J, c)
        return tuple(t.squeeze(0) for t in out) if alone else out

    def psi(self, x, aux):
        return self.forward(x, torch.zeros_like(x), aux)[0]

    def jacobian(self, x, aux=None):
        return self.forward(x, torch.zeros_like(x), aux)[2]

    def curvature(self, x, xd, aux=None, J=None):
        return self.forward(x, xd, aux)[3]

    def extra_repr(self) -> str:
        return numbers_repr({"in_dim": self.in_dim, "out_dim": self.out_dim, "radii": self.radii})


def _centres(a: Sequence[ForwardKinematics], b: Sequence[ForwardKinematics]):
    """The a centres then the b centres as one group of forward-kinematics points (one pass of the chain for all);
    its stacked numbers are float64 and cast to the input's dtype on use, like a point's own."""
    return ForwardKinematics.stacked([*a, *b], torch.zeros((), dtype=CONSTANT_DTYPE))
