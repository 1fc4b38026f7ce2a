"""A reaching task laid out for any arm from its kinematics (``env.reach_layout``, ``experiment=reach``).

The arm's reach is measured from its forward kinematics over configurations drawn uniformly inside its joint limits,
as the horizontal distance of the end effector from the base (the robot's mount); every size below is a fraction of
it, so a 0.4 m arm and a 1.3 m arm get the same task at their own scale. The starts are drawn around the robot's home
(``start_spread``); their end effectors' mean is the start point S. The goal point G is S turned about the base's
vertical axis by ``turn`` (away from the side S lies on), at S's height: a place the arm reaches when its first joint
turns, whatever its structure, and checked against the sampled workspace by inverse kinematics.

The obstacle is a standing cylinder on the ground (z = 0), taller than S and G. Where it stands and how wide it is
are searched, not fixed: the mean of S and G is not where the straight reaches bundle (a UR5's or a Kinova's starts
fan out, and their reaches pass a cylinder at the midpoint on both sides). The layout draws its own starts (around
home, as the environment does) and goals (in the goal box), and over a grid of places between S and G (``along``,
``across``) and radii (``obstacle_radius`` × ``radius_steps``) it keeps the cylinder that the most of these reaches
both cross and may start (a start whose control spheres are ``start_clearance`` from the cylinder, a goal
``goal_clearance`` from it: the environment redraws the others), a wider one only where more cross. It prefers the
midpoint moved ``outward`` (away from the base): there the straight reach grazes the cylinder's inner side, which
turns the expert around it, where a cylinder on the midpoint met head on pins it in front (on the iiwa the expert
reached 7 of 20 validation goals so, 18 of 20 at 0.05 of the reach outward). That place is kept while at least
``keep`` of the most reaches cross there; on an arm whose reaches fan out (a UR5, a Kinova: 20-47 % crossed at that
place) the nearest place that does is taken. A place where the cylinder would stand within ``start_clearance`` of
the links no joint moves (the base) is never taken: no start could be placed. Every environment moves the cylinder
by ``jitter``; the test split's is moved along the reach by ``test_shift`` (moving it outward would take it off the reaches' line) and made
``test_widen`` times wider (the paper's Franka test set moves and resizes its obstacle). Goals are drawn in a box
around G (``goal_half_width``).

The layout is derived from a fixed seed, so validation and the run derive the same numbers, and ``describe`` says
what they are, with the fraction of its own reaches that cross.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from pydantic import Field, field_validator

from ...registry import Params
from ...robots.home import ground_check
from ...scenes import Cylinder, Ground, Scene

_SEED = 12345
_SAMPLES = 4096
_REACHES = 256  # the layout's own starts and goals
_GRID = 11  # places tried along and across the reach


class ReachLayout(Params):
    """How ``experiment=reach`` lays the task out for the environment's robot; fractions are of the arm's reach."""

    min_outreach: float = Field(
        0.35,
        ge=0,
        lt=1,
        description="the starts' end effector must lie at least this "
        "fraction of the reach out from the base's axis (a reach turned about the base needs "
        "room); where the robot's home is closer (an upright arm), the starts' centre becomes ...",
    )
    outreach: tuple[float, float] = Field(
        (0.45, 0.75),
        description="... the sampled configuration nearest home whose "
        "end effector lies between these fractions of the reach out, clear of the "
        "ground",
    )
    turn: float = Field(
        1.2,
        gt=0,
        lt=math.pi,
        description="rad the goal point is turned from the start point about the base's vertical axis",
    )
    goal_half_width: float = Field(0.08, ge=0, le=0.5, description="goals ~ uniform in G ± this fraction of the reach")
    obstacle_radius: float = Field(
        0.06, gt=0, le=0.5, description="the standing cylinder's smallest radius tried, fraction of the reach"
    )
    radius_steps: tuple[float, ...] = Field(
        (1.0,), min_length=1, description="radii tried: obstacle_radius times each of these"
    )
    along: tuple[float, float] = Field(
        (0.25, 0.75), description="the cylinder's place is searched between these fractions of the way from S to G ..."
    )
    across: float = Field(0.15, ge=0, le=0.5, description="... and this fraction of the reach either side of that line")
    outward: float = Field(
        0.05,
        ge=0,
        le=0.5,
        description="the preferred place: the midpoint of S and G moved this "
        "fraction outward (away from the base), where the straight "
        "reach grazes the cylinder's inner side instead of meeting it "
        "head on ...",
    )
    keep: float = Field(
        0.9,
        gt=0,
        le=1,
        description="... taken while at least this fraction of the most reaches cross "
        "there; else the place nearest it that does",
    )
    obstacle_top: float = Field(0.15, ge=0, description="the cylinder's top above the higher of S and G, fraction")
    jitter: float = Field(0.02, ge=0, le=0.5, description="± uniform horizontal move of the cylinder per environment")
    test_shift: float = Field(
        0.04, ge=0, le=0.5, description="the test cylinder moved along the reach (towards the goals) by this fraction"
    )
    test_widen: float = Field(1.2, gt=0, description="the test cylinder's radius, times the training one's")

    @field_validator("radius_steps")
    @classmethod
    def _positive_steps(cls, v: tuple[float, ...]) -> tuple[float, ...]:
        if not all(0 < k <= 10 for k in v):
            raise ValueError(f"radius_steps: every step must lie in (0, 10] (a multiple of obstacle_radius); given {v}")
        return v

    @field_validator("along", "outreach")
    @classmethod
    def _fractions(cls, v: tuple[float, float], info) -> tuple[float, float]:
        if not 0 <= v[0] <= v[1] <= 1:
            raise ValueError(f"{info.field_name}: must be two fractions 0 <= low <= high <= 1; given {list(v)}")
        return v


@dataclass(frozen=True)
class Derived:
    """The numbers a layout gives one robot (m)."""

    reach: float
    start_point: tuple[float, float, float]
    goal_point: tuple[float, float, float]
    goal_region: tuple[tuple[float, float], tuple[float, float], tuple[float, float]]
    scene: Scene
    test_scene: Scene
    obstacle_jitter: tuple[float, float, float]
    min_start_goal_distance: float
    start_centre: tuple[float, ...] | None  # the starts' centre the layout chose (None: the robot's home / nominal_q)
    crossing: float  # of the layout's own reaches that may start (start and goal clear of the cylinder), those crossing
    startable: float  # of the layout's own reaches, those whose start and goal are clear of the cylinder

    def describe(self) -> str:
        cylinder, test_cylinder = self.scene.obstacles[0], self.test_scene.obstacles[0]
        assert isinstance(cylinder, Cylinder) and isinstance(test_cylinder, Cylinder)  # what derive places
        c, r = cylinder.center, cylinder.radius
        f = lambda v: "(" + ", ".join(f"{a:.3f}" for a in v) + ")"
        lean = (
            ""
            if self.start_centre is None
            else (f"starts around {f(self.start_centre)} (home leaves the end effector too near the base's axis); ")
        )
        return (
            f"reach layout: reach {self.reach:.3f} m; {lean}starts' end effector around {f(self.start_point)}, goals "
            f"around {f(self.goal_point)}; a standing cylinder of radius {r:.3f} m at {f(c[:2])} (test: "
            f"{f(test_cylinder.center[:2])}, radius {test_cylinder.radius:.3f} m); "
            f"{self.crossing:.0%} of the layout's own reaches cross it ({self.startable:.0%} may start)"
        )


@dataclass(frozen=True)
class Clearances:
    """What the environment asks of a start and a goal, and what a reach must clear (m)."""

    start: float  # every control sphere this far from the cylinder at the start
    goal: float  # the goal this far from it
    end_effector: float  # the end effector's control sphere: a straight reach closer than this crosses
    fixed_extent: float  # the links no joint moves (the base) reach this far horizontally from the base's axis


def _point(v: torch.Tensor) -> tuple[float, float, float]:
    """A point (3,) as plain floats."""
    x, y, z = (float(a) for a in v)
    return x, y, z


def derive(
    robot,
    centre: tuple[float, ...],
    spread: tuple[float, ...],
    layout: ReachLayout,
    clear: Clearances,
    centre_given: bool = False,
) -> Derived:
    """The task for ``robot`` (a built robot: kinematics, limits, control spheres) with starts centred on ``centre`` ±
    ``spread`` (the robot's home, or ``nominal_q`` when ``centre_given``: then it is never moved)."""
    g = torch.Generator().manual_seed(_SEED)
    lo, hi = robot.lower, robot.upper
    base = torch.tensor(robot.base_pose()[0], dtype=torch.float64)
    # a continuous joint (no finite limits) is sampled over one turn each way, as robots/home.py samples it
    turn_lo, turn_hi = lo.clamp(min=-math.pi), hi.clamp(max=math.pi)
    anywhere = turn_lo + (turn_hi - turn_lo) * torch.rand(_SAMPLES, robot.dof, generator=g, dtype=torch.float64)
    out = (robot.ee_position(anywhere) - base)[:, :2].norm(dim=-1)
    reach = float(torch.quantile(out, 0.99))
    c, s = torch.tensor(centre, dtype=torch.float64), torch.tensor(spread, dtype=torch.float64)
    chosen = None
    if float((robot.ee_position(c[None])[0] - base)[:2].norm()) < layout.min_outreach * reach:
        if centre_given:
            raise ValueError(
                f"reach_layout: env.nominal_q puts {robot.name}'s end effector less than "
                f"{layout.min_outreach} of its reach ({reach:.3f} m) from the base's axis, leaving no room "
                f"for a reach turned about the base; lean the arm out in nominal_q, or leave nominal_q "
                f"out and the layout picks the starts' centre"
            )
        c = _leaning_centre(robot, c, anywhere, out, reach, layout, clear)
        chosen = tuple(round(float(v), 4) for v in c)
    starts = (c + s * (2 * torch.rand(_REACHES, robot.dof, generator=g, dtype=torch.float64) - 1)).clamp(lo, hi)
    ee = robot.ee_position(starts)
    S = ee.mean(0)
    side = -1.0 if float(S[1] - base[1]) >= 0 else 1.0  # turn away from the side the starts lie on
    G = base + _turned(side * layout.turn) @ (S - base)
    _check_reachable(G, c.clamp(lo, hi), reach, robot)
    h = layout.goal_half_width * reach
    gx, gy, gz = _point(G)
    goal_region = ((gx - h, gx + h), (gy - h, gy + h), (gz - h, gz + h))
    goals = G + h * (2 * torch.rand(_REACHES, 3, generator=g, dtype=torch.float64) - 1)
    top = max(float(S[2]), float(G[2])) + layout.obstacle_top * reach
    xy, radius, crossing, startable = _place_cylinder(robot, starts, ee, goals, S, G, base, reach, layout, clear)
    along = (G - S)[:2] / (G - S)[:2].norm().clamp_min(1e-9)
    test_xy = xy + layout.test_shift * reach * along  # along the reach: as far from its line as in training

    def post(at, r) -> Scene:
        return Scene(
            obstacles=[
                {"type": "cylinder", "center": [float(at[0]), float(at[1]), top / 2], "radius": r, "height": top}
            ],
            ground=Ground(height=0.0),
        )

    j = layout.jitter * reach
    return Derived(
        reach=reach,
        start_point=_point(S),
        goal_point=_point(G),
        goal_region=goal_region,
        scene=post(xy, radius),
        test_scene=post(test_xy, layout.test_widen * radius),
        obstacle_jitter=(j, j, 0.0),
        min_start_goal_distance=0.5 * float((S - G).norm()),
        start_centre=chosen,
        crossing=crossing,
        startable=startable,
    )


def _leaning_centre(
    robot,
    home: torch.Tensor,
    samples: torch.Tensor,
    out: torch.Tensor,
    reach: float,
    layout: ReachLayout,
    clear: Clearances,
) -> torch.Tensor:
    """Of the configurations ``samples`` (their end effectors ``out`` m from the base's axis), the one nearest
    ``home`` (in fractions of each joint's range) whose end effector lies ``layout.outreach`` of the reach out and
    whose control spheres clear the ground as a start must."""
    lo, hi = layout.outreach
    fits = (out >= lo * reach) & (out <= hi * reach) & ground_check(robot.params, clearance=clear.start)(samples)
    if not bool(fits.any()):
        raise ValueError(
            f"reach_layout: no configuration of {robot.name} inside its limits puts the end effector "
            f"{lo}-{hi} of its reach out from the base clear of the ground; set a home that leans "
            f"out in the robot file, or env.nominal_q"
        )
    span = robot.upper.clamp(max=math.pi) - robot.lower.clamp(min=-math.pi)
    distance = ((samples - home) / span).norm(dim=-1).masked_fill(~fits, math.inf)
    return samples[int(distance.argmin())]


def _turned(a: float) -> torch.Tensor:
    """The rotation by ``a`` about the vertical axis."""
    return torch.tensor(
        [[math.cos(a), -math.sin(a), 0.0], [math.sin(a), math.cos(a), 0.0], [0.0, 0.0, 1.0]], dtype=torch.float64
    )


def _place_cylinder(
    robot, starts, ee, goals, S, G, base, reach: float, layout: ReachLayout, clear: Clearances
) -> tuple[torch.Tensor, float, float, float]:
    """(xy, radius, crossing, startable) of the standing cylinder that the most of the layout's reaches (start
    configurations ``starts`` with end effectors ``ee``, goals ``goals``) both cross and may start; see the module
    docstring. The cylinder stands taller than the reaches, so only horizontal distances count (a control sphere
    above its top is counted as if beside it: a stricter start)."""
    along, across = torch.meshgrid(
        torch.linspace(*layout.along, _GRID, dtype=torch.float64),
        torch.linspace(-layout.across, layout.across, _GRID, dtype=torch.float64),
        indexing="ij",
    )
    line = (G - S)[:2]
    normal = torch.stack([-line[1], line[0]]) / line.norm().clamp_min(1e-9)
    places = S[:2] + along.reshape(-1, 1) * line + across.reshape(-1, 1) * reach * normal  # (P, 2)
    mid = (S + G)[:2] / 2
    outward = (mid - base[:2]) / (mid - base[:2]).norm().clamp_min(1e-9)
    preferred_distance = (places - (mid + layout.outward * reach * outward)).norm(dim=-1)
    spheres = robot.sphere_centres(starts)[..., :2]  # (N, C, 2)
    sphere_r = torch.tensor([cp.radius for cp in robot.params.control_points], dtype=starts.dtype)
    seg = _point_to_segments(places, ee[:, :2], goals[:, :2])  # (P, N)
    best: tuple | None = None
    for step in layout.radius_steps:
        r = layout.obstacle_radius * step * reach
        cross = seg < r + clear.end_effector
        start_ok = ((spheres[None] - places[:, None, None]).norm(dim=-1) - sphere_r - r >= clear.start).all(-1)
        goal_ok = (goals[None, :, :2] - places[:, None]).norm(dim=-1) - r >= clear.goal
        base_ok = (places - base[:2]).norm(dim=-1) - r >= clear.fixed_extent + clear.start  # (P,)
        ok = start_ok & goal_ok & base_ok[:, None]
        score = (cross & ok).double().mean(-1)
        i = int(preferred_distance.masked_fill(score < layout.keep * score.max(), math.inf).argmin())
        if best is None or float(score[i]) > best[0] + 1e-12:  # a wider cylinder only where it crosses more
            crossing = float((cross[i] & ok[i]).double().sum() / ok[i].double().sum().clamp_min(1))
            best = (float(score[i]), places[i], r, crossing, float(ok[i].double().mean()))
    if best is None or best[0] <= 0.0:
        raise ValueError(
            f"reach_layout: no place between the start and goal points of {robot.name} lets a standing "
            f"cylinder cross the reaches while the starts stay clear of it (and of the base) by "
            f"env.start_clearance; raise reach_layout.turn or reach_layout.across, or lower "
            f"env.start_clearance"
        )
    return best[1], best[2], best[3], best[4]


def _point_to_segments(points: torch.Tensor, a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """(P, N) distance from each of ``points`` (P, 2) to each segment a[n] → b[n] (N, 2)."""
    d = b - a
    t = (((points[:, None] - a[None]) * d[None]).sum(-1) / (d * d).sum(-1).clamp_min(1e-18)).clamp(0, 1)
    return (points[:, None] - (a[None] + t[..., None] * d[None])).norm(dim=-1)


def _check_reachable(G: torch.Tensor, centre: torch.Tensor, reach: float, robot) -> None:
    """The goal point lies where the arm reaches inside its limits: a projected-gradient inverse kinematics from the
    starts' centre comes within 1 % of the reach of it."""
    q = centre.clone().unsqueeze(0).requires_grad_(True)
    opt = torch.optim.Adam([q], lr=0.05)
    for _ in range(300):
        opt.zero_grad()
        loss = (robot.ee_position(q)[0] - G).pow(2).sum()
        loss.backward()
        opt.step()
        with torch.no_grad():
            q.copy_(torch.maximum(torch.minimum(q, robot.upper), robot.lower))
    miss = float((robot.ee_position(q.detach())[0] - G).norm())
    if miss > 0.01 * reach:
        raise ValueError(
            f"reach_layout: {robot.name} cannot reach the goal point {[round(float(v), 3) for v in G]} "
            f"inside its joint limits (inverse kinematics ends {miss:.3f} m from it); lower "
            f"reach_layout.turn or move the robot's home"
        )
