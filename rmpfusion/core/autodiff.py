"""Batched derivatives by forward/reverse mode for the parts a building block does not supply analytically.

Every function here takes a *batched* callable whose b-th output depends only on the b-th input, which
lets one jvp with a batched tangent or one vjp with a cotangent of ones give per-sample derivatives.
They compose with ordinary autograd, so parameters inside the callable still receive gradients.
"""

from __future__ import annotations

from collections.abc import Callable

import torch
from torch import Tensor
from torch.func import jvp, vjp, vmap


def directional(fn: Callable[[Tensor], Tensor], x: Tensor, v: Tensor) -> Tensor:
    """(∂fn/∂x) v, per sample."""
    return jvp(fn, (x,), (v,))[1]


def jacobian(fn: Callable[[Tensor], Tensor], x: Tensor) -> Tensor:
    """Per-sample Jacobian (..., n, m) of fn: (..., m) -> (..., n), one jvp per input coordinate."""
    m = x.shape[-1]
    eye = torch.eye(m, dtype=x.dtype, device=x.device).reshape(m, *([1] * (x.dim() - 1)), m).expand(m, *x.shape)
    cols = vmap(lambda t: jvp(fn, (x,), (t,))[1])(eye)  # (m, ..., n)
    return cols.movedim(0, -1)


def second_directional(fn: Callable[[Tensor], Tensor], x: Tensor, v: Tensor) -> Tensor:
    """d²fn[v, v], i.e. J̇ẋ for a task map when v = ẋ."""
    return jvp(lambda z: jvp(fn, (z,), (v,))[1], (x,), (v,))[1]


def gradient(fn: Callable[[Tensor], Tensor], x: Tensor) -> Tensor:
    """Per-sample gradient (..., m) of a scalar-per-sample fn: (..., m) -> (...)."""
    out, pull = vjp(fn, x)[:2]  # (output, vjp function): torch's return type also covers has_aux's third item
    return pull(torch.ones_like(out))[0]
