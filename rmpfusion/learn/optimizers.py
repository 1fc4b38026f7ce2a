"""Optimisers, registered in ``OPTIMIZERS`` by the name ``train.optimizer`` gives them.

An entry is a factory ``(parameters, lr) -> torch.optim.Optimizer``; the step size comes from the training
block (and its schedule), every other hyper-parameter is the entry's own choice.
"""

from __future__ import annotations

from collections.abc import Iterable

import torch

from ..registry import OPTIMIZERS, Params


# foreach=True: one fused update for all tensors (on the CPU torch defaults to a loop over them)
@OPTIMIZERS.register("rmsprop", params=Params)
def rmsprop(parameters: Iterable[torch.nn.Parameter], lr: float) -> torch.optim.Optimizer:
    return torch.optim.RMSprop(parameters, lr=lr, foreach=True)


@OPTIMIZERS.register("adam", params=Params)
def adam(parameters: Iterable[torch.nn.Parameter], lr: float) -> torch.optim.Optimizer:
    return torch.optim.Adam(parameters, lr=lr, foreach=True)


@OPTIMIZERS.register("sgd", params=Params)
def sgd(parameters: Iterable[torch.nn.Parameter], lr: float) -> torch.optim.Optimizer:
    return torch.optim.SGD(parameters, lr=lr, foreach=True)


def make_optimizer(parameters: Iterable[torch.nn.Parameter], name: str, lr: float) -> torch.optim.Optimizer:
    """The registered optimiser ``name`` over ``parameters`` (``RegistryError`` naming the registered ones if
    there is none)."""
    return OPTIMIZERS.get(name).obj(parameters, lr)
