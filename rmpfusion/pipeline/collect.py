"""Stage 1, collect: the expert's demonstrations of every split, cached in the run directory (checksummed)."""

from __future__ import annotations

import dataclasses
import hashlib
import json
import time
from dataclasses import dataclass
from pathlib import Path

import torch

from ..assembly.weighting import plain_data
from ..envs.demonstrations import Dataset, load_dataset, save_dataset
from ..envs.protocol import JointSpace, LearnsFromRecordings, Reaches
from ..evaluate.divergence import Divergence, divergence_of_records
from ..recordings import recorded_dataset, split_of
from ..recordings.formats import flat_dump
from ..recordings.recording import RecordingError
from ..recordings.signals import States
from ..recordings.source import content_hash, ignored_columns, ignored_line, on_grid_for, read_recordings
from ..scenes.crossing import summarize
from .config import RunConfig
from .experiment import Experiment
from .obstacle_entries import apply_policy

#: Each split's generator seed is the run's seed plus its offset: three disjoint draws of environments and starts.
SPLIT_SEED_OFFSET = {"train": 0, "test": 1_000_003, "val": 2_000_003}


class ExpertDivergedError(FloatingPointError):
    """The expert's own rollouts diverged: demonstrations of it would teach nothing, so the run stops."""


def expert_diverged(what: str, found: Divergence) -> ExpertDivergedError:
    return ExpertDivergedError(
        f"the expert diverged on {len(found.samples)} of {found.total} {what} (trajectories {found.samples[:8]}"
        f"{' …' if len(found.samples) > 8 else ''}): {found.reason}; nothing it demonstrates could be learned, so "
        "the run stops. Lower the tree's gains (tree.nodes.<leaf>.rmp.gain) or the step (env.dt, or a higher "
        "env.control_rate), and check the expert alone with a short run (data=tiny train=tiny eval=fast)"
    )


@dataclass
class Splits:
    """The datasets of a run by split (``train``, ``test``, and ``val`` when ``data.val_envs`` > 0) and what
    metrics.json says about each (file, checksum, size, the expert's success there)."""

    data: dict[str, Dataset]
    info: dict[str, dict]
    #: recorded demonstrations (``data.source: recorded``): each split's on the step grid, and every one (the
    #: evaluation's starts and horizon are made from them); None for the expert's rollouts
    demos: dict[str, list[States]] | None = None
    every_demo: list[States] | None = None
    #: recorded demonstrations: what reading them found beside the splits (columns left out, obstacle entries and
    #: what ``data.obstacle_entries`` did with them), recorded in metrics.json's data section; None otherwise
    recordings: dict | None = None

    @property
    def train(self) -> Dataset:
        return self.data["train"]

    @property
    def test(self) -> Dataset:
        return self.data["test"]

    @property
    def val(self) -> Dataset | None:
        return self.data.get("val")


def data_hash(run: RunConfig, split: str | None = None) -> str:
    """What determines the demonstrations: env, tree, expert, data sizes and seed (not the cache location). An
    environment's ``test_sampling`` (the test split's own sampler settings) determines only the test split: the
    hash of the training and validation splits leaves it out, so a run that changes only the test split reuses
    their cached files, and it is left out wherever it is empty (the hashes of runs that never set it)."""
    env = run.env.model_dump()
    if not env.get("test_sampling") or split in ("train", "val"):
        env.pop("test_sampling", None)
    key = {
        "env": env,
        "tree": run.tree.model_dump(),
        "expert": {k: plain_data(w) for k, w in run.expert.items()},
        "seed": run.seed,
        "data": run.data.model_dump(exclude={"cache_dir", "source"}),
    }
    return hashlib.sha256(json.dumps(key, sort_keys=True, default=str).encode()).hexdigest()


def _trajectory_seconds(ds: Dataset) -> dict[str, float]:
    """Duration of the dataset's trajectories (min, mean, max): fixed for the 2D data, 5–10 s for Franka's."""
    ids, inv = ds.traj_id.unique(return_inverse=True)
    last = torch.zeros(len(ids), dtype=ds.t.dtype).scatter_reduce(0, inv, ds.t, "amax", include_self=False)
    return {"min": float(last.min()), "mean": float(last.mean()), "max": float(last.max())}


def _describe(ds: Dataset) -> dict:
    return {
        "trajectories": int(ds.traj_id.unique().numel()),
        "trajectory_seconds": _trajectory_seconds(ds),
        "expert_success": float(ds.success.double().mean()),
        "expert_collision": float(ds.collided.double().mean()),
    }


#: below these the run warns before training: a reaching task whose obstacle is seldom in the way, and an expert that
#: does not reach the validation goals (what the learners imitate would then not be the task's solution)
MIN_CROSSING, MIN_EXPERT_SUCCESS = 0.8, 0.8


def _crossing(env, ds: Dataset) -> dict:
    """How many of the split's straight reaches cross an obstacle (``scenes/crossing.py``), for a reaching task."""
    if not isinstance(env, Reaches):
        return {}
    q0, _, aux = ds.initial_states()
    return {"crossing": summarize(env.path_clearance(q0, aux), env.ee_radius).as_dict()}


def check_task(exp: Experiment, splits: Splits) -> list[str]:
    """Say, before any training, how the task was laid out, whether its obstacle is in the way of the reaches, and
    whether the expert reached the validation goals; returns the warnings (also printed)."""
    env, say = exp.env, exp.say.say
    warnings: list[str] = []
    if not isinstance(env, Reaches):
        return warnings
    layout = env.describe_task()
    if layout:
        say(f"task: {layout}")
    for split, info in splits.info.items():
        c = info.get("crossing")
        if c:
            say(
                f"task: {split}: {c['crossing_fraction']:.0%} of {c['paths']} straight reaches cross an obstacle "
                f"(median clearance {c['clearance_quantiles']['median']:.3f} m, crossing below {c['radius']:.3f} m); "
                f"the expert reached {info['expert_success']:.0%} of the goals, collided on "
                f"{info['expert_collision']:.0%}"
            )
    train = splits.info["train"].get("crossing")
    if train and train["crossing_fraction"] < MIN_CROSSING:
        warnings.append(
            f"only {train['crossing_fraction']:.0%} of the training reaches cross an obstacle (fewer "
            f"than {MIN_CROSSING:.0%}): the obstacle is seldom in the way; move the goals or the obstacle"
        )
    check = splits.info.get("val") or splits.info["train"]
    if check["expert_success"] < MIN_EXPERT_SUCCESS:
        warnings.append(
            f"the expert reached only {check['expert_success']:.0%} of the "
            f"{'validation' if 'val' in splits.info else 'training'} goals (fewer than "
            f"{MIN_EXPERT_SUCCESS:.0%}): its weights do not solve this task on this robot, and the learners "
            f"will imitate a failing expert"
        )
    for w in warnings:
        say(f"warning: {w}")
    return warnings


def load_or_collect(exp: Experiment, split: str) -> tuple[Dataset, dict]:
    """The split's dataset from the cache when present and valid, else collected and saved (then reused).

    ``val`` is drawn like ``train`` (the training environments' distribution, for Franka the training obstacle
    placement) from its own seed: the split settings are chosen on, never trained on.
    """
    d, h = exp.expert_data, data_hash(exp.run, split)
    cache = Path(d.cache_dir) if d.cache_dir else exp.dir / "data"
    path = cache / f"{split}-{h[:16]}.pt"
    meta = {"seed": exp.run.seed, "config_hash": h, "split": split}
    if path.exists():
        ds = load_dataset(path, meta)  # damaged or foreign files raise, naming the file and the fix
        exp.say.say(f"data: reusing {split} set {path} ({len(ds)} points)")
        return ds, {
            "path": str(path),
            "sha256": ds.checksum(),
            "points": len(ds),
            "reused": True,
            **_describe(ds),
            **_crossing(exp.env, ds),
        }
    n_envs, n_traj = {
        "train": (d.train_envs, d.train_trajectories),
        "val": (d.val_envs, d.val_trajectories),
        "test": (d.test_envs, d.test_trajectories),
    }[split]
    gen = torch.Generator().manual_seed(exp.run.seed + SPLIT_SEED_OFFSET[split])
    exp.say.say(f"data: collecting {split} set, {n_envs} envs x {n_traj} trajectories x up to {d.points} points")
    t0 = time.time()
    ds = exp.env.demonstrations(
        exp.expert, n_envs, n_traj, d.points, d.interval, gen, split=split, progress=exp.say.bar(f"collect {split}")
    )
    if (found := divergence_of_records(ds.q, ds.qd, ds.traj_id, ds.t)) is not None:
        raise expert_diverged(f"{split} demonstrations", found)
    sha = save_dataset(path, ds, meta)
    return ds, {
        "path": str(path),
        "sha256": sha,
        "points": len(ds),
        "reused": False,
        "seconds": time.time() - t0,
        **_describe(ds),
        **_crossing(exp.env, ds),
    }


def collect(exp: Experiment, splits: tuple[str, ...] | None = None) -> Splits:
    """Every split the run uses (or those named): the one place that decides the splits, for
    ``rmpfusion-run`` and the stage commands alike; recorded demonstrations are split by demonstration
    (``recorded_splits``), every split at once."""
    if exp.run.data.source == "recorded":  # the recorded source supplies every split at once
        made, demos, every_demo = recorded_splits(exp)
        return dataclasses.replace(made, demos=demos, every_demo=every_demo)
    names = splits or (("train", "test", "val") if exp.expert_data.val_envs else ("train", "test"))
    t0 = time.time()
    loaded = {s: load_or_collect(exp, s) for s in names}
    exp.timing["data_s"] = time.time() - t0
    collected = Splits({s: ds for s, (ds, _) in loaded.items()}, {s: info for s, (_, info) in loaded.items()})
    if "train" in collected.info:
        check_task(exp, collected)
    return collected


# ------------------------------------------------------------------ the recorded source
#: data keys that change the evaluation only, never a split's dataset
EVALUATION_ONLY = frozenset(
    {"cache_dir", "starts", "enlarge", "horizon_factor", "convergence_horizon_factor", "at_rest_rate", "tolerance"}
)


def _dataset_settings(d) -> dict:
    """The data settings a split's dataset depends on. ``obstacle_entries`` counts only where it drops recordings:
    the members are indices into the recordings kept, which refuse and warn keep alike (and every run made before
    the key existed kept them too)."""
    out = {k: v for k, v in flat_dump(d).items() if k not in EVALUATION_ONLY}
    if out.get("obstacle_entries") != "drop":
        out.pop("obstacle_entries", None)
    return out


def _cache_key(exp: Experiment, files: str, split: str, members: tuple[int, ...]) -> str:
    """What determines a split's dataset: the files' content hash, the data settings, the step and its members."""
    d = exp.run.data
    key = {
        "files": files,
        "data": _dataset_settings(d),
        "dt": exp.env.dt,
        "env": exp.run.env.model_dump(mode="json"),  # the aux state (an arm's goal, obstacles) depends on it
        "split": split,
        "members": members,
    }
    return hashlib.sha256(json.dumps(key, sort_keys=True, default=str).encode()).hexdigest()


def _dataset(
    exp: Experiment, files: str, split: str, members: tuple[int, ...], states: list[States]
) -> tuple[Dataset, dict]:
    """The split's dataset, from the cache when the files (``files``: their content hash) and settings are the
    same, else made and cached."""
    d = exp.recorded_data
    h = _cache_key(exp, files, split, members)
    path = (Path(d.cache_dir) if d.cache_dir else exp.dir / "data") / f"{split}-{h[:16]}.pt"
    meta = {"seed": exp.run.seed, "config_hash": h, "split": split}
    info = {"path": str(path), "demonstrations": [states[i].source for i in members]}
    if path.exists():
        ds = load_dataset(path, meta)
        return ds, {**info, "sha256": ds.checksum(), "points": len(ds), "reused": True}
    ds = recorded_dataset(
        [states[i] for i in members], every=d.every if split == "train" else 1, aux_of=recording_env(exp).recorded_aux
    )
    return ds, {**info, "sha256": save_dataset(path, ds, meta), "points": len(ds), "reused": False}


def recording_env(exp: Experiment) -> LearnsFromRecordings:
    """The run's environment as one that learns from recordings (what the tree reads besides the configuration)."""
    env = exp.env
    if not isinstance(env, LearnsFromRecordings):
        raise RecordingError(
            f"env.type={exp.run.env.type} cannot learn from recorded demonstrations (data.source: recorded): it "
            "does not say what aux state a recording implies; use env=plane or an arm's env=manipulator"
        )
    return env


def recorded_splits(exp: Experiment) -> tuple[Splits, dict[str, list[States]], list[States]]:
    """The run's splits as datasets, the demonstrations of each split on the step grid, and all of them."""
    d = exp.recorded_data
    t0 = time.time()
    env = recording_env(exp)
    robot = exp.env.robot_description if isinstance(exp.env, JointSpace) else None
    recordings = read_recordings(d, robot.joints if robot is not None else None)
    states = on_grid_for(recordings, d, exp.env.dt, exp.env.dim, exp.run.env.type, robot, exp.env.aux_dims())
    states, found, warnings = apply_policy(env, states, d.obstacle_entries)
    if (line := ignored_line(recordings)) is not None:
        exp.say.say(f"data: {line}")
    for w in warnings:
        exp.say.say(f"warning: {w}")
    read = {
        "ignored_columns": ignored_columns(recordings),
        "obstacle_entries": found.as_dict(d.obstacle_entries, found.entering if d.obstacle_entries == "drop" else []),
    }
    split = split_of(d, len(states), exp.run.seed)
    parts = {"train": split.train, "test": split.test, **({"val": split.val} if split.val else {})}
    files = content_hash(d)
    seen = states if d.aux_to_policy else [dataclasses.replace(s, aux={}) for s in states]  # the scene's aux
    made = {name: _dataset(exp, files, name, members, seen) for name, members in parts.items()}
    for name, (ds, info) in made.items():
        exp.say.say(
            f"data: {name}: {len(info['demonstrations'])} demonstration(s), {info['points']} points"
            f"{' (reused)' if info['reused'] else ''}"
        )
    exp.timing["data_s"] = time.time() - t0
    splits = Splits({k: ds for k, (ds, _) in made.items()}, {k: info for k, (_, info) in made.items()}, recordings=read)
    return splits, {k: [states[i] for i in m] for k, m in parts.items()}, states
