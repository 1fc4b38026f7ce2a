"""Which control spheres can move up or down, and a home configuration proposed for a robot that has none: the middle of every joint's range, or the nearest
configuration to it whose control spheres clear the ground.

Only spheres whose height changes over the joints' range are judged (sampled, not assumed): a sphere on a link no
joint can raise or lower, such as a shoulder that only spins about the vertical, sits where it sits whatever the
configuration; and a sphere that can never rise ``clearance`` above the ground is asked only for the height it can
reach.
"""

from __future__ import annotations

import math

import torch

from .description import RobotDescription
from .robot import build_robot

#: configurations sampled (uniformly within the limits, a continuous joint over one turn)
SAMPLES = 512
#: a sphere whose centre height varies less than this over the samples (m) cannot move towards the ground
STILL = 1e-5


def mid_range(robot: RobotDescription) -> list[float]:
    """The middle of every joint's range; 0 for a joint with no finite limits (continuous)."""
    out = []
    for lo, hi, _ in robot.joint_limits():
        out.append(round((lo + hi) / 2, 4) if math.isfinite(lo) and math.isfinite(hi) else 0.0)
    return out


def sphere_heights(robot: RobotDescription, q: torch.Tensor) -> torch.Tensor:
    """(B, S) height of every control sphere's lowest point at configurations ``q`` (B, dof)."""
    radii = torch.tensor([cp.radius for cp in robot.control_points], dtype=q.dtype)
    return build_robot(robot).sphere_centres(q)[..., 2] - radii


def sampled_configurations(robot: RobotDescription, n: int = SAMPLES, seed: int = 0) -> torch.Tensor:
    """(n, dof) configurations uniform within the limits (a continuous joint over one turn each way)."""
    lo = torch.tensor([max(lim[0], -math.pi) for lim in robot.joint_limits()], dtype=torch.float64)
    hi = torch.tensor([min(lim[1], math.pi) for lim in robot.joint_limits()], dtype=torch.float64)
    g = torch.Generator().manual_seed(seed)
    return lo + (hi - lo) * torch.rand(n, len(lo), generator=g, dtype=torch.float64)


def spheres_at_fixed_height(robot: RobotDescription) -> list[int]:
    """Indices (from 0) of the control spheres whose height no joint changes (sampled): a ground barrier on one of
    them could never act, and one that starts below the ground would stay there."""
    return sorted(spheres_without_ground_edge(robot, ground=-math.inf))


def spheres_never_clear_of(robot: RobotDescription, ground: float = 0.0) -> list[int]:
    """Indices (from 0) of the control spheres that reach below ``ground`` in every configuration (sampled): a
    sphere beside a shoulder axis, coarser than the link it covers. A ground barrier on one would act at full
    strength wherever the arm is, holding the whole arm back for a contact the link itself never makes."""
    if not robot.control_points:
        return []
    return _below(_sampled_heights(robot), ground)


def spheres_without_ground_edge(robot: RobotDescription, ground: float = 0.0) -> set[int]:
    """The spheres a tree gives no ground edge, from one sampling of their heights: those no joint raises or lowers
    (``spheres_at_fixed_height``) and those below ``ground`` everywhere (``spheres_never_clear_of``)."""
    if not robot.control_points:
        return set()
    heights = _sampled_heights(robot)
    still = (heights.max(0).values - heights.min(0).values) <= STILL
    return {i for i, s in enumerate(still.tolist()) if s} | set(_below(heights, ground))


def _sampled_heights(robot: RobotDescription) -> torch.Tensor:
    return sphere_heights(robot, sampled_configurations(robot))


def _below(heights: torch.Tensor, ground: float) -> list[int]:
    return [i for i, top in enumerate(heights.max(0).values.tolist()) if top < ground]


def ground_check(robot: RobotDescription, ground: float = 0.0, clearance: float = 0.05, seed: int = 0):
    """A function of configurations (B, dof) -> (B,) bool: every control sphere that can move up or down is
    ``clearance`` above the ground or, if it can never rise that far (beside a shoulder axis), as high as it can get
    less 2 mm: the rule the environment's start check applies to links."""
    heights = sphere_heights(robot, sampled_configurations(robot, SAMPLES, seed))
    moves = (heights.max(0).values - heights.min(0).values) > STILL
    need = torch.minimum(torch.full_like(heights[0], ground + clearance), heights.max(0).values - 0.002)
    return lambda q: (sphere_heights(robot, q)[:, moves] >= need[moves]).all(-1)


def propose_home(
    robot: RobotDescription, ground: float = 0.0, clearance: float = 0.05, seed: int = 0
) -> tuple[list[float], str]:
    """(home, how it was chosen): mid-range when every sphere that can move up or down is ``clearance`` above the
    ground there, else the sampled configuration nearest to mid-range (in fractions of each range) that is."""
    mid = torch.tensor([mid_range(robot)], dtype=torch.float64)
    if not robot.control_points:
        return mid[0].tolist(), "the middle of every joint's range (no control spheres to check against the ground)"
    lo = torch.tensor([max(lim[0], -math.pi) for lim in robot.joint_limits()], dtype=torch.float64)
    hi = torch.tensor([min(lim[1], math.pi) for lim in robot.joint_limits()], dtype=torch.float64)
    samples = sampled_configurations(robot, SAMPLES, seed)
    clear = ground_check(robot, ground, clearance, seed)
    if bool(clear(mid)[0]):
        return mid[0].tolist(), "the middle of every joint's range (clear of the ground)"
    ok = clear(samples)
    if not bool(ok.any()):
        return mid[0].tolist(), (
            f"the middle of every joint's range, though some sphere is less than {clearance} m "
            f"above the ground there and no sampled configuration clears it: set home by hand"
        )
    distance = ((samples - mid) / (hi - lo)).norm(dim=-1).masked_fill(~ok, math.inf)
    best = torch.minimum(torch.maximum(samples[int(distance.argmin())].round(decimals=3), lo), hi)
    return best.tolist(), (
        f"the configuration nearest the middle of every joint's range whose "
        f"spheres clear the ground by {clearance} m, of {SAMPLES} sampled"
    )
