"""A reaching task laid out for any arm from its kinematics (``env.reach_layout``, ``experiment=reach``).

The arm's reach is measured from its forward kinematics over configurations drawn uniformly inside its joint limits;
every size below is a fraction of it, so a 0.4 m arm and a 1.3 m arm get the same task at their own scale. The starts
are drawn around the robot's home (``start_spread``); their end effectors' mean is the start point S. The goal point G
is S turned about the base's vertical axis by ``turn`` (away from the side S lies on), at S's height: a place the
arm reaches when its first joint turns, whatever its structure, and checked against the sampled workspace. The
obstacle is a standing cylinder on the ground (z = 0) at the midpoint of S and G (moved ``outward`` from the base),
taller than both, so the straight reach from S to G passes through it (``scenes/crossing.py``); every environment moves it by ``jitter``, and the test
split's placement is moved along the reach by ``test_shift`` (moving it outward would take it off the reaches' line:
on the training split, 0.08 of the reach outward left 68 % of the xArm6's reaches crossing) and made ``test_widen``
times wider (the paper's Franka test set
moves and resizes its obstacle). Goals are drawn in a box around G (``goal_half_width``).

The layout is derived from a fixed seed, so validation and the run derive the same numbers, and ``describe`` says
what they are.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from pydantic import Field

from ...registry import Params
from ...scenes import Ground, Scene

_SEED = 12345
_SAMPLES = 4096


class ReachLayout(Params):
    """How ``experiment=reach`` lays the task out for the environment's robot; fractions are of the arm's reach."""

    turn: float = Field(1.2, gt=0, lt=math.pi, description="rad the goal point is turned from the start point about "
                                                          "the base's vertical axis")
    goal_half_width: float = Field(0.08, ge=0, le=0.5, description="goals ~ uniform in G ± this fraction of the reach")
    obstacle_radius: float = Field(0.06, gt=0, le=0.5, description="the standing cylinder's radius, fraction of reach")
    outward: float = Field(0.05, ge=0, le=0.5, description="the cylinder moved outward (away from the base) from the "
                                                         "midpoint by this fraction: the straight reach grazes its "
                                                         "inner side instead of meeting it head on")
    obstacle_top: float = Field(0.15, ge=0, description="the cylinder's top above the higher of S and G, fraction")
    jitter: float = Field(0.02, ge=0, le=0.5, description="± uniform horizontal move of the cylinder per environment")
    test_shift: float = Field(0.04, ge=0, le=0.5, description="the test cylinder moved along the reach (towards the "
                                                              "goals) by this fraction")
    test_widen: float = Field(1.2, gt=0, description="the test cylinder's radius, times the training one's")


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

    def describe(self) -> str:
        c, r = self.scene.obstacles[0].center, self.scene.obstacles[0].radius
        f = lambda v: "(" + ", ".join(f"{a:.3f}" for a in v) + ")"  # noqa: E731
        return (f"reach layout: reach {self.reach:.3f} m; starts' end effector around {f(self.start_point)}, goals "
                f"around {f(self.goal_point)}; a standing cylinder of radius {r:.3f} m at {f(c[:2])} (test: "
                f"{f(self.test_scene.obstacles[0].center[:2])}, radius {self.test_scene.obstacles[0].radius:.3f} m)")


def derive(robot, centre: tuple[float, ...], spread: tuple[float, ...], layout: ReachLayout) -> Derived:
    """The task for ``robot`` (a built robot: kinematics and limits) with starts centred on ``centre`` ± ``spread``."""
    g = torch.Generator().manual_seed(_SEED)
    lo, hi = robot.lower, robot.upper
    # a continuous joint (no finite limits) is sampled over one turn each way, as robots/home.py samples it
    turn_lo, turn_hi = lo.clamp(min=-math.pi), hi.clamp(max=math.pi)
    anywhere = turn_lo + (turn_hi - turn_lo) * torch.rand(_SAMPLES, robot.dof, generator=g, dtype=torch.float64)
    workspace = robot.ee_position(anywhere)
    reach = float(torch.quantile(workspace[:, :2].norm(dim=-1), 0.99))
    c, s = torch.tensor(centre, dtype=torch.float64), torch.tensor(spread, dtype=torch.float64)
    starts = (c + s * (2 * torch.rand(256, robot.dof, generator=g, dtype=torch.float64) - 1)).clamp(lo, hi)
    S = robot.ee_position(starts).mean(0)
    side = -1.0 if float(S[1]) >= 0 else 1.0  # turn away from the side the starts lie on, across the x axis
    a = side * layout.turn
    rot = torch.tensor([[math.cos(a), -math.sin(a), 0.0], [math.sin(a), math.cos(a), 0.0], [0.0, 0.0, 1.0]],
                       dtype=torch.float64)
    G = rot @ S
    _check_reachable(G, c.clamp(lo, hi), reach, robot)
    h = layout.goal_half_width * reach
    goal_region = tuple((float(v) - h, float(v) + h) for v in G)
    mid = (S + G) / 2
    top = max(float(S[2]), float(G[2])) + layout.obstacle_top * reach
    radius = layout.obstacle_radius * reach
    outward = mid[:2] / mid[:2].norm().clamp_min(1e-9)
    along = (G - S)[:2] / (G - S)[:2].norm().clamp_min(1e-9)
    train_xy = mid[:2] + layout.outward * reach * outward
    test_xy = train_xy + layout.test_shift * reach * along  # along the reach: as far from its line as in training

    def post(xy, r) -> Scene:
        return Scene(obstacles=[{"type": "cylinder", "center": [float(xy[0]), float(xy[1]), top / 2], "radius": r,
                                 "height": top}], ground=Ground(height=0.0))

    j = layout.jitter * reach
    return Derived(reach=reach, start_point=tuple(map(float, S)), goal_point=tuple(map(float, G)),
                   goal_region=goal_region, scene=post(train_xy, radius), test_scene=post(test_xy, layout.test_widen * radius),
                   obstacle_jitter=(j, j, 0.0), min_start_goal_distance=0.5 * float((S - G).norm()))


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
        raise ValueError(f"reach_layout: {robot.name} cannot reach the goal point {[round(float(v), 3) for v in G]} "
                         f"inside its joint limits (inverse kinematics ends {miss:.3f} m from it); lower "
                         f"reach_layout.turn or move the robot's home")
