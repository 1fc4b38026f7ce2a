"""Shared test helpers: float64 everywhere, finite differences, wandb never online."""
import os

import pytest
import torch

os.environ.setdefault("WANDB_MODE", "disabled")
os.environ.setdefault("MPLBACKEND", "Agg")

torch.set_default_dtype(torch.float64)
# small batched linear algebra is dominated by thread hand-off on a 2-core machine
torch.set_num_threads(1)


def fd_jacobian(fn, x: torch.Tensor, eps: float = 1e-6) -> torch.Tensor:
    """Central-difference per-sample Jacobian (B, n, m) of a batched fn: (B, m) -> (B, n)."""
    cols = []
    for k in range(x.shape[1]):
        e = torch.zeros_like(x)
        e[:, k] = eps
        cols.append((fn(x + e) - fn(x - e)) / (2 * eps))
    return torch.stack(cols, dim=-1)


def fd_directional(fn, x: torch.Tensor, v: torch.Tensor, eps: float = 1e-6) -> torch.Tensor:
    return (fn(x + eps * v) - fn(x - eps * v)) / (2 * eps)


@pytest.fixture
def gen():
    return torch.Generator().manual_seed(1234)
