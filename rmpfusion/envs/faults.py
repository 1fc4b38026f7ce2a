"""Fault isolation for batched rollouts: one sample's numerical fault ends that sample, not the batch.

An RMPTree refuses to return a non-finite acceleration (it raises ``NumericalError`` naming the node), which
is right for a controller but would end a whole batched rollout because of one bad sample. ``IsolatingPolicy``
wraps a policy for the length of one rollout: when a call raises a ``FloatingPointError`` it finds the samples
at fault (from the error's ``samples``, else by evaluating the samples one by one), answers NaN for them (the
rollout then ends them and records why) and evaluates the others normally. A faulted sample stays faulted:
its rows are replaced by a healthy sample's inputs before every later call and answered with NaN.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from typing import Any

import torch
from torch import Tensor


class IsolatingPolicy:
    """``policy`` with per-sample fault isolation; ``reason(b)`` is why sample ``b`` faulted (None if it did not)."""

    def __init__(self, policy: Callable[..., Any]):
        self.policy = policy
        self.reasons: dict[int, str] = {}
        self._template: Any = None  # the last full answer: its structure when no sample can be evaluated

    def reason(self, b: int) -> str | None:
        return self.reasons.get(b)

    def explain(self, b: int, what: str) -> str:
        """The rollout's error text for sample ``b``: ``what`` happened, and why if the policy said so."""
        why = self.reasons.get(b)
        return f"{what}: policy raised {why}" if why else what

    def __call__(self, q: Tensor, qd: Tensor, aux: Mapping[str, Tensor]):
        B = q.shape[0]
        for _ in range(B + 1):  # every round either answers or marks at least one more sample as faulted
            bad = sorted(self.reasons)
            if len(bad) >= B:
                return self._all_nan(q)
            qq, qqd, aa = _replace_rows(q, qd, aux, bad)
            try:
                out = self.policy(qq, qqd, aa)
            except FloatingPointError as e:
                new = [
                    int(s)
                    for s in (getattr(e, "samples", None) or [])
                    if int(s) not in self.reasons and 0 <= int(s) < B
                ]
                if not new:
                    new = self._find_faulty(q, qd, aux, bad)
                if not new:
                    raise  # the batch fails but no sample alone does: not a per-sample fault
                for s in new:
                    self.reasons[s] = f"{type(e).__name__}: {e}"
                continue
            self._template = out
            return _nan_rows(out, bad, B) if bad else out
        raise RuntimeError("IsolatingPolicy: could not isolate the faulting samples")  # pragma: no cover

    def _find_faulty(self, q: Tensor, qd: Tensor, aux: Mapping[str, Tensor], bad: list[int]) -> list[int]:
        found = []
        for b in range(q.shape[0]):
            if b in self.reasons:
                continue
            try:
                self.policy(q[b : b + 1], qd[b : b + 1], _rows(aux, q.shape[0], slice(b, b + 1)))
            except FloatingPointError:
                found.append(b)
        return found

    def _all_nan(self, q: Tensor):
        nan = torch.full_like(q, float("nan"))
        if self._template is None or isinstance(self._template, Tensor):
            return nan
        return _nan_rows(self._template, list(range(q.shape[0])), q.shape[0])


def _rows(aux: Mapping[str, Tensor], B: int, index) -> dict[str, Tensor]:
    return {k: (v[index] if torch.is_tensor(v) and v.dim() > 0 and v.shape[0] == B else v) for k, v in aux.items()}


def _replace_rows(q: Tensor, qd: Tensor, aux: Mapping[str, Tensor], bad: list[int]):
    """Inputs with the faulted samples' rows replaced by the first healthy sample's rows."""
    if not bad:
        return q, qd, aux
    B = q.shape[0]
    src = next(b for b in range(B) if b not in set(bad))
    idx = torch.arange(B)
    idx[bad] = src
    return q[idx], qd[idx], _rows(aux, B, idx)


def _nan_rows(out: Any, bad: list[int], B: int):
    """``out`` (a tensor or a dataclass of tensors such as TreeOutput) with the rows ``bad`` set to NaN."""
    mask = torch.zeros(B, dtype=torch.bool)
    mask[bad] = True

    def nanned(t):
        if not torch.is_tensor(t) or t.dim() == 0 or t.shape[0] != B or not t.is_floating_point():
            return t
        m = mask.to(t.device).view(B, *([1] * (t.dim() - 1)))
        return torch.where(m, torch.full_like(t, float("nan")), t)

    if torch.is_tensor(out):
        return nanned(out)
    if dataclasses.is_dataclass(out) and not isinstance(out, type):
        return dataclasses.replace(
            out,
            **{
                f.name: nanned(getattr(out, f.name))
                for f in dataclasses.fields(out)
                if torch.is_tensor(getattr(out, f.name))
            },
        )
    return out
