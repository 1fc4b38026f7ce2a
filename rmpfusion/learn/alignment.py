"""Soft dynamic time warping (Cuturi & Blondel, ICML 2017): the cost of aligning a rollout with a demonstration
that moves at another speed, differentiable in both.

Dynamic time warping takes the least sum of pairwise costs over monotone alignments of the two sequences
(``evaluate/reproduction.py::dtw_distance`` reports it as a metric). Its minimum is not differentiable where two
alignments tie; soft-DTW replaces every min by the soft minimum −γ·log Σ exp(−x/γ), which is smooth and tends to
the hard minimum as γ → 0 (it is below it by at most γ·log 3 per cell). That is what lets a trajectory-matching
loss be back-propagated through a rollout (``learn/methods/match.py``) without first forcing the two onto one clock.

The table R[i, j] = c[i−1, j−1] + softmin(R[i−1, j], R[i, j−1], R[i−1, j−1]) is filled one anti-diagonal at a time
(the cells of one depend only on the two before it), so the Python loop runs N + M times, each step a batched
tensor operation. Cells outside the table hold a large finite number rather than ∞: a soft minimum over three ∞
has a NaN gradient, over three large numbers a zero one.
"""

from __future__ import annotations

import torch
from torch import Tensor

#: what stands for ∞ outside the table: far above any alignment cost, far below float32's overflow
OUTSIDE = 1.0e10


def soft_min(a: Tensor, b: Tensor, c: Tensor, gamma: float) -> Tensor:
    """−γ·log(e^(−a/γ) + e^(−b/γ) + e^(−c/γ)), elementwise."""
    return -gamma * torch.logsumexp(torch.stack([a, b, c]) / -gamma, dim=0)


def soft_dtw(cost: Tensor, lengths: Tensor, gamma: float) -> Tensor:
    """(B,) soft-DTW of every sample's cost table ``cost`` (B, N, M) (the cost of pairing row i of the first
    sequence with row j of the second), the first sequence of sample b being its first ``lengths[b]`` rows (≤ N;
    the rest is padding): the soft minimum over monotone alignments of (0, 0) with (lengths[b] − 1, M − 1)."""
    if not gamma > 0:
        raise ValueError(f"soft-DTW needs a smoothing gamma > 0; given {gamma}")
    B, N, M = cost.shape
    n = lengths.to(torch.long)
    if int(n.min()) < 1 or int(n.max()) > N:
        raise ValueError(f"lengths must be in 1..{N} (the rows of the cost table); given {n.tolist()}")
    i = torch.arange(1, N + 1, device=cost.device)  # the table's rows 1..N (row 0 is the boundary)
    edge = cost.new_full((B, 1), OUTSIDE)
    before = torch.cat([cost.new_zeros(B, 1), cost.new_full((B, N), OUTSIDE)], 1)  # diagonal 0: R[0, 0] = 0
    last = cost.new_full((B, N + 1), OUTSIDE)  # diagonal 1: R[0, 1], R[1, 0], outside
    diagonals = [before, last]
    for s in range(2, N + M + 1):
        j = s - i  # the column of row i on diagonal s
        inside = (j >= 1) & (j <= M)
        c = cost[:, i - 1, (j - 1).clamp(0, M - 1)]
        value = c + soft_min(last[:, :-1], last[:, 1:], before[:, :-1], gamma)
        before, last = last, torch.cat([edge, torch.where(inside, value, torch.full_like(value, OUTSIDE))], 1)
        diagonals.append(last)
    return torch.stack([diagonals[int(nb) + M][b, int(nb)] for b, nb in enumerate(n)])


def scaled_square_distances(x: Tensor, y: Tensor, scale: Tensor) -> Tensor:
    """(B, N, M) Σ_d ((x_bid − y_bjd) / scale_d)² of x (B, N, d) and y (B, M, d): each coordinate in units of its
    own spread, so that no coordinate dominates the alignment by its units alone."""
    return (((x[:, :, None, :] - y[:, None, :, :]) / scale) ** 2).sum(-1)
