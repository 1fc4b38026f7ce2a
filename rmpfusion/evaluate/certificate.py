"""A stability certificate for a tree at given states (Theorem 2), usable after training.

For each state it checks the theorem's premises and conclusion directly, not through a rollout:
  - every edge weight is positive (and finite),
  - the root inertia M_r is positive definite (smallest eigenvalue of its symmetric part),
  - dV_r/dt along q̈ = π(q, q̇), by a central difference in time, equals −q̇ᵀB_r q̇ ≤ 0.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import torch
from torch import Tensor

from ..core.tree import RMPTree


@dataclass
class Certificate:
    states: int
    weights_positive: bool
    min_weight: float
    inertia_positive_definite: bool
    min_inertia_eigenvalue: float
    energy_identity_holds: bool
    max_energy_identity_error: float  # |dV/dt + q̇ᵀBq̇| relative to 1 + |q̇ᵀBq̇|
    dissipative: bool  # q̇ᵀB_r q̇ ≥ 0 everywhere
    failing_states: list[int]

    @property
    def ok(self) -> bool:
        return self.weights_positive and self.inertia_positive_definite and self.energy_identity_holds and self.dissipative

    def as_dict(self) -> dict:
        return {**asdict(self), "ok": self.ok}

    def summary(self) -> str:
        mark = lambda b: "ok  " if b else "FAIL"  # noqa: E731
        return "\n".join([
            f"stability certificate over {self.states} states: {'PASSED' if self.ok else 'FAILED'}",
            f"  [{mark(self.weights_positive)}] weights positive         (min w = {self.min_weight:.3e})",
            f"  [{mark(self.inertia_positive_definite)}] M_r positive definite    (min eig = {self.min_inertia_eigenvalue:.3e})",
            f"  [{mark(self.energy_identity_holds)}] dV/dt = -qd'B qd         (max rel. error = {self.max_energy_identity_error:.3e})",
            f"  [{mark(self.dissipative)}] qd'B qd >= 0",
            *([f"  failing states: {self.failing_states[:20]}"] if self.failing_states else []),
        ])


def certify(tree: RMPTree, q: Tensor, qd: Tensor, aux=None, eps: float = 1e-6, rtol: float = 1e-5) -> Certificate:
    """Check Theorem 2's premises and identity at every state of the batch (float64 recommended)."""
    with torch.no_grad():
        out = tree(q, qd, aux, return_nodes=True)
        ws = [e.w for e in out.nodes["edge"].values() if e.w is not None]
        w_all = torch.stack(ws, dim=1) if ws else q.new_ones(q.shape[0], 1)
        w_ok = torch.isfinite(w_all).all(1) & (w_all > 0).all(1)
        Msym = 0.5 * (out.M + out.M.transpose(-1, -2))
        eig = torch.linalg.eigvalsh(Msym)[:, 0]
        pd = eig > 0
        was = tree.check_finite
        tree.check_finite = False
        try:
            Vp = tree(q + eps * qd, qd + eps * out.qdd, aux).V
            Vm = tree(q - eps * qd, qd - eps * out.qdd, aux).V
        finally:
            tree.check_finite = was
        dVdt = (Vp - Vm) / (2 * eps)
        diss = torch.einsum("bi,bij,bj->b", qd, out.B, qd)
        err = (dVdt + diss).abs() / (1 + diss.abs())
        ident = err <= rtol
        dissipative = diss >= -1e-12 * (1 + diss.abs())
    good = w_ok & pd & ident & dissipative
    return Certificate(
        states=int(q.shape[0]),
        weights_positive=bool(w_ok.all()),
        min_weight=float(w_all.min()),
        inertia_positive_definite=bool(pd.all()),
        min_inertia_eigenvalue=float(eig.min()),
        energy_identity_holds=bool(ident.all()),
        max_energy_identity_error=float(err.max()),
        dissipative=bool(dissipative.all()),
        failing_states=[int(i) for i in (~good).nonzero().flatten()],
    )
