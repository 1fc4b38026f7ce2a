#!/usr/bin/env python
"""One controller, compiled once, in a world that changes while it runs: the Panda's expert tree (experiment=franka's
leaves and expert weights) built with obstacle sets of 4 spheres and 2 boxes and no fixed obstacle, reaching goals that move across the table while
spheres and a box appear in its way, one moves, and they vanish again (rmpfusion.scenes.World).

    python tools/world_demo.py                 # compiled (torch.compile), 6 s at 500 Hz, prints the report
    python tools/world_demo.py --eager --seconds 2
    python tools/world_demo.py --sim pybullet  # the arm and the obstacles in a simulator (or --sim mujoco)

Without ``--sim`` the arm is integrated in joint space (RK4 on the tree's q̈, the kinematic model), and the clearance
is the exact distance between the control spheres and the obstacles present. With ``--sim`` the Panda is simulated
(computed torque at every step, the simulator's own integrator) and every change of the world is mirrored into the
simulator (bodies appear, move and vanish there: ``rmpfusion.sims.obstacles_of_sets``); the clearance is then the
simulator's distance between the robot's collision geometry and the bodies present. Reported: the compiles counted by
torch's dynamo after the first call (0 means no change of the world compiled anything), the least clearance to the
obstacles present, the end effector's final distance to the goal, and V_r between changes of the world (Theorem 2
holds while the aux state is constant; at a change V_r may jump).
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import dataclass, field

import torch
from omegaconf import OmegaConf

from rmpfusion import build_tree
from rmpfusion.assembly.generated import expand_tree
from rmpfusion.assembly.weighting import plain_data, tree_with_weights, weights_by_name
from rmpfusion.envs.manipulator.worlds import TaskWorld
from rmpfusion.pipeline.compose import compose_config
from rmpfusion.pipeline.validate import resolve_and_validate
from rmpfusion.robots.robot import build_robot
from rmpfusion.scenes import ObstacleSet, SetsSource, World, set_dims, sets_read
from rmpfusion.scenes.sets import set_distances
from rmpfusion.sims import SimulatorParams, WorldSettings, obstacles_of_sets

SETS = [ObstacleSet(shape="sphere", n_max=4), ObstacleSet(shape="box", n_max=2)]
GOAL, GOAL_B = [0.45, 0.35, 0.35], [0.45, -0.35, 0.35]


def schedule(world: World) -> list[tuple[float, callable]]:
    """(time, change): the goal moves across the table and a sphere appears on the straight way there; a box
    appears beyond the new goal; the sphere rises out of the way and goes; the goal comes back while a second
    sphere appears beside the way back; the box goes. Every obstacle appears clear of the arm."""
    return [
        (1.0, lambda: world.set_goal(GOAL_B)),
        (1.2, lambda: world.add("sphere", name="ball", center=[0.45, 0.0, 0.35], radius=0.06)),
        (2.0, lambda: world.add("box", name="wall", center=[0.45, -0.56, 0.3], half_extents=[0.1, 0.04, 0.15])),
        (3.0, lambda: world.move("ball", center=[0.45, 0.0, 0.6])),
        (3.5, lambda: world.remove("ball")),
        (4.0, lambda: world.set_goal(GOAL)),
        (4.1, lambda: world.add("sphere", name="pebble", center=[0.6, 0.15, 0.35], radius=0.04)),
        (5.5, lambda: world.remove("wall")),
    ]


def controller(sets: list[ObstacleSet] = SETS):
    """The expert of experiment=franka (its weights by role) on the Panda's Fig. 1b tree generated with the obstacle
    ``sets`` and no fixed obstacle, and the robot. The environment does not yet provide the sets (their bodies in
    pybullet are future work), so the tree is built from the run's tree declaration here."""
    cfg = compose_config(["experiment=franka"])
    run = resolve_and_validate(cfg)
    decl = OmegaConf.to_container(cfg.tree, resolve=True)
    decl["scene"] = {"obstacles": []}  # every obstacle is the world's
    decl["obstacle_sets"] = [s.model_dump(exclude_none=True) for s in sets]
    spec = expand_tree(decl)
    expert = weights_by_name(spec, {k: plain_data(v) for k, v in run.expert.items()})
    read = sets_read(sets, len(run.env.robot.control_points))  # a per-control-point set once per control point
    tree = build_tree(tree_with_weights(spec, expert, where="expert"), aux_dims={"goal": 3, **set_dims(read)}).double()
    return tree, build_robot(run.env.robot), run


@dataclass
class Report:
    compiles_after_first_call: int | None
    min_clearance: float
    final_goal_distance: float
    vr_rises_between_changes: int
    changes: int
    seconds: float
    trace: list[tuple] = field(default_factory=list)  # every 0.25 s: t, clearance, goal distance, V_r


def clearance_to_world(robot, q: torch.Tensor, world: World) -> float:
    """Least distance between a control sphere's surface and an obstacle present (inf if none), by the maps the
    tree measures the sets' members with (``scenes.sets.set_distances``)."""
    centres = robot.sphere_centres(q)[0]
    radii = torch.tensor([cp.radius for cp in robot.params.control_points], dtype=q.dtype)
    d = set_distances(list(world.sets.values()), world.set_aux(), centres) - radii[:, None]
    return float(d.min()) if d.numel() else float("inf")


def run_demo(compiled: bool = True, seconds: float = 6.0, dt: float = 0.002, sim: str | None = None) -> Report:
    from torch._dynamo.utils import counters

    tree, robot, run = controller()
    tree.read_aux_through(SetsSource(SETS, len(run.env.robot.control_points)))  # it makes its per-member entries
    world = World(SETS, goal=GOAL)
    simulated = None if sim is None else TaskWorld(robot, WorldSettings(timestep=dt), SimulatorParams(type=sim))
    q = torch.tensor([list(run.env.robot.home)], dtype=torch.float64)
    qd = torch.zeros_like(q)
    if compiled:
        tree.compile()
    aux = world.set_aux  # the goal and each set's tensors and mask: a handful of inputs, whatever N_max

    def accel(x, xd):
        with torch.no_grad():
            return tree(x, xd, aux()).qdd

    t0 = time.time()
    accel(q, qd)  # the first call compiles
    counters.clear()
    graphs0 = counters["stats"]["unique_graphs"]
    events, k = schedule(world), 0
    V_prev, rises, clear_w, trace = None, 0, float("inf"), []
    steps = round(seconds / dt)
    if simulated is not None:
        simulated.reset(q[0].numpy(), qd[0].numpy())
        simulated.sim.set_obstacles(obstacles_of_sets(SETS, world.aux()))
    for i in range(steps):
        t = i * dt
        while k < len(events) and events[k][0] <= t + 1e-12:
            events[k][1]()
            k, V_prev = k + 1, None  # the world changed: V_r may jump here
            if simulated is not None:  # the same change in the simulator: bodies appear, move, vanish
                simulated.sim.set_obstacles(obstacles_of_sets(SETS, world.aux()))
        with torch.no_grad():
            V = float(tree(q, qd, aux()).V[0])
        if V_prev is not None and V > V_prev * (1 + 1e-6) + 1e-9:
            rises += 1
        V_prev = V
        if simulated is not None:  # computed torque in the simulator, its own integrator
            simulated.step_computed_torque(accel(q, qd)[0].numpy(), robot.params.held_joint_gains)
            qs, qds = simulated.sim.state()
            # (1, dof) with the strides of a new tensor: the compiled tree is guarded on them
            q = torch.tensor(qs[: robot.dof], dtype=q.dtype).unsqueeze(0)
            qd = torch.tensor(qds[: robot.dof], dtype=q.dtype).unsqueeze(0)
            cw = simulated.sim.obstacle_distance(0.5) if world.present() else float("inf")
        else:
            k1v, k1a = qd, accel(q, qd)
            k2v, k2a = qd + 0.5 * dt * k1a, accel(q + 0.5 * dt * k1v, qd + 0.5 * dt * k1a)
            k3v, k3a = qd + 0.5 * dt * k2a, accel(q + 0.5 * dt * k2v, qd + 0.5 * dt * k2a)
            k4v, k4a = qd + dt * k3a, accel(q + dt * k3v, qd + dt * k3a)
            q = q + dt / 6 * (k1v + 2 * k2v + 2 * k3v + k4v)
            qd = qd + dt / 6 * (k1a + 2 * k2a + 2 * k3a + k4a)
            cw = clearance_to_world(robot, q, world)
        clear_w = min(clear_w, cw)
        if i % round(0.25 / dt) == 0:
            trace.append((round(t, 3), cw, float((tip_of(robot, run, q) - world.goal[0]).norm()), V))
    compiles = counters["stats"]["unique_graphs"] - graphs0 if compiled else None
    if simulated is not None:
        simulated.close()
    return Report(
        compiles, clear_w, float((tip_of(robot, run, q) - world.goal[0]).norm()), rises, k, time.time() - t0, trace
    )


def tip_of(robot, run, q: torch.Tensor) -> torch.Tensor:
    """The end effector's position (3,) at the configuration q (1, d)."""
    link = run.env.robot.end_effector
    R, p = robot.chain.forward_kinematics(q, [link.link])[link.link]
    return p[0] + R[0] @ torch.tensor(link.offset, dtype=q.dtype)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--eager", action="store_true", help="no torch.compile")
    ap.add_argument("--seconds", type=float, default=6.0)
    ap.add_argument("--dt", type=float, default=0.002)
    ap.add_argument("--trace", action="store_true", help="print the state every 0.25 s")
    ap.add_argument("--sim", choices=["pybullet", "mujoco"], default=None, help="simulate the arm and the obstacles")
    args = ap.parse_args(argv)
    r = run_demo(not args.eager, args.seconds, args.dt, args.sim)
    print(
        f"changes of the world: {r.changes}; compiles after the first call: "
        f"{'n/a (eager)' if r.compiles_after_first_call is None else r.compiles_after_first_call}"
    )
    print(
        f"least clearance to the obstacles present: {r.min_clearance * 100:.1f} cm; end effector to goal at "
        f"{args.seconds:g} s: {r.final_goal_distance * 1000:.1f} mm"
    )
    print(f"V_r rises between changes: {r.vr_rises_between_changes}; wall time {r.seconds:.1f} s")
    if args.trace:
        for t, cw, g, V in r.trace:
            print(f"  t={t:5.2f}  clearance {cw * 100:6.1f} cm  goal {g * 1000:6.1f} mm  V_r {V:.4g}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
