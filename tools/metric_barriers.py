#!/usr/bin/env python
"""Does a barrier without a potential still keep a body off its obstacle? The obstacle (and joint-limit) barriers'
Φ = ½·α·w(x)²: α = 0 leaves a barrier of metric and damping only, which meets premise 5 of docs/math.md §12 (no
potential besides the attractor's) while its velocity-gated metric still grows without bound toward the obstacle.
Rollouts from starts aimed at the obstacle, with the shipped α and with α = 0, every weight 1 (the RMPflow tree,
nothing learned) and with the experiment's hand-designed expert weights:

* the plane: 2d1level's tree (an attractor to the goal at the origin and the collision_avoidance barrier of a disc of
  radius 0.5 m centred at (-1.5, 0), between the starts and the goal), from starts at x = -3.5 m spread across the
  disc (|y| ≤ 0.3 m, the first exactly on the line through the disc's centre and the goal), at rest and at 1 and
  2 m/s toward the goal; RK4 at 100 Hz for 20 s;
* the Panda: experiment=franka's tree (every control point's barrier of the cylinder, the joint-limit barriers), from
  the validation split's starts, whose straight reaches run into the cylinder, in the kinematic simulator at 250 Hz
  for 10 s; the control spheres' clearance (the tree's own distance maps, every record) and the links' meshes' (the
  simulator's).

Prints, per variant: how many rollouts enter the obstacle (the particle's position, or a control sphere, below 0),
the least clearance, how many reach the goal (within 1 mm on the plane, the task's tolerance on the arm) and, on the
arm, the links' collisions.

    python tools/metric_barriers.py                  # both
    python tools/metric_barriers.py --only plane     # the plane alone (seconds)
"""

from __future__ import annotations

import argparse
import sys
import time

import torch

from rmpfusion.assembly.tree import build_tree
from rmpfusion.envs.manipulator.collisions import sphere_clearance
from rmpfusion.pipeline.collect import SPLIT_SEED_OFFSET
from rmpfusion.pipeline.compose import compose_run
from rmpfusion.pipeline.construct import build_all, build_unit_weights, expert_spec

#: the plane's integration step (s)
PLANE_DT = 0.01
#: the plane's disc, goal and starts
DISC_CENTRE, DISC_RADIUS = (-1.5, 0.0), 0.5
START_X, OFFSETS, SPEEDS = -3.5, (0.0, 0.02, 0.05, 0.1, 0.2, 0.3, -0.02, -0.05, -0.1, -0.2, -0.3), (0.0, 1.0, 2.0)


def tree_of(run, env, weights: str):
    """The experiment's tree with every weight 1 (``unit``) or the expert's hand-designed weights (``expert``)."""
    if weights == "unit":
        return build_unit_weights(run, env.aux_dims())
    return build_tree(expert_spec(run), aux_dims=env.aux_dims())


def plane_rollouts(alpha: float | None, weights: str) -> dict:
    """The plane's numbers for the barrier's α (None: the shipped one) and the ``weights``."""
    over = ["experiment=2d1level", "logger=disabled", f"env.dt={PLANE_DT}"]
    over += [] if alpha is None else [f"tree.nodes.obstacle.rmp.alpha={alpha}"]
    run = compose_run(over)
    env, _, _ = build_all(run)
    tree = tree_of(run, env, weights)
    starts = [(START_X, y, v) for v in SPEEDS for y in OFFSETS]
    q0 = torch.tensor([[x, y] for x, y, _ in starts], dtype=torch.float64)
    qd0 = torch.tensor([[v, 0.0] for *_, v in starts], dtype=torch.float64)
    n = len(starts)
    aux = {
        "goal": torch.zeros(n, 2, dtype=torch.float64),
        "obstacle1_center": torch.tensor([DISC_CENTRE], dtype=torch.float64).expand(n, -1).clone(),
        "obstacle1_radius": torch.full((n, 1), DISC_RADIUS, dtype=torch.float64),
    }
    ro = env.rollout(tree, q0, qd0, aux, horizon=20.0, record_every=env.dt)
    clearance = (ro.q - torch.tensor(DISC_CENTRE, dtype=torch.float64)).norm(dim=-1) - DISC_RADIUS  # (T, B)
    least = clearance.min(0).values
    reached = ro.goal_distance[-1] <= 1e-3
    return {
        "rollouts": n,
        "entered": int((least < 0).sum()),
        "least_clearance_m": float(least.min()),
        "least_clearance_aimed_m": float(least[0]),
        "reached": int(reached.sum()),
        "alpha": float(tree.rmps["obstacle"].alpha),
    }


def arm_rollouts(alpha: float | None, joint_limits_too: bool, trajectories: int, weights: str) -> dict:
    """The Panda's numbers for the obstacle barriers' α (None: the shipped one), the joint-limit barriers' α set
    to 0 as well with ``joint_limits_too``, and the ``weights``."""
    over = ["experiment=franka", "logger=disabled", "env.mode=kinematic", "env.control_rate=250"]
    if alpha is not None:
        over.append(f"tree.obstacle_rmp.alpha={alpha}")
    if joint_limits_too:
        over.append("tree.joint_limit_rmp.alpha=0.0")
    run = compose_run(over)
    env, _, _ = build_all(run)
    tree = tree_of(run, env, weights)
    gen = torch.Generator().manual_seed(run.seed + SPLIT_SEED_OFFSET["val"])
    q0, qd0, aux = env.sample_initial_states(env.sample_envs(1, gen, split="val"), trajectories, gen)
    ro = env.rollout(tree, q0, qd0, aux, horizon=10.0, record_every=env.dt)
    T, B, dof = ro.q.shape
    rows = {k: v.repeat(T, 1) for k, v in aux.items()}
    spheres = sphere_clearance(env, ro.q.reshape(-1, dof), rows).reshape(T, B)
    least = torch.nan_to_num(spheres, nan=float("inf")).min(0).values
    out = {
        "rollouts": B,
        "entered": int((least < 0).sum()),
        "least_sphere_clearance_m": float(least.min()),
        "least_mesh_clearance_m": float(ro.min_clearance.min()),
        "collisions": int(ro.collided.sum()),
        "reached": int(ro.reached.sum()),
        "errors": sum(e is not None for e in ro.error),
    }
    env.close()
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--only", choices=["plane", "arm"], default=None)
    ap.add_argument("--trajectories", type=int, default=20, help="the Panda's starts (validation split)")
    ap.add_argument("--weights", nargs="+", choices=["unit", "expert"], default=["unit", "expert"])
    a = ap.parse_args(argv)
    torch.set_num_threads(1)
    for weights in a.weights:
        if a.only in (None, "plane"):
            for label, alpha in (("shipped alpha", None), ("alpha = 0", 0.0)):
                t0 = time.time()
                found = plane_rollouts(alpha, weights)
                print(f"plane, {weights} weights, {label}: {found} ({time.time() - t0:.0f} s)", flush=True)
        if a.only in (None, "arm"):
            variants = (
                ("shipped alphas", None, False),
                ("obstacle alpha = 0", 0.0, False),
                ("every alpha = 0", 0.0, True),
            )
            for label, alpha, limits in variants:
                t0 = time.time()
                found = arm_rollouts(alpha, limits, a.trajectories, weights)
                print(f"Panda, {weights} weights, {label}: {found} ({time.time() - t0:.0f} s)", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
