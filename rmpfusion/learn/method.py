"""What a training method is to the pipeline: a class registered in ``TRAIN_METHODS`` with its ``Params`` (a
``TrainParams``), built from the run's ``train:`` block and handed the learner and one ``MethodContext``.

Behavior cloning needs only the demonstrations; DAgger also rolls the learner out and asks the expert; APG and
the policy gradient roll out in the environment without the expert. The context holds all of it explicitly, so a
method states what it uses instead of reaching into the pipeline (which ``learn/`` never imports).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable, Mapping
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, ClassVar, Generic, TypeVar

import torch
from torch import nn

from ..envs.common import DTYPES
from ..envs.demonstrations import Dataset
from ..envs.protocol import Env
from .config import TrainParams
from .learner import Learner
from .loop import Loop, Steps, TrainResult, run
from .objectives import module_device
from .optimizers import make_optimizer

P = TypeVar("P", bound=TrainParams)


class MethodContextError(ValueError):
    """A training method was given a context without something it needs (an environment, the expert)."""


@dataclass
class MethodContext:
    """Everything a training method may use beside the learner and its own settings: filled by the pipeline's fit
    stage (``pipeline/fit.py``), or by ``learn.train.train`` for behavior cloning on a dataset alone."""

    data: Mapping[str, Dataset]  # "train" always; "val" and "test" when the run has them
    seed: int  # of the method's generator (minibatches, starts, exploration)
    env: Env | None = None  # rollouts: DAgger, APG, the policy gradient
    expert: Callable[..., Any] | None = None  # DAgger's labels (and its β-mixture)
    interval: float | None = None  # the demonstrations' recording interval (s)
    points: int | None = None  # records per demonstration
    checkpoint_dir: Path | None = None
    run_config: Mapping[str, Any] | None = None  # stored in every checkpoint
    progress: Callable[[int, int], Any] | None = None
    log: Callable[[dict[str, float]], Any] | None = None
    say: Callable[[str], Any] | None = None  # one-line messages (a DAgger round, ...)
    keep_checkpoints: int = 2

    @property
    def train(self) -> Dataset:
        return self.data["train"]

    @property
    def val(self) -> Dataset | None:
        return self.data.get("val")

    @property
    def test(self) -> Dataset | None:
        return self.data.get("test")

    def cast(self, dtype: torch.dtype, device: torch.device | None = None) -> MethodContext:
        """The same context with every dataset in ``dtype`` (the training dtype) on ``device`` (the model's)."""
        return replace(self, data={k: v.to(dtype, device) for k, v in self.data.items()})

    def need(self, method: str, **what: Any) -> None:
        """Refuse a context without what ``method`` needs (``need("dagger", env=self.env)``), naming it."""
        missing = [k for k, v in what.items() if v is None]
        if missing:
            raise MethodContextError(
                f"training method '{method}' needs {' and '.join(missing)} in its context, "
                "which this caller did not give (the pipeline's fit stage gives them)"
            )

    def tell(self, message: str) -> None:
        if self.say is not None:
            self.say(message)


class TrainingMethod(ABC, Generic[P]):
    """A way of training a learner. Subclasses register with ``TRAIN_METHODS`` with a ``Params`` model (a
    ``TrainParams``, ``P``) and supply their ``Steps``; the loop around them (schedule, curves, snapshots,
    checkpoints, signals, resume) is shared (``learn/loop.py``)."""

    Params: type[TrainParams] = TrainParams

    #: whether the method learns from recorded demonstrations alone (``data.source: recorded``): behavior cloning on
    #: the recorded accelerations and trajectory matching do; a method that asks an expert or a task cost does not
    from_recordings: ClassVar[bool] = False

    def __init__(self, params: P):
        self.params = params

    @classmethod
    def requirements(cls, params: P, env: Env, train_trajectories: int) -> list[tuple[str, str]]:
        """What the method needs of the run that it lacks, as (config path, message) pairs (none by default):
        checked when the config is validated, before anything runs. ``env`` is the run's environment,
        ``train_trajectories`` the number of demonstrations the training split will hold."""
        return []

    @abstractmethod
    def steps(self, model: nn.Module, ctx: MethodContext, opt: torch.optim.Optimizer, gen: torch.Generator) -> Steps:
        """The method's iterations over ``model`` (in the training dtype), its optimiser and generator."""

    def train(self, model: nn.Module, ctx: MethodContext) -> TrainResult:
        """Train ``model`` in place for ``params.iterations`` steps, resuming from ``ctx.checkpoint_dir``."""
        p = self.params
        dtype = DTYPES[p.dtype]
        model.to(dtype)
        ctx = ctx.cast(dtype, module_device(model))  # the model trains where it is; its data goes there once
        if isinstance(model, Learner):
            model.initialise(ctx.train)  # a start made from the data; a resumed run's checkpoint replaces it
        opt = make_optimizer(model.parameters(), p.optimizer, p.lr)
        gen = torch.Generator().manual_seed(int(ctx.seed))
        loop = Loop(
            model=model,
            cfg=p,
            opt=opt,
            gen=gen,
            steps=self.steps(model, ctx, opt, gen),
            ckdir=ctx.checkpoint_dir,
            run_config=ctx.run_config,
            keep_checkpoints=ctx.keep_checkpoints,
            progress=ctx.progress,
            log=ctx.log,
        )
        return run(loop)
