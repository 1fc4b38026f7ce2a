"""What the evaluate and report stages add on recorded demonstrations (``data.source: recorded``), which go
through the same stages as the expert's: the collect stage reads and splits them by demonstration
(``collect.recorded_splits``), the fit stage trains on them, and the evaluation measures each policy against the
held-out demonstrations.

There is no expert. The reference beside the learners is the tree as configured with every weight 1 (``tree``):
what the structure alone does before anything is learned. Each policy is measured the way the LASA literature
measures learned dynamical systems (Khansari-Zadeh & Billard 2011; Rana et al. 2020):

* reproduction, from each held-out demonstration's first state (its position and velocity): DTW distance per
  sample and swept error area over the demonstration's duration, the distance to the goal after
  ``horizon_factor`` durations, and the time to come within ``tolerance``;
* convergence, from ``starts`` states at rest on a regular grid over the demonstrations' bounding box enlarged by
  ``enlarge``, over ``horizon_factor`` times the longest demonstration: the fraction within ``tolerance`` of the
  goal at the end, V_r non-increasing (Theorem 2), and where the others stopped nearly at rest; then the same starts
  go on to ``convergence_horizon_factor`` times the longest demonstration, where each is told converged, at rest
  away from the goal (where, how far) or still moving, with the time each took to come within ``tolerance``
  (``convergence.at_long_horizon``, ``evaluate/convergence.py``);
* whether the goal is the tree's only equilibrium for any parameters: the premises of docs/math.md §12 read off the
  tree (``premises``, ``assembly/premises.py``);
* the trained tree's certificate (Theorem 2's premises and energy identity) at every record of those rollouts.
"""

from __future__ import annotations

import copy
import dataclasses
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from ..assembly.premises import check_premises
from ..core.tree import RMPTree
from ..envs.protocol import JointSpace, LearnsFromRecordings
from ..envs.rollout import Rollout
from ..evaluate.convergence import convergence_outcomes, outcomes_line
from ..evaluate.lyapunov import lyapunov_monotone
from ..evaluate.reproduction import dtw_distance, overshoot, swept_error_area
from ..evaluate.rest_forces import rest_forces
from ..files import atomic_write_json
from ..plots.recorded import View, recorded_figures
from ..recordings.signals import States
from .certificates import certificate
from .collect import Splits, recorded_splits, recording_env  # noqa: F401  (recorded_splits: where tools and tests find it)
from .experiment import COMPILE_FROM_ROW_STEPS, COMPILING, Experiment, clean, compiles
from .fit import Fitted

#: the reference policy's name: the configured tree with every weight 1, nothing learned
TREE = "tree"


# ------------------------------------------------------------------ evaluation
#: configurations (..., d) -> task-space points (..., k)
ToTask = Callable[[np.ndarray], np.ndarray]


def _end_effector(env: Any) -> ToTask | None:
    """An arm's configurations as end-effector points (m), where reproduction is also measured; None for an
    environment whose configuration is the task space."""
    if not isinstance(env, JointSpace):
        return None

    def to_task(q: np.ndarray) -> np.ndarray:
        flat = torch.as_tensor(np.asarray(q), dtype=torch.float64).reshape(-1, q.shape[-1])
        return env.ee_position(flat).detach().numpy().reshape(*q.shape[:-1], 3)

    return to_task


def _as_tensor(x: np.ndarray) -> torch.Tensor:
    return torch.as_tensor(np.asarray(x), dtype=torch.float64)


def start_box(demos: list[States], enlarge: float) -> tuple[np.ndarray, np.ndarray]:
    """The demonstrations' bounding box, each side ``enlarge`` times longer (about its centre)."""
    q = np.concatenate([s.q for s in demos])
    lo, hi = q.min(0), q.max(0)
    pad = 0.5 * enlarge * (hi - lo)
    return lo - pad, hi + pad


#: up to this dimension the starts lie on a grid; above it (an arm's joints: 2 per side of 7 would be the box's
#: 128 corners) they are drawn uniformly in the box
GRID_DIMENSIONS = 3
#: rounds of drawing ``data.starts`` candidates before the convergence check goes with the starts it has
START_ROUNDS = 20


def grid_starts(demos: list[States], d) -> np.ndarray:
    """``data.starts`` positions at rest on a regular grid over the enlarged box (as many per side as the
    starts' root allows, rounded down; every dimension the same count)."""
    lo, hi = start_box(demos, d.enlarge)
    per_side = max(2, int(np.floor(d.starts ** (1.0 / len(lo)) + 1e-9)))
    axes = [np.linspace(lo[k], hi[k], per_side) for k in range(len(lo))]
    return np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, len(lo))


def convergence_starts(env: LearnsFromRecordings, demos: list[States], d, seed: int) -> np.ndarray:
    """The starts at rest of the convergence check: the grid (up to ``GRID_DIMENSIONS``) or ``data.starts``
    uniform draws in the enlarged box (seeded by the run's seed), keeping only those the environment accepts (an
    arm: inside its limits, clear of the obstacles and the ground); an arm's box past its limits or in the table
    yields fewer, which the metrics report as the number of starts."""
    lo, hi = start_box(demos, d.enlarge)
    if len(lo) <= GRID_DIMENSIONS:
        grid = grid_starts(demos, d)
        return grid[env.recorded_starts(_as_tensor(grid)).numpy()]
    rng = np.random.default_rng(seed)
    kept: list[np.ndarray] = []
    for _ in range(START_ROUNDS):
        draw = rng.uniform(lo, hi, size=(d.starts, len(lo)))
        kept += list(draw[env.recorded_starts(_as_tensor(draw)).numpy()])
        if len(kept) >= d.starts:
            break
    return np.array(kept[: d.starts]).reshape(-1, len(lo))


@dataclass
class Batch:
    """Every rollout a policy is judged on, as one batch: each held-out demonstration from its first state
    (``demos``: split -> indices into the batch), then the grid of starts at rest (``grid``)."""

    q0: torch.Tensor
    qd0: torch.Tensor
    aux: dict[str, torch.Tensor]
    demos: dict[str, list[States]]
    index: dict[str, slice]
    grid: slice
    horizon: float
    #: aux the policy is not told (``data.aux_to_policy=false``): name -> the scene's value (k,) it reads instead,
    #: the same for every row; ``aux`` keeps where the obstacles stood, which collisions are counted against
    hidden: dict[str, torch.Tensor] = dataclasses.field(default_factory=dict)
    #: how long the starts at rest go on (``data.convergence_horizon_factor``), at least ``horizon``
    long_horizon: float | None = None

    def policy_aux(self) -> dict[str, torch.Tensor]:
        """The aux state the policy reads: ``aux`` with the hidden entries at the scene's values."""
        return with_scene_values(self.aux, self.hidden)


def with_scene_values(aux: Mapping[str, torch.Tensor], hidden: Mapping[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """``aux`` (rows of any count) with each ``hidden`` entry at its one scene value (k,) in every row."""
    return {**aux, **{k: v.to(aux[k]).expand(aux[k].shape) for k, v in hidden.items()}}


def told_only_the_scene(policy: Callable, hidden: Mapping[str, torch.Tensor]) -> Callable:
    """``policy`` reading the scene's value of each ``hidden`` aux entry whatever the world's (row-independent, so
    it holds for a rollout's batch and for the single rows fault isolation evaluates)."""
    if not hidden:
        return policy
    return lambda q, qd, aux: policy(q, qd, with_scene_values(aux, hidden))


def evaluation_batch(exp: Experiment, demos: dict[str, list[States]], every_demo: list[States]) -> Batch:
    d, dt = exp.recorded_data, exp.env.dt
    held: dict[str, list[States]] = {k: demos[k] for k in ("test", "val") if k in demos}
    q0 = [s.q[0] for v in held.values() for s in v]
    qd0 = [s.qd[0] for v in held.values() for s in v]
    goals = [s.goal for v in held.values() for s in v]
    index: dict[str, slice] = {}
    at = 0
    for k, v in held.items():
        index[k], at = slice(at, at + len(v)), at + len(v)
    env = recording_env(exp)
    grid = convergence_starts(env, every_demo, d, exp.run.seed)
    goal = np.mean([s.goal for s in every_demo], axis=0)
    q0 += list(grid)
    qd0 += [np.zeros_like(goal)] * len(grid)
    goals += [goal] * len(grid)
    longest = max(float(s.t[-1]) for s in every_demo)
    horizon = dt * int(np.ceil(d.horizon_factor * longest / dt - 1e-9))
    long_horizon = max(horizon, dt * int(np.ceil(d.convergence_horizon_factor * longest / dt - 1e-9)))
    aux = {k: v.clone() for k, v in env.recorded_aux(_as_tensor(np.stack(goals))).items()}  # written into below
    held_states = [s for v in held.values() for s in v]
    from_files = sorted({name for s in every_demo for name in s.aux})
    hidden = {} if d.aux_to_policy else {name: aux[name][0].clone() for name in from_files}  # the scene's values
    for n, s in enumerate(held_states):  # a demonstration's own aux state (its obstacle, its goal) where it has one
        for name, value in s.aux.items():
            aux[name][n] = _as_tensor(value)
    return Batch(
        _as_tensor(np.stack(q0)),
        _as_tensor(np.stack(qd0)),
        aux,
        held,
        index,
        slice(at, at + len(grid)),
        horizon,
        hidden,
        long_horizon,
    )


def _goal_distance(demo: States, to_task: ToTask | None) -> np.ndarray:
    """(T,) a demonstration's distance to its goal, measured where the rollouts' is (an arm: its end effector)."""
    if to_task is None:
        return np.linalg.norm(demo.q - demo.goal, axis=-1)
    return np.linalg.norm(to_task(demo.q) - to_task(demo.goal[None]), axis=-1)


def reproduction(batch: Batch, ro, split: str, tolerance: float, to_task: ToTask | None = None) -> dict:
    """DTW per sample and swept error area over each demonstration's duration, the distance to the goal at the
    horizon, the time to within ``tolerance``, how far the rollout swings back out after having been closer to the goal
    (``overshoot``, beside the demonstrations' own largest): the mean over the split's demonstrations and each one's
    own. With
    ``to_task`` (an arm: configurations -> end-effector points), also the DTW of the end-effector paths (m) beside
    the joint-space one (rad)."""
    path, dist = ro.q.numpy(), ro.goal_distance.numpy()
    per: list[dict[str, Any]] = []
    for n, demo in zip(range(batch.index[split].start, batch.index[split].stop), batch.demos[split]):
        T = len(demo.t)
        within = np.flatnonzero(dist[:, n] <= tolerance)
        per.append(
            {
                "demonstration": demo.source,
                "dtw": dtw_distance(path[:T, n], demo.q),
                "swept_error_area": swept_error_area(path[:T, n], demo.q),
                "final_distance": float(dist[-1, n]),
                "time_to_tolerance": float(ro.times[within[0]]) if within.size else float("inf"),
                "overshoot": overshoot(dist[:, n]),
                "demonstration_overshoot": overshoot(_goal_distance(demo, to_task)),
                **({"ee_dtw": dtw_distance(to_task(path[:T, n]), to_task(demo.q))} if to_task else {}),
            }
        )
    keys = ("dtw", "swept_error_area", "final_distance", "overshoot", *(("ee_dtw",) if to_task else ()))
    mean = {k: float(np.mean([p[k] for p in per])) for k in keys}
    reached = [p["time_to_tolerance"] for p in per if np.isfinite(p["time_to_tolerance"])]
    rows = batch.index[split]
    return {
        **mean,
        "collisions": int(ro.collided[rows].sum()),
        "reached": len(reached) / len(per),
        "time_to_tolerance": float(np.mean(reached)) if reached else None,
        "demonstration_overshoot": max(p["demonstration_overshoot"] for p in per),
        "per_demonstration": per,
    }


def convergence(batch: Batch, ro, d, rtol: float, atol: float, dt: float, tree: RMPTree | None = None) -> dict:
    """From the grid of starts at rest: the fraction within ``tolerance`` of the goal at the horizon, V_r
    non-increasing, and where the others stopped (nearly at rest away from the goal: a spurious equilibrium, or, for a
    tree whose map is a diffeomorphism onto ℝⁿ and so has none, a region the map makes extremely slow); for a tree,
    which of its leaves hold it there (``held_by``)."""
    g = batch.grid
    final = ro.goal_distance[-1, g]
    ok = final <= d.tolerance
    stalled = (~ok & (ro.qd[-1, g].norm(dim=-1) < 1e-3 * d.tolerance / dt)).nonzero().flatten()
    V = ro.V[:, g] if ro.V is not None else None
    out = {
        "starts": int(final.numel()),
        "horizon_s": batch.horizon,
        "converged": float(ok.double().mean()),
        "final_distance_max": float(final.max()),
        "final_distance_median": float(final.median()),
        "stalled": [ro.q[-1, g][int(b)].tolist() for b in stalled[:10]],
        "stalled_count": int(stalled.numel()),
        "collisions": int(ro.collided[g].sum()),
    }
    if V is not None:
        out["lyapunov_monotone_fraction"] = float(lyapunov_monotone(V, rtol=rtol, atol=atol).double().mean())
    if tree is not None and stalled.numel():
        rows = g.start + stalled[:STALLED_EXAMINED]  # the batch's rows of the first stalled rollouts
        out.update(held_by(tree, ro.q[-1, rows], batch, rows))
    return out


#: about this many records of the starts at rest past the reproduction's horizon (the distance to the goal, for the
#: time each start first comes within the tolerance and the rate it changes at the end)
LONG_RECORDS = 2000


def long_horizon_outcomes(exp: Experiment, policy: Callable, batch: Batch, ro: Rollout, label: str) -> dict:
    """The starts at rest continued from where ``ro`` left them to ``batch.long_horizon``, then each told converged,
    at rest away from the goal or still moving there (``evaluate/convergence.py``). The whole batch goes on (the
    held-out demonstrations' rows too, whose continuation is not read), so a compiled policy meets the batch size it
    was compiled for instead of compiling again; the continuation is the convergence check's own progress stage."""
    d, g, dt = exp.recorded_data, batch.grid, exp.env.dt
    assert ro.goal_distance is not None, "an environment for recorded demonstrations measures the distance to the goal"
    times, dist, q_end = ro.times, ro.goal_distance[:, g], ro.q[-1, g]
    steps = round(((batch.long_horizon or batch.horizon) - batch.horizon) / dt)
    if steps > 0 and g.stop > g.start:
        every = max(1, steps // LONG_RECORDS)
        steps = every * -(-steps // every)  # the last record at the horizon's end
        check = f"convergence check, from rest to {batch.horizon + steps * dt:.4g} s"
        more = exp.env.rollout(
            told_only_the_scene(policy, batch.hidden),
            ro.q[-1],
            ro.qd[-1],
            batch.aux,
            steps * dt,
            every * dt,
            progress=exp.say.bar(f"rollout {label}").stage(check),
        )
        times = torch.cat([times, times[-1] + more.times[1:].to(times)])
        assert more.goal_distance is not None
        dist = torch.cat([dist, more.goal_distance[1:, g].to(dist)])
        q_end = more.q[-1, g]
    return convergence_outcomes(times, q_end, dist, d.tolerance, d.at_rest_rate)


#: the stalled rollouts whose rest forces are examined (the first ones; a spurious equilibrium is usually shared)
STALLED_EXAMINED = 10


def held_by(tree: RMPTree, q: torch.Tensor, batch: Batch, rows: torch.Tensor) -> dict:
    """The leaves whose forces balance where rollouts stopped (median size over the stalled states, strongest
    first), the part of each its weights' gradient makes (−Φ∇W, docs/math.md §12 premise 3), and how much of the
    root force at rest their sum leaves unexplained (~0 for a tree of GDS leaves)."""
    aux = {k: v[rows].to(tree.device) for k, v in batch.policy_aux().items()}
    forces = rest_forces(tree, q.to(tree.device), aux)
    strongest = dict(forces.strongest())
    return {
        "held_by": strongest,
        "held_by_weight_gradient": {n: float(forces.weight_gradient[n].norm(dim=-1).median()) for n in strongest},
        "held_by_unexplained": float(forces.residual.norm(dim=-1).max()),
    }


def evaluate_policy(
    exp: Experiment, label: str, policy: Callable, batch: Batch, tree: RMPTree | None = None, long: bool = True
) -> tuple[dict, Rollout]:
    """One policy on the evaluation batch: reproduction of the held-out demonstrations, convergence from the grid
    (with ``tree``, the policy's tree: which leaves hold the rollouts that stop short); with ``long``, the starts at
    rest go on to the long horizon (``convergence.at_long_horizon``)."""
    d, ev = exp.recorded_data, exp.run.eval
    ro = exp.env.rollout(
        told_only_the_scene(policy, batch.hidden),
        batch.q0,
        batch.qd0,
        batch.aux,
        batch.horizon,
        exp.env.dt,
        progress=exp.say.bar(f"rollout {label}"),
    )
    to_task = _end_effector(exp.env)
    out = {f"reproduction_{k}": reproduction(batch, ro, k, d.tolerance, to_task) for k in batch.index}
    out["convergence"] = conv = convergence(batch, ro, d, ev.lyapunov_rtol, ev.lyapunov_atol, exp.env.dt, tree)
    if long:
        conv["at_long_horizon"] = long_horizon_outcomes(exp, policy, batch, ro, label)
        exp.say.say(f"{label}: {outcomes_line(conv['at_long_horizon'], d.tolerance)} (convergence.at_long_horizon)")
    rep = out["reproduction_test"]
    monotone = conv.get("lyapunov_monotone_fraction")
    unit, area = ("rad", "rad²") if to_task else ("m", "m²")
    ee = f" (end effector {rep['ee_dtw']:.4g} m)" if to_task else ""
    exp.say.say(
        f"{label}: test DTW {rep['dtw']:.4g} {unit}{ee}, swept area {rep['swept_error_area']:.4g} {area}, final "
        f"{rep['final_distance']:.2e} m, {rep['collisions']} collision(s); converged {conv['converged']:.0%} of {conv['starts']} starts"
        + (f", V_r monotone {monotone:.0%}" if monotone is not None else " (no V_r: not a tree)")
    )
    if monotone is not None and monotone < 1.0:
        exp.say.say(
            f"WARNING: {label}: V_r rose on {1 - monotone:.0%} of the rollouts from rest, which Theorem 2 forbids "
            f"for a tree in continuous time: either the integrator's step (env.dt = {exp.env.dt:g} s) is too "
            "coarse for this policy there, or a term of the tree is wrong (the certificate checks the identity at "
            "each record). Integration error shrinks with the step, a wrong term does not: python "
            "tools/recorded_step_check.py <run dir> re-evaluates this learner on finer steps without training "
            "again (metrics.json: convergence.lyapunov_monotone_fraction)"
        )
    if conv["stalled_count"]:
        held = conv.get("held_by")
        exp.say.say(
            f"{label}: {conv['stalled_count']} start(s) nearly at rest away from the goal at {batch.horizon:.4g} s (a "
            f"spurious equilibrium, or a region the policy makes extremely slow), e.g. at {conv['stalled'][0]}"
            + (
                "; held there by the forces of "
                + ", ".join(f"{n} ({f:.3g})" for n, f in held.items())
                + " (metrics.json: convergence.held_by)"
                if held
                else ""
            )
        )
    return out, ro


#: at most about this many states are certified: every record up to it, else every n-th (an arm's 100 starts over
#: 3,400 records would take minutes and gigabytes for a check that the stored fraction of records settles)
CERTIFIED_STATES = 100_000


def certified_every(ro: Rollout) -> int:
    """Which records the certificate checks: every one, or every n-th so that about ``CERTIFIED_STATES`` are."""
    T, B = ro.q.shape[:2]
    return max(1, -(-T * B // CERTIFIED_STATES))


@dataclass
class RecordedEval:
    """The evaluation stage on recorded demonstrations: the results (the tree with every weight 1, each learner at
    each snapshot), each policy's final rollout (for the figures) and the batch they were rolled out from."""

    results: dict
    rollouts: dict[str, Rollout]
    batch: Batch


def premises(exp: Experiment, label: str, tree: RMPTree) -> dict:
    """Whether ``tree``'s goal is its only equilibrium for any parameters (docs/math.md §12), said in the log:
    the premise report metrics.json records beside the convergence measured."""
    report = check_premises(tree)
    exp.say.say(f"{label}: {report.line()}")
    return report.as_dict()


def row_steps(batch: Batch, dt: float, policies: int, long: int) -> int:
    """Rows × integration steps of ``policies`` evaluations on ``batch``, ``long`` of them on to the long horizon:
    the work a compile of their tree is repaid by (``experiment.compiles``)."""
    steps = round(batch.horizon / dt)
    more = round(((batch.long_horizon or batch.horizon) - batch.horizon) / dt)
    return batch.q0.shape[0] * (policies * steps + long * more)


def compiled_if_it_pays(exp: Experiment, what: str, tree: RMPTree | None, work: int) -> str | None:
    """``tree`` set to compile (once; its structure does not change in the evaluation) when ``eval.compile`` says so
    for ``work`` row-steps; None then, else why it stays eager."""
    if tree is None:
        return "not a tree"
    if not compiles(exp.run.eval, work):
        if exp.run.eval.compile == "auto":
            return f"eval.compile=auto: {work:,} row-steps, fewer than the {COMPILE_FROM_ROW_STEPS:,} a compile repays"
        return "eval.compile is false"
    # a batch of ~100 rows gains nothing from SIMD loops, and compiles in half the time without them (the arm's tree
    # at 100 starts: 45 s against 95 s, calls 0.24x and 0.20x the eager time; docs/results/performance.md)
    tree.compile(fixed_structure=True, vectorize=False)
    exp.say.say(COMPILING.format(what=what))
    return None


def evaluated_as(exp: Experiment, label: str, tree: RMPTree | None, seconds: float, eager: str | None) -> dict:
    """How ``label``'s rollouts evaluated it (compiled, or eagerly and why: ``eager``, or the compile's failure) and
    how long they took, said in the log: an entry of metrics.json's ``evaluation``."""
    mode = f"eager ({eager})" if eager is not None else ("eager" if tree is None else tree.evaluation_mode)
    exp.say.say(f"{label}: evaluated {mode}, {seconds:.0f} s of rollouts (metrics.json: evaluation.{label})")
    return {"mode": mode, "seconds": seconds}


def _evaluate_learner(exp: Experiment, name: str, f: Fitted, batch: Batch) -> tuple[dict, Rollout, dict]:
    """One learner at every snapshot (the final one on to the long horizon), in one float64 copy whose tree
    compiles once where it pays (every snapshot's weights are loaded into it; parameters are the compiled tree's
    inputs, so no snapshot compiles again): its results, its final rollout and how it was evaluated."""
    model = f.model.to(torch.float64)
    evaluated = copy.deepcopy(model)
    its = sorted(f.result.snapshots)
    final_it = exp.run.train.iterations
    work = row_steps(batch, exp.env.dt, len(its) + (final_it not in its), 1)
    eager = compiled_if_it_pays(exp, f"learner {name}'s tree for evaluation", evaluated.tree, work)
    t0, snaps = time.time(), {}
    for it in its:
        evaluated.load_state_dict(dict(f.result.snapshots[it]))
        last = it == final_it  # only the final policy goes on to the long horizon
        snaps[str(it)], ro = evaluate_policy(exp, f"{name}-{it}", evaluated.policy, batch, evaluated.tree, last)
    final = snaps.get(str(final_it))
    if final is None:
        evaluated.load_state_dict(model.state_dict())
        final, ro = evaluate_policy(exp, name, evaluated.policy, batch, evaluated.tree)
    how = evaluated_as(exp, name, evaluated.tree, time.time() - t0, eager)
    if model.tree is not None:
        final["certificate"] = certificate(model, ro, batch.policy_aux(), every=certified_every(ro))
        final["premises"] = premises(exp, name, model.tree)
    if learned := model.learned_numbers():
        final["learned_leaf_parameters"] = learned
    out = {
        **final,
        "snapshots": snaps,
        "train_seconds": f.seconds,
        "final_train_loss": f.result.curve[-1][1] if f.result.curve else None,
    }
    return out, ro, how


def evaluate_recorded(exp: Experiment, fitted: dict, batch: Batch) -> RecordedEval:
    """The configured tree (every weight 1) and every learner at every training snapshot; the results, the final
    rollout of each policy (for the figures) and how each was evaluated (``evaluation``: compiled or eager, seconds)."""
    started = time.time()
    res: dict[str, Any] = {"learners": {}, "evaluation": {}}
    rollouts: dict[str, Rollout] = {}
    work = row_steps(batch, exp.env.dt, 1, 1)
    eager = compiled_if_it_pays(exp, "the tree with every weight 1", exp.expert, work)
    res[TREE], rollouts[f"{TREE} (every weight 1)"] = evaluate_policy(exp, TREE, exp.expert_at(), batch, exp.expert)
    res["evaluation"][TREE] = evaluated_as(exp, TREE, exp.expert, time.time() - started, eager)
    res[TREE]["premises"] = premises(exp, TREE, exp.expert)
    for name, f in fitted.items():
        res["learners"][name], ro, res["evaluation"][name] = _evaluate_learner(exp, name, f, batch)
        rollouts[f"{name} after {exp.run.train.iterations} iterations"] = ro
    exp.timing["training_s"] = sum(f.seconds for f in fitted.values())
    exp.timing["evaluation_s"] = time.time() - started
    return RecordedEval(res, rollouts, batch)


# ------------------------------------------------------------------ the run
def _arm_views(env: Any) -> list[View] | None:
    """An arm's configurations as its end effector seen from above (x, y) and from the side (y, z), for the
    rollouts figure; None for an environment whose configuration is already the plane."""
    to_task = _end_effector(env)
    if to_task is None:
        return None
    return [
        View(lambda q: to_task(q)[..., :2], (0, 1), ("x (m)", "y (m)"), ", from above", from_above=True),
        View(lambda q: to_task(q)[..., 1:], (1, 2), ("y (m)", "z (m)"), ", from the side"),
    ]


def objective(results: dict) -> float | None:
    """What a sweep minimises: the first learner's DTW on the validation demonstrations (settings such as the
    filter's window are chosen there, never on the test demonstrations); None without a validation split."""
    for res in results["learners"].values():
        return (res.get("reproduction_val") or {}).get("dtw")
    return None


def report_recorded(
    exp: Experiment, splits: Splits, fitted: dict[str, Fitted], evaluated: RecordedEval, started: float
) -> dict:
    """The report stage on recorded demonstrations: metrics.json (and the figures); returns the metrics."""
    assert splits.demos is not None, "a report on recorded demonstrations needs them"
    results = {**evaluated.results, "objective": objective(evaluated.results)}
    metrics = clean(
        {
            "name": exp.run.name,
            "seed": exp.run.seed,
            "source": "recorded",
            "data": {
                **{k: {kk: vv for kk, vv in v.items() if kk != "path"} for k, v in splits.info.items()},
                "recordings": splits.recordings,
            },
            **results,
            "timing": {**exp.timing, "total_s": time.time() - started},
        }
    )
    if exp.run.eval.figures:
        t0 = time.time()
        trees = {name: f.model.tree for name, f in fitted.items() if f.model.tree is not None}
        metrics["figures"] = recorded_figures(
            exp.dir / "figures", evaluated.rollouts, evaluated.batch, splits.demos, _arm_views(exp.env), trees
        )
        metrics["timing"]["figures_s"] = time.time() - t0
    metrics["timing"]["total_s"] = time.time() - started  # the figures included
    atomic_write_json(exp.dir / "metrics.json", metrics)
    return metrics
