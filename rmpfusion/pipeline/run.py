"""One experiment end to end (issue 4, paper §4.1): demonstrations -> expert -> learners -> behavior cloning
-> evaluation at every snapshot -> figures -> metrics.json. Everything lands in the run directory.

All on CPU, one intra-op thread: the batches are small (2-D states), so extra threads only contend on a
shared machine (a batched 2x2 solve got ~10x slower with 2 busy threads in measurements).
"""
from __future__ import annotations

import hashlib
import json
import math
import os
import sys
import time
import zlib
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Callable, Mapping

import torch

from .config import RunConfig
from ..build.tree import build_tree
from ..files import atomic_torch_save, atomic_write_json
from ..evaluate.metrics import StageResult, batch_loss, evaluate_learner, online_loss, rollout_rates, task_stage
from ..evaluate.weights import edge_weights, learned_edges, summarize_weights
from ..registry import ENVS
from ..learn.demonstrations import Dataset, collect, load_dataset, save_dataset
from ..learn.learners import RMPLearner, build_learner, build_order, compile_learner
from ..learn.train import latest_checkpoint, load_snapshot, train


def expert_spec(cfg: RunConfig) -> dict:
    """The tree with the expert's weights; the validator's version also places weights on shared-weight names."""
    from ..pipeline.validate import expert_spec as spec

    return spec(cfg)


# ---------------------------------------------------------------------------------------------- helpers
class Progress:
    """Progress of long steps with rate and ETA: a bar redrawn in place on a terminal; on a file or pipe
    (CI, SLURM logs) plain lines every 10 % or every 30 s, whichever comes first."""

    def __init__(self, enabled: bool = True, stream=None, every_seconds: float = 30.0):
        self.enabled = enabled
        self.stream = stream or sys.stdout
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.every_seconds = every_seconds
        self._state: dict[str, tuple[float, int, float]] = {}  # label -> (start, last tenth, last print time)

    def say(self, msg: str) -> None:
        if self.enabled:
            print(("\r\033[K" if self.tty else "") + msg, file=self.stream, flush=True)

    @staticmethod
    def _clock(seconds: float) -> str:
        seconds = int(max(seconds, 0))
        return f"{seconds // 3600:d}:{seconds // 60 % 60:02d}:{seconds % 60:02d}" if seconds >= 3600 else f"{seconds // 60:02d}:{seconds % 60:02d}"

    def _line(self, label: str, done: int, total: int, elapsed: float) -> str:
        rate = done / elapsed if elapsed > 0 else 0.0
        eta = (total - done) / rate if rate > 0 else float("nan")
        width = 24
        filled = int(width * done / total)
        bar = "#" * filled + "." * (width - filled)
        eta_s = self._clock(eta) if eta == eta else "--:--"
        return f"{label} [{bar}] {done}/{total} {100 * done / total:3.0f}%  {rate:.1f}/s  elapsed {self._clock(elapsed)}  eta {eta_s}"

    def bar(self, label: str) -> Callable[[int, int], None]:
        def cb(done: int, total: int) -> None:
            if not self.enabled or total <= 0:
                return
            now = time.perf_counter()
            start, last_tenth, last_print = self._state.get(label, (now, -1, 0.0))
            if done == 0 or label not in self._state:
                start, last_tenth, last_print = now, -1, 0.0
            tenth = int(10 * done / total)
            if self.tty:
                print("\r\033[K" + self._line(label, done, total, now - start), end="\n" if done >= total else "",
                      file=self.stream, flush=True)
            elif done >= total or tenth > last_tenth or now - last_print >= self.every_seconds:
                print(self._line(label, done, total, now - start), file=self.stream, flush=True)
                last_tenth, last_print = max(tenth, last_tenth), now
            self._state[label] = (start, last_tenth, last_print)
        return cb


@contextmanager
def _threads(n: int):
    old = torch.get_num_threads()
    torch.set_num_threads(n)
    try:
        yield
    finally:
        torch.set_num_threads(old)


def data_hash(cfg: RunConfig) -> str:
    """What determines the demonstrations: env, tree, expert, data sizes and seed (not the cache location)."""
    key = {"env": cfg.env.model_dump(), "tree": cfg.tree, "expert": cfg.expert, "seed": cfg.seed,
           "data": cfg.data.model_dump(exclude={"cache_dir"})}
    return hashlib.sha256(json.dumps(key, sort_keys=True, default=str).encode()).hexdigest()


def make_env(cfg: RunConfig):
    block = cfg.env.model_dump()
    entry = ENVS.get(block.pop("type"))
    return entry.obj(entry.validate(block))


def _fine_record(env, interval: float) -> float:
    """A recording interval dividing ``interval`` ~10x finer, on the env's step grid (smooth figures, stricter monitor)."""
    dt = getattr(env, "dt", None)
    if not isinstance(dt, (int, float)):
        dt = getattr(getattr(env, "params", None), "dt", None)
    if not dt:
        return interval
    steps = int(round(interval / dt))
    for n in (10, 8, 5, 4, 2):
        if steps % n == 0:
            return interval / n
    return interval


def _finite(x: float) -> float | None:
    return x if isinstance(x, float) and math.isfinite(x) else None


def _clean(m: Any) -> Any:
    """JSON has no inf/nan: a diverged learner's loss is written as null (and reported as such); nested too."""
    if isinstance(m, Mapping):
        return {k: _clean(v) for k, v in m.items()}
    if isinstance(m, (list, tuple)):
        return [_clean(v) for v in m]
    return _finite(m) if isinstance(m, float) else m


def _trajectory_seconds(ds: Dataset) -> dict[str, float]:
    """Duration of the dataset's trajectories (min, mean, max): fixed for the 2D data, 5–10 s for Franka's."""
    ids, inv = ds.traj_id.unique(return_inverse=True)
    last = torch.zeros(len(ids), dtype=ds.t.dtype).scatter_reduce(0, inv, ds.t, "amax", include_self=False)
    return {"min": float(last.min()), "mean": float(last.mean()), "max": float(last.max())}


#: Each split's generator seed is the run's seed plus its offset: three disjoint draws of environments and starts.
SPLIT_SEED_OFFSET = {"train": 0, "test": 1_000_003, "val": 2_000_003}


def load_or_collect(cfg: RunConfig, env, expert, run_dir: Path, split: str, say: Progress) -> tuple[Dataset, dict]:
    """The split's dataset from the cache when present and valid, else collected and saved (then reused).

    ``val`` is drawn like ``train`` (the training environments' distribution, for Franka the training obstacle
    placement) from its own seed: the split settings are chosen on, never trained on.
    """
    d = cfg.data
    h = data_hash(cfg)
    cache = Path(d.cache_dir) if d.cache_dir else run_dir / "data"
    path = cache / f"{split}-{h[:16]}.pt"
    meta = {"seed": cfg.seed, "config_hash": h, "split": split}
    if path.exists():
        ds = load_dataset(path, meta)  # damaged or foreign files raise, naming the file and the fix
        say.say(f"data: reusing {split} set {path} ({len(ds)} points)")
        info = {"path": str(path), "sha256": ds.checksum(), "points": len(ds), "reused": True}
        if getattr(env, "collect_demonstrations", None) is not None:
            info.update(trajectories=int(ds.traj_id.unique().numel()), trajectory_seconds=_trajectory_seconds(ds),
                        expert_success=float(ds.success.double().mean()),
                        expert_collision=float(ds.collided.double().mean()))
        return ds, info
    n_envs, n_traj = {"train": (d.train_envs, d.train_trajectories), "val": (d.val_envs, d.val_trajectories),
                      "test": (d.test_envs, d.test_trajectories)}[split]
    gen = torch.Generator().manual_seed(cfg.seed + SPLIT_SEED_OFFSET[split])
    hook = getattr(env, "collect_demonstrations", None)  # an env with its own protocol (Franka: 5-10 s, split obstacles)
    say.say(f"data: collecting {split} set, {n_envs} envs x {n_traj} trajectories x {'up to ' if hook else ''}"
            f"{d.points} points")
    t0 = time.time()
    bar = say.bar(f"collect {split}")
    if hook is not None:
        ds = hook(expert, n_envs, n_traj, d.points, d.interval, gen, split=split, progress=bar)
    else:
        ds = collect(env, expert, n_envs, n_traj, d.points, d.interval, gen, progress=bar)
    sha = save_dataset(path, ds, meta)
    info = {"path": str(path), "sha256": sha, "points": len(ds), "reused": False, "seconds": time.time() - t0,
            "expert_success": float(ds.success.double().mean()), "expert_collision": float(ds.collided.double().mean())}
    if hook is not None:
        info["trajectories"] = int(ds.traj_id.unique().numel())
        info["trajectory_seconds"] = _trajectory_seconds(ds)
    return ds, info


def load_splits(cfg: RunConfig, env, expert, run_dir: Path, say: Progress) -> dict[str, tuple[Dataset, dict]]:
    """``{split: (dataset, info)}`` for every split the run uses: train, test, and val when ``data.val_envs`` > 0.
    The one place that decides the splits, for ``rmpfusion-run`` and the stage commands alike."""
    names = ("train", "test", "val") if cfg.data.val_envs else ("train", "test")
    return {s: load_or_collect(cfg, env, expert, run_dir, s, say) for s in names}


class WeightReport:
    """The weights of learner-rmp's learned edges over the test states at every snapshot, beside the expert's on
    the same states (an edge the expert leaves unweighted has w = 1 there): summaries for metrics.json, values
    along one test trajectory for the figure."""

    def __init__(self, expert, model: RMPLearner, test_ds: Dataset):
        self.edges = learned_edges(model.tree)
        self.states = (test_ds.q, test_ds.qd, test_ds.aux)
        self.along = test_ds.traj_id == test_ds.traj_id[0]  # the first test trajectory
        self.times = test_ds.t[self.along]
        weighted = [e for e in self.edges if e in expert.weights]
        values = edge_weights(expert, *self.states, weighted)
        ones = torch.ones(len(test_ds), dtype=test_ds.q.dtype)
        self.expert = {e: values.get(e, ones) for e in self.edges}
        self.traces: dict[str, dict[str, torch.Tensor]] = {}

    def expert_summary(self) -> dict:
        return summarize_weights(self.expert)

    def snapshot(self, label: str, model: RMPLearner) -> dict:
        values = edge_weights(model.tree, *self.states, self.edges)
        self.traces[label] = {e: w[self.along] for e, w in values.items()}
        return summarize_weights(values)

    def figure(self, path: Path, title: str) -> Path:
        from ..plots import plot_weights

        return plot_weights(path, self.times, {e: w[self.along] for e, w in self.expert.items()}, self.traces,
                            title=title)


def _learner_seed(seed: int, name: str) -> int:
    return (seed * 1_000_003 + zlib.crc32(name.encode())) % (2**63 - 1)


# ---------------------------------------------------------------------------------------------- the run
def run_experiment(cfg: RunConfig, run_dir: str | os.PathLike, progress: bool = True,
                   log: Callable[[dict[str, float]], Any] | None = None, threads: int = 1) -> dict:
    """Run ``cfg`` in ``run_dir`` and return (and write) its metrics; rerunning reuses data and checkpoints."""
    run_dir = Path(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    say = Progress(progress)
    with _threads(threads):
        return _run(cfg, run_dir, say, log)


def _run(cfg: RunConfig, run_dir: Path, say: Progress, log) -> dict:
    t_start = time.time()
    timing: dict[str, float] = {}
    config = cfg.model_dump()
    atomic_write_json(run_dir / "config.json", config)
    env = make_env(cfg)
    aux_dims = env.aux_dims()
    expert = build_tree(expert_spec(cfg), aux_dims=aux_dims)
    if cfg.eval.compile:
        expert.compile()
    dim = expert.dim
    # optional environment hooks (Franka): per-trajectory task metrics compared with the expert, and its figures
    has_task = callable(getattr(env, "task_metrics", None))
    env_figures = getattr(env, "figures", None)

    t0 = time.time()
    data = load_splits(cfg, env, expert, run_dir, say)
    (train_ds, _), (test_ds, _) = data["train"], data["test"]
    val_ds = data["val"][0] if "val" in data else None
    timing["data_s"] = time.time() - t0

    d, ev = cfg.data, cfg.eval
    horizon = ev.horizon if ev.horizon is not None else d.points * d.interval
    fine = _fine_record(env, d.interval)
    q0, qd0, aux0 = test_ds.initial_states()

    # the expert on the same test initial states: the reference for rates and the dashed lines in figures
    t0 = time.time()
    say.say("eval: expert")
    exp_ro = online_loss(expert, expert, env, q0, qd0, aux0, horizon, d.interval, fine, say.bar("rollout expert")).rollout
    expert_metrics = rollout_rates(exp_ro, ev.lyapunov_rtol, ev.lyapunov_atol)
    expert_stage: StageResult | None = None
    if has_task:
        expert_stage = task_stage("expert", exp_ro, env, rtol=ev.lyapunov_rtol, atol=ev.lyapunov_atol)
        expert_metrics["task"] = expert_stage.summary
        say.say("expert: " + _task_line(expert_stage))
    timing["expert_eval_s"] = time.time() - t0

    blocks = {n: b.model_dump() for n, b in cfg.learners.items()}
    learners: dict[str, torch.nn.Module] = {}
    for name in build_order(blocks):
        with torch.random.fork_rng():
            torch.manual_seed(_learner_seed(cfg.seed, name))
            learners[name] = build_learner(blocks[name], cfg.tree, aux_dims, dim, expert=cfg.expert, built=learners,
                                           where=f"learners.{name}")
        say.say(f"learner {name}: {blocks[name]['type']}, {learners[name].num_parameters()} parameters")

    results: dict[str, dict] = {}
    figures: list[str] = []
    fig_dir = run_dir / "figures"
    per_env = d.test_trajectories
    plot_idx = torch.arange(min(per_env, q0.shape[0]))  # test environment 0
    aux_plot = {k: v[:1] for k, v in aux0.items()}
    curves: dict[str, dict] = {}
    task_stages: list[StageResult] = []
    for name in cfg.learners:  # config order for reporting
        model = learners[name]
        t0 = time.time()
        if cfg.train.compile:
            compile_learner(model)
        ckdir = run_dir / "checkpoints" / name
        if (ck := latest_checkpoint(ckdir)) is not None:
            say.say(f"learner {name}: resuming from {ck}")
        tr = train(model, train_ds, cfg.train, seed=_learner_seed(cfg.seed, name) + 1, test_data=test_ds,
                   val_data=val_ds, checkpoint_dir=ckdir, run_config=config,
                   progress=say.bar(f"train {name}"),
                   log=(lambda m, _n=name: log({f"{_n}/{k}" if k != "iteration" else k: v for k, v in m.items()}))
                   if log is not None else None)
        train_s = time.time() - t0
        dtype = next(model.parameters()).dtype
        model.to(torch.float64)  # rollouts and evaluation in float64 (docs/math.md §11)
        if cfg.eval.compile:
            compile_learner(model)
        atomic_torch_save({"model": model.state_dict(), "learner": blocks[name], "config": config,
                      "iterations": cfg.train.iterations}, ckdir / "final.pt")
        t0 = time.time()
        snaps: dict[str, dict] = {}
        stages = []
        weights = WeightReport(expert, model, test_ds) if isinstance(model, RMPLearner) else None
        if weights is not None:
            expert_metrics.setdefault("weights", {}).update(weights.expert_summary())
        final_metrics, final_online = None, None

        def with_task(met: dict, ro, it: int) -> dict:
            if expert_stage is None:
                return met
            label = f"learner-{it}" if len(cfg.learners) == 1 else f"{name}-{it}"  # the paper's names
            st = task_stage(label, ro, env, expert_stage, ev.lyapunov_rtol, ev.lyapunov_atol,
                            learner=name, iteration=it)
            task_stages.append(st)
            say.say(f"{label}: " + _task_line(st))
            return {**met, "task": st.summary, "ratio_to_expert": st.ratios, "lyapunov": st.lyapunov}

        for it in sorted(tr.snapshots):
            m_it = load_snapshot(model, tr.snapshots[it]).to(torch.float64)
            met, onl = evaluate_learner(m_it, expert, env, test_ds, horizon, d.interval, ev.lyapunov_rtol,
                                        ev.lyapunov_atol, fine, say.bar(f"eval {name}@{it}"))
            ro = onl.rollout
            met = with_task(met, ro, it)
            if val_ds is not None:
                met["val_loss"] = batch_loss(m_it, val_ds)
            if weights is not None:
                met["weights"] = weights.snapshot(f"{name} @ {it}", m_it)
            snaps[str(it)] = _clean(met)
            stages.append({"label": f"{name} @ {it}", "q": ro.q[:, plot_idx], "times": ro.times,
                           "V": ro.V[:, plot_idx] if ro.V is not None else None})
            if it == cfg.train.iterations:
                final_metrics, final_online = met, onl
            if log is not None:
                log({"iteration": float(it), **{f"{name}/snapshot_{k}": v for k, v in met.items()
                                                if isinstance(v, (int, float))}})
        if final_metrics is None:
            final_metrics, final_online = evaluate_learner(model, expert, env, test_ds, horizon, d.interval,
                                                           ev.lyapunov_rtol, ev.lyapunov_atol, fine,
                                                           say.bar(f"eval {name}"))
            final_metrics = with_task(final_metrics, final_online.rollout, cfg.train.iterations)
            if val_ds is not None:
                final_metrics["val_loss"] = batch_loss(model, val_ds)
        eval_s = time.time() - t0
        model.to(dtype)
        res = _clean(final_metrics)
        res.update({"num_parameters": model.num_parameters(), "type": blocks[name]["type"],
                    "train_seconds": train_s, "eval_seconds": eval_s, "snapshots": snaps,
                    "final_train_loss": tr.curve[-1][1] if tr.curve else None,
                    "resumed_from": tr.resumed_from})
        if hasattr(model, "hidden"):
            res["hidden"] = list(model.hidden)
        results[name] = res
        curves[name] = {"train": tr.curve, "val": tr.val_curve, "test": tr.test_curve}
        say.say(f"learner {name}: " + ", ".join(f"{k}={v:.4g}" for k, v in res.items()
                                                 if isinstance(v, float) and k not in ("train_seconds", "eval_seconds")))
        if ev.figures:
            from ..plots import plot_learning_curves, plot_lyapunov, plot_progression, plot_trajectories
            ro = final_online.rollout
            state_space = env_figures is None  # the default figures draw 2-D configuration spaces (particle2d)
            if state_space:
                figures.append(str(plot_trajectories(
                    fig_dir / f"trajectories_{name}.png", aux_plot, exp_ro.q[:, plot_idx], {name: ro.q[:, plot_idx]},
                    q0[plot_idx], qd0[plot_idx], title=f"{cfg.name}: expert (dashed) vs {name}")))
                if ro.V is not None:
                    figures.append(str(plot_lyapunov(fig_dir / f"lyapunov_{name}.png", ro.times, ro.V[:, plot_idx],
                                                     title=f"{name}: $V_r(t)$, test environment 0")))
            figures.append(str(plot_learning_curves(fig_dir / f"learning_curve_{name}.png", {name: curves[name]},
                                                    {name: sorted(tr.snapshots)})))
            if weights is not None and weights.traces:
                figures.append(str(weights.figure(fig_dir / f"weights_{name}.png",
                                                  f"{cfg.name}: {name}'s weights vs the expert's (dashed) "
                                                  "along test trajectory 0")))
            if state_space:
                if stages:
                    figures.append(str(plot_progression(fig_dir / f"progression_{name}.png", aux_plot,
                                                        exp_ro.q[:, plot_idx], stages, q0[plot_idx], qd0[plot_idx])))
    if ev.figures and curves:
        from ..plots import plot_learning_curves
        figures.append(str(plot_learning_curves(fig_dir / "learning_curves.png", curves)))
    if ev.figures and env_figures is not None and expert_stage is not None:
        t0 = time.time()
        say.say("figures: " + cfg.name)
        figures += [str(f) for f in env_figures(fig_dir, expert_stage, task_stages, aux0, title=cfg.name)]
        timing["figures_s"] = time.time() - t0
    timing["total_s"] = time.time() - t_start
    metrics = {"name": cfg.name, "seed": cfg.seed, "config_hash": data_hash(cfg),
               "data": {s: info for s, (_, info) in data.items()}, "expert": _clean(expert_metrics),
               "learners": results, "figures": figures, "timing": timing}
    if expert_stage is not None:
        metrics["task_table"] = _clean(_task_table(expert_stage, task_stages, getattr(env, "ratio_metrics", ())))
    atomic_write_json(run_dir / "metrics.json", metrics)
    say.say(f"done in {timing['total_s']:.1f}s: {run_dir / 'metrics.json'}")
    return metrics


def _task_line(st: StageResult) -> str:
    parts = [f"{k}={v['mean']:.4g}±{v['std']:.2g}" for k, v in st.summary.items()]
    if st.ratios:
        parts += [f"ratio.{k}={v['mean']:.3f}±{v['std']:.3f}" for k, v in st.ratios.items()]
    return ", ".join(parts)


def _task_table(expert: StageResult, stages: list[StageResult], ratio_keys) -> list[dict]:
    """One row per policy (expert, then every learner snapshot): task-metric means ± std, ratios to the expert,
    collisions and the Lyapunov monitor: the numbers of the paper's Fig. 5b in one place."""
    rows = []
    for st in [expert, *stages]:
        row: dict[str, Any] = {"policy": st.label, "learner": st.learner, "iteration": st.iteration}
        for k, v in st.summary.items():
            row[k] = {"mean": v["mean"], "std": v["std"]}
        row["collisions"] = int(round(float(st.per_trajectory["collided"].sum()))) if "collided" in st.per_trajectory else None
        row["trajectories"] = int(st.rollout.q.shape[1])
        if st.ratios:
            row["ratio"] = {k: {"mean": v["mean"], "std": v["std"]} for k, v in st.ratios.items() if k in ratio_keys}
        if st.lyapunov:
            row["lyapunov"] = dict(st.lyapunov)
        rows.append(row)
    return rows
