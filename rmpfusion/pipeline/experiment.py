"""What every stage of an experiment shares: the validated config, the run directory, the environment, the
expert, progress output and the metrics logger, and the settings derived from the config once."""

from __future__ import annotations

import math
import zlib
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch
from torch import Tensor

from ..assembly.errors import ConfigError, Issue
from ..core.tree import RMPTree
from ..envs.common import on_device
from ..envs.demonstrations import Dataset
from ..envs.protocol import ComputesOn, Env
from .config import DataConfig, EvalConfig, RecordedDataConfig, RunConfig
from .construct import build_expert, make_env
from .progress import Progress
from .validate import typed

#: metrics.json's and the logger's sink for scalar metrics: ``log({"iteration": i, "<name>/<key>": value})``
Log = Callable[[dict[str, float]], Any]


def evaluation_horizon(ev: EvalConfig, data: DataConfig) -> float:
    """Seconds an evaluation rollout lasts: ``eval.horizon``, default the demonstrations' length."""
    return ev.horizon if ev.horizon is not None else data.points * data.interval


@dataclass
class Experiment:
    """One run's fixed context, built once (``prepare``) and handed to every stage."""

    run: RunConfig
    dir: Path
    env: Env
    expert: RMPTree
    say: Progress
    log: Log | None = None
    timing: dict[str, float] = field(default_factory=dict)

    @property
    def device(self) -> torch.device:
        """Where trees, learners and training compute (``device`` in the run config)."""
        return torch.device(self.run.device)

    def expert_at(self) -> Callable:
        """The expert as a callable for states held on the CPU (rollout records, datasets): it computes on the
        run's device and answers on the states'."""
        return on_device(self.expert, self.device)

    @property
    def config(self) -> dict:
        """The run config as plain data: what checkpoints and config.json store."""
        return self.run.model_dump()

    @property
    def expert_data(self) -> DataConfig:
        """``data`` of a run on the expert's demonstrations, which the collect and evaluate stages read; on recorded
        demonstrations the same stages read ``recorded_data`` instead."""
        assert isinstance(self.run.data, DataConfig), "a run on recorded demonstrations has no expert's data"
        return self.run.data

    @property
    def recorded_data(self) -> RecordedDataConfig:
        """``data`` of a run on recorded demonstrations, which the collect stage (the recorded source) and the
        evaluation's recorded part (``pipeline/recorded.py``) read."""
        assert isinstance(self.run.data, RecordedDataConfig), "a run on the expert's demonstrations has no recordings"
        return self.run.data

    @property
    def horizon(self) -> float:
        """Seconds each evaluation rollout lasts (``evaluation_horizon``)."""
        return evaluation_horizon(self.run.eval, self.expert_data)

    @property
    def fine_interval(self) -> float:
        """A recording interval dividing ``data.interval`` ~10x finer on the env's step grid: smooth figures and
        a stricter Lyapunov monitor than the demonstrations' spacing."""
        interval = self.expert_data.interval
        steps = round(interval / self.env.dt)
        for n in (10, 8, 5, 4, 2):
            if steps % n == 0:
                return interval / n
        return interval

    def environment_0(self, test: Dataset) -> tuple[Tensor, Tensor, Tensor, dict[str, Tensor]]:
        """Test environment 0, the one figures draw: the indices of its initial states (they are
        environment-major), those states, and its aux as a one-row batch."""
        q0, qd0, aux0 = test.initial_states()
        idx = torch.arange(min(self.expert_data.test_trajectories, q0.shape[0]))
        return idx, q0[idx], qd0[idx], {k: v[:1] for k, v in aux0.items()}

    def learner_seed(self, name: str) -> int:
        """Each learner's own seed (its initial weights; training uses this + 1): independent of the others."""
        return learner_seed(self.run.seed, name)

    def log_scalars(self, name: str, metrics: Mapping[str, float]) -> None:
        if self.log is not None:
            self.log({k if k == "iteration" else f"{name}/{k}": v for k, v in metrics.items()})


def learner_seed(seed: int, name: str) -> int:
    """The seed learner ``name``'s initial weights are drawn from in a run with seed ``seed``."""
    return (seed * 1_000_003 + zlib.crc32(name.encode())) % (2**63 - 1)


#: ``eval.compile: auto`` compiles a tree whose rollouts in a recorded evaluation come to at least this many row-steps
#: (rows of the batch × integration steps, over every snapshot it is loaded with): on LASA Angle the tree's 164,000
#: took as long eagerly as compiled, compile included, and its learner's 214,000 half as long compiled (the arm's
#: 1.2 million per policy far more); docs/results/performance.md, "Recorded runs". Smoke-sized runs stay eager.
COMPILE_FROM_ROW_STEPS = 200_000


def compiles(ev: EvalConfig, row_steps: int | None = None) -> bool:
    """Whether a tree is rolled out compiled: ``eval.compile``, where ``auto`` compiles when the rollouts it serves
    come to ``COMPILE_FROM_ROW_STEPS`` row-steps (``row_steps`` None: an expert's evaluation, always compiled)."""
    if ev.compile == "auto":
        return row_steps is None or row_steps >= COMPILE_FROM_ROW_STEPS
    return ev.compile


def prepare(run: RunConfig, run_dir: Path, say: Progress, log: Log | None = None) -> Experiment:
    """The environment and the expert tree of a validated config, compiled when ``eval.compile`` asks."""
    run = typed(run)
    env = make_env(run)
    device = torch.device(run.device)
    if device.type != "cpu":
        if not isinstance(env, ComputesOn):
            raise ConfigError(
                [
                    Issue(
                        "device",
                        f"the environment '{run.env.type}' cannot evaluate policies on "
                        f"{run.device} (it does not implement envs.protocol.ComputesOn); "
                        "set device=cpu",
                    )
                ]
            )
        env.to(device)
    expert = build_expert(run, env.aux_dims()).to(device)
    if compiles(run.eval) and not isinstance(run.data, RecordedDataConfig):  # recorded: decided at the evaluation
        expert.compile(fixed_structure=True)  # the expert never changes in a run: no checks of its modules per call
        say.say(COMPILING.format(what="the expert's tree"))
    return Experiment(run=run, dir=run_dir, env=env, expert=expert, say=say, log=log)


#: Said before the first call of a compiled policy, which compiles it (minutes, in silence otherwise).
COMPILING = (
    "compiling {what} with torch.compile (first call, cached afterwards: it can take minutes; eval.compile="
    "false or train.compile=false skip it)"
)


def clean(m: Any) -> Any:
    """JSON has no inf/nan: a diverged learner's loss is written as null (and reported as such); nested too."""
    if isinstance(m, Mapping):
        return {k: clean(v) for k, v in m.items()}
    if isinstance(m, (list, tuple)):
        return [clean(v) for v in m]
    if isinstance(m, float):
        return m if math.isfinite(m) else None
    return m
