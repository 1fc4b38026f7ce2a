"""Splitting demonstrations by whole demonstration: samples of one demonstration are strongly correlated, so a
split by sample would let the validation and test sets leak into training.

Two protocols: ``holdout`` (train / validation / test counts, drawn by a seeded permutation) and
``leave_one_out`` (fold k tests demonstration k and trains on the rest; with a validation demonstration taken
from the rest, the next one in cyclic order, so settings are never chosen on the test demonstration).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from .recording import RecordingError


@dataclass(frozen=True)
class Split:
    """Indices of demonstrations (into the list the readers returned) in each part."""

    train: tuple[int, ...]
    val: tuple[int, ...]
    test: tuple[int, ...]


def holdout(n: int, val: int, test: int, seed: int = 0) -> Split:
    """``val`` and ``test`` demonstrations drawn at random (seeded), the rest for training."""
    if val < 0 or test < 0 or n - val - test < 1:
        raise RecordingError(
            f"cannot split {n} demonstration(s) into {val} validation, {test} test and at least one "
            "for training; record more or lower data.val / data.test"
        )
    order = np.random.default_rng(seed).permutation(n)
    return Split(
        train=tuple(sorted(int(i) for i in order[val + test :])),
        val=tuple(sorted(int(i) for i in order[:val])),
        test=tuple(sorted(int(i) for i in order[val : val + test])),
    )


def leave_one_out(n: int, fold: int, with_validation: bool = True) -> Split:
    """Fold ``fold`` of ``n``: demonstration ``fold`` is the test set; with ``with_validation`` the next one
    (cyclically) is the validation set."""
    if not 0 <= fold < n:
        raise RecordingError(
            f"leave-one-out fold {fold} does not exist: there are {n} demonstrations (folds 0 to {n - 1})"
        )
    need = 3 if with_validation else 2
    if n < need:
        raise RecordingError(f"leave-one-out needs at least {need} demonstrations; there are {n}")
    val = ((fold + 1) % n,) if with_validation else ()
    train = tuple(i for i in range(n) if i != fold and i not in val)
    return Split(train=train, val=val, test=(fold,))


def split_of(d: Any, n: int, seed: int) -> Split:
    """Which of ``n`` demonstrations train, validate and test under a data block's ``split`` (holdout: ``val`` and
    ``test``, seeded; leave_one_out: ``fold``; all: every demonstration trains and tests, the protocol of most
    published LASA numbers)."""
    if d.split == "leave_one_out":
        return leave_one_out(n, d.fold)
    if d.split == "all":
        every = tuple(range(n))
        return Split(train=every, val=(), test=every)
    return holdout(n, d.val, d.test, seed)
