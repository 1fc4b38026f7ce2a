#!/usr/bin/env python
"""A learner trained with one cylinder, run through a depth camera among three obstacles, beside the same learner
given the obstacles exactly.

    python tools/camera_run.py outputs/franka/<time>/checkpoints/rmp/final.pt
    python tools/camera_run.py CHECKPOINT --sim mujoco --starts 20 --horizon 10 --json camera.json

The checkpoint is a learner of experiment=franka (one cylinder in training). Its shared weights are copied by role
(``copy_weights``) into two trees of the Panda's Fig. 1b generator on experiment=franka_three_obstacles' scene (a
cylinder, a moving sphere, a turned box; the test split's placement):

- **exact**: one node per (control point, obstacle), fed each obstacle's geometry from the scene's aux state;
- **camera**: the same tree with its obstacle edges given way to a sphere obstacle set (``learner_over_sets``): no
  obstacle known in advance; ``--n-max`` members, filled
  from the environment's depth camera (``env.depth_camera``: 160×120, 30 Hz unless overridden) by
  ``scenes/clouds.py``: the cloud binned in ``--voxel`` cubes, one member per occupied cube at its points' centroid
  with radius √3/2·voxel, the cubes nearest to the control spheres kept. Between frames the members are fixed; at a
  frame they switch, where V_r may jump (docs/math.md §13). With ``--velocities`` the set is a moving one and each
  member gets its displacement from the nearest member of the previous frame over the frames' interval
  (``member_velocities``), so the obstacle leaves see the moving sphere move.

Both run in torque mode in the simulator (computed torque at env.control_rate) from the same starts and goals,
drawn from the three-obstacle experiment's test split (seed ``--seed``). Printed per policy: reached, collided,
minimum clearance to the true obstacles (the simulator's distance), final goal distance, and V_r rises between
changes of the tree's aux, in all and before each rollout's first contact (a contact's force acts from outside the
closed loop that Theorem 2 speaks of): for the camera policy between frames (its aux holds still between them, whatever moves
in the world), for the exact policy nowhere while the sphere moves (its aux changes at every step).

``--policy learner-0`` runs the checkpoint's learner at its random initialisation (training snapshot 0) and
``--policy unit`` its tree with every weight 1 (RMPflow) instead, both ways.

``--json FILE`` also writes the numbers with the command, the seed and the wall time (what results/ stores);
``rmpfusion.studies.tables.camera`` turns such files back into the documentation's table (rmpfusion-study table world).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np
import torch

from rmpfusion.envs.manipulator_tree import copy_weights
from rmpfusion.files import atomic_write_json
from rmpfusion.learn.checkpoints import load_checkpoint
from rmpfusion.learn.loop import load_snapshot
from rmpfusion.pipeline.collect import SPLIT_SEED_OFFSET
from rmpfusion.pipeline.compose import compose_run
from rmpfusion.pipeline.config import upgrade_run_config
from rmpfusion.pipeline.construct import UNIT_WEIGHT_LEARNER, build_learners, learner_over_sets, make_env
from rmpfusion.pipeline.validate import parse_run_config
from rmpfusion.scenes import ObstacleSet, sets_read, with_slots
from rmpfusion.scenes.clouds import cloud_members, member_velocities, nearest_per_point, per_point_aux

MAX_SPEED = 2.0  # m/s: a member farther than this from every member of the previous frame came into view, not moved


def trained_learner(checkpoint: Path, snapshot: int | None = None):
    """The learner in ``checkpoint`` (its run's config and weights; with ``snapshot``, that training snapshot's
    weights, read from the last ``ckpt-*.pt`` beside it: 0 is the learner at its random initialisation) and that run
    config."""
    state = load_checkpoint(checkpoint)
    run = parse_run_config(upgrade_run_config(state["config"]))
    name = checkpoint.parent.name
    env = make_env(run)
    learner = build_learners(run, env.aux_dims())[name]
    if snapshot is None:
        learner.load_state_dict(state["model"])
    else:
        last = max(checkpoint.parent.glob("ckpt-*.pt"), default=None)
        snapshots = {} if last is None else load_checkpoint(last).get("snapshots", {})
        if snapshot not in snapshots:
            raise SystemExit(f"camera_run: no snapshot {snapshot} beside {checkpoint} (found: {sorted(snapshots)})")
        learner = load_snapshot(learner, snapshots[snapshot])
    env.close()
    return learner.double(), run, name


def unit_weight_run(run, name: str):
    """``run`` with learner ``name``'s weights all the constant 1: RMPflow's combination of the same leaves."""
    learners = {**run.learners, name: type(run.learners[name]).model_validate(UNIT_WEIGHT_LEARNER)}
    return run.model_copy(update={"learners": learners})


def three_obstacle_run(overrides: list[str]):
    return compose_run(["experiment=franka_three_obstacles", *overrides])


class CameraFed:
    """A tree policy whose sphere set is filled from the environment's depth camera every ``period`` calls (one call
    per integration step in torque mode); each sample sees its own world, its frame ``latency`` steps old. The cloud
    becomes members by voxel binning (one shared set, ``radius`` = √3/2·voxel) or, for a per-control-point set, by
    each control point's k nearest points (``radius`` given)."""

    def __init__(
        self, learner, env, robot, obstacle_set: ObstacleSet, voxel: float, radius: float, period: int, latency: int
    ):
        self.learner, self.env, self.robot, self.set = learner, env, robot, obstacle_set
        self.voxel, self.radius, self.period, self.latency = voxel, radius, period, latency
        self.read = sets_read([obstacle_set], len(robot.params.control_points))
        self.calls, self.frames, self.members = 0, [], []
        self.rng = np.random.default_rng(env.params.depth_camera.seed)
        self.current: dict[str, torch.Tensor] | None = None
        self.pending: list[tuple[int, dict[str, torch.Tensor]]] = []  # (step it arrives at, frame's set aux)
        self.previous: dict[int, tuple[torch.Tensor, torch.Tensor]] = {}  # sample -> its last frame's members, mask

    def _sense(self, q: torch.Tensor, aux) -> dict[str, torch.Tensor]:
        samples = []
        for b in range(q.shape[0]):
            points = self.env.point_cloud(q[b], aux, sample=b, rng=self.rng)
            near = self.robot.sphere_centres(q[b : b + 1])[0]
            if self.set.per_control_point:
                members, mask = nearest_per_point(points, near, self.set.n_max)
                samples.append(per_point_aux(self.set, members, mask, self.radius))
            else:
                c, m = cloud_members(points, self.voxel, self.set.n_max, near=near)
                p, r = self.set.prefix, self.radius
                samples.append(
                    {f"{p}_center": c[None], f"{p}_radius": torch.full_like(c[None, :, :1], r), f"{p}_mask": m[None]}
                )
                if self.set.moving:
                    samples[-1][f"{p}_velocity"] = self._velocities(b, c, m)[None]
            self.members.append(int(sum(v.sum() for k, v in samples[-1].items() if k.endswith("_mask"))))
        return {k: torch.cat([s[k] for s in samples]) for k in samples[0]}

    def _velocities(self, sample: int, centres: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        """The members' velocities from ``sample``'s previous frame (at rest in the first)."""
        previous = self.previous.get(sample)
        self.previous[sample] = (centres, mask)
        if previous is None:
            return torch.zeros_like(centres)
        interval = self.period * self.env.dt
        return member_velocities(centres, mask, previous[0], previous[1], interval, MAX_SPEED)

    def __call__(self, q, qd, aux):
        if self.calls % self.period == 0:
            self.frames.append(self.calls)
            self.pending.append((self.calls + self.latency, self._sense(q, aux)))
        while self.pending and self.pending[0][0] <= self.calls:
            self.current = self.pending.pop(0)[1]
        self.calls += 1
        assert self.current is not None, "the first frame arrives before the first step (latency 0)"
        return self.learner.policy(q, qd, with_slots(self.read, {"goal": aux["goal"], **self.current}))


def rises_between_changes(
    V: torch.Tensor, changed: np.ndarray, free: torch.Tensor | None = None, rtol: float = 1e-6, atol: float = 1e-9
) -> tuple[int, float]:
    """(records where V_r rose from the previous record although the tree's aux did not change between them, the
    largest such rise relative to V_r); with ``free`` (T, B), only where both records are free of contact (a
    contact's force is outside the closed loop Theorem 2 speaks of)."""
    steady = torch.as_tensor(~changed[1:, None])
    if free is not None:
        steady = steady & free[1:] & free[:-1]
    rise = (V[1:] > V[:-1] * (1 + rtol) + atol) & steady
    relative = torch.where(steady, (V[1:] - V[:-1]) / V[:-1].abs().clamp(min=1e-12), torch.zeros_like(V[1:]))
    return int(rise.sum()), float(relative.max().clamp(min=0.0))


def report(env, ro) -> dict:
    m = env.task_metrics(ro)
    return {
        "reached": int(ro.reached.sum()),
        "collided": int(ro.collided.sum()),
        "n": int(ro.reached.numel()),
        "min_clearance_m": float(ro.min_clearance.min()),
        "final_goal_distance_m": float(m["timeout_goal_distance"].mean()),
        "errors": sum(e is not None for e in ro.error),
    }


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("checkpoint", type=Path)
    ap.add_argument("--sim", default="pybullet")
    ap.add_argument("--starts", type=int, default=20)
    ap.add_argument("--horizon", type=float, default=10.0)
    ap.add_argument(
        "--reduction",
        choices=["voxel", "nearest"],
        default="voxel",
        help="voxel: one set of --n-max binned members; nearest: each control point's --k nearest points",
    )
    ap.add_argument("--n-max", type=int, default=48, help="voxel: members of the shared set (N_max)")
    ap.add_argument("--voxel", type=float, default=0.04, help="voxel: cube side of the cloud's binning (m)")
    ap.add_argument("--k", type=int, default=8, help="nearest: points per control point")
    ap.add_argument("--point-radius", type=float, default=0.02, help="nearest: the radius each point gets (m)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--camera-only", action="store_true", help="skip the exact policy (the same for every reduction)")
    ap.add_argument(
        "--velocities",
        action="store_true",
        help="voxel: the members move, with velocities from successive frames (member_velocities)",
    )
    ap.add_argument(
        "--policy",
        choices=["trained", "learner-0", "unit"],
        default="trained",
        help="the checkpoint's learner; its random initialisation (snapshot 0); or its tree with every weight 1 (RMPflow)",
    )
    ap.add_argument("overrides", nargs="*", help="Hydra overrides of experiment=franka_three_obstacles")
    return ap


def _policies(a: argparse.Namespace):
    """(env, exact learner, camera-fed tree, how many weights were copied) for the run's settings."""
    learner, _, name = trained_learner(a.checkpoint, 0 if a.policy == "learner-0" else None)
    run3 = three_obstacle_run([f"sim={a.sim}", *a.overrides])
    env = make_env(run3)
    if a.policy == "unit":
        run3 = unit_weight_run(run3, name)
        learner = build_learners(run3, env.aux_dims())[name].double()
    exact = build_learners(run3, env.aux_dims())[name]
    copied = copy_weights(learner.tree, exact.tree)
    if a.reduction == "voxel":
        voxel_set = ObstacleSet(shape="sphere", n_max=a.n_max, name="points", moving=a.velocities)
        sets, radius = [voxel_set], math.sqrt(3) / 2 * a.voxel
    else:
        sets, radius = [ObstacleSet(shape="sphere", n_max=a.k, name="points", per_control_point=True)], a.point_radius
    cam, _ = learner_over_sets(run3, name, learner, sets)  # the exact tree's obstacle edges, given sets
    camera = env.params.depth_camera
    period = max(1, round(1.0 / (camera.rate * env.dt)))
    fed = CameraFed(cam, env, env.robot, sets[0], a.voxel, radius, period, round(camera.latency / env.dt))
    return env, exact, fed, copied, period


def _evaluate(env, label: str, policy, fed, starts, a: argparse.Namespace, record: float = 0.01) -> dict:
    """One policy's rollouts from ``starts`` and where V_r rose between changes of its aux."""
    q0, qd0, aux = starts
    n_records = round(a.horizon / record) + 1
    step_of_record = np.arange(n_records) * round(record / env.dt)
    # the moving sphere moves at every step: V_r is held to Theorem 2 only where nothing moves
    changed = np.full(n_records, bool(env.moving))
    t0 = time.time()
    with torch.no_grad():
        ro = env.rollout(policy, q0, qd0, aux, horizon=a.horizon, record_every=record, mode="torque")
    if label == "camera":  # the camera tree's aux changes only at a frame: the moving sphere moves in the frames
        frames = np.array(fed.frames + [10**12])
        changed = np.searchsorted(frames, step_of_record, side="right") != np.searchsorted(
            frames, np.r_[-1, step_of_record[:-1]], side="right"
        )
    rises, worst = rises_between_changes(ro.V, changed) if ro.V is not None else (None, None)
    free = ro.times[:, None] < ro.first_collision_time[None, :]  # before the sample's first contact
    rises_free, worst_free = rises_between_changes(ro.V, changed, free) if ro.V is not None else (None, None)
    out = report(env, ro) | {
        "vr_rises_between_changes": rises,
        "vr_max_relative_rise": worst,
        "vr_rises_before_contact": rises_free,
        "vr_max_relative_rise_before_contact": worst_free,
        "records_checked": int((~changed[1:]).sum()) * ro.V.shape[1] if ro.V is not None else 0,
        "seconds": round(time.time() - t0, 1),
    }
    if label == "camera":
        out["members_per_frame"] = float(np.mean(fed.members)) if fed.members else 0.0
    return out


def main(argv=None) -> int:
    ap = _parser()
    a = ap.parse_args(argv)
    if a.velocities and a.reduction != "voxel":
        ap.error("--velocities needs --reduction voxel (a per-control-point set's members have no velocities)")
    started = time.time()
    torch.set_num_threads(1)
    env, exact, fed, copied, period = _policies(a)
    g = torch.Generator().manual_seed(a.seed + SPLIT_SEED_OFFSET["test"])
    q0, qd0, aux = env.sample_initial_states(env.sample_envs(1, g, split="test"), a.starts, g)
    out = {
        "command": "python tools/camera_run.py CHECKPOINT " + " ".join(argv if argv is not None else sys.argv[2:]),
        "seed": a.seed,
        "copied_weights": copied,
        "camera_hz": 1.0 / (period * env.dt),
        "settings": {k: str(v) if isinstance(v, Path) else v for k, v in vars(a).items()},
    }
    policies = (("exact", exact.policy), ("camera", fed))
    for label, policy in policies[1:] if a.camera_only else policies:
        out[label] = _evaluate(env, label, policy, fed, (q0, qd0, aux), a)
        print(label, json.dumps(out[label]), flush=True)
    env.close()
    out["timing"] = {"total_s": round(time.time() - started, 1)}
    if a.json is not None:
        atomic_write_json(a.json, out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
