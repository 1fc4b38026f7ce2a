"""A stability certificate for a tree at given states (Theorem 2), usable after training.

For each state it checks the theorem's premises and conclusion directly, not through a rollout:
  - the tree's outputs are finite there,
  - every edge weight is positive (and finite),
  - the root inertia M_r is positive definite (smallest eigenvalue of its symmetric part above ``pd_rtol``
    times its largest: a numerically singular M_r is not certified, since resolve cannot be trusted there),
  - dV_r/dt along q̈ = π(q, q̇), by a central difference in time, equals −q̇ᵀB_r q̇ ≤ 0.

Theorem 2 holds for maps that are only once differentiable where their pieces meet (a box's distance between the
regions of its faces, edges and corners: its curvature term jumps there), on either side of the seam; a central
difference whose stencil straddles such a seam averages the two sides' rates and misses the identity by a finite
amount however small the step. A state that misses it is therefore checked again with a 10 and a 100 times narrower
stencil (``REFINE``), and passes where one of them meets it: a tree that breaks the identity misses it at every
width, while a state within about one step of a seam along the flow meets it at a narrower one.

``certify`` takes a batch of states; ``certify_rollout`` takes the records of a rollout.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field
from typing import Any

import torch
from torch import Tensor

from ..core.gds import quad
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
    non_finite_states: list[int] = field(default_factory=list)  # the tree's outputs are NaN/inf there

    @property
    def ok(self) -> bool:
        return (
            self.weights_positive
            and self.inertia_positive_definite
            and self.energy_identity_holds
            and self.dissipative
            and not self.non_finite_states
        )

    def as_dict(self) -> dict:
        return {**asdict(self), "ok": self.ok}

    def summary(self) -> str:
        mark = lambda b: "ok  " if b else "FAIL"
        return "\n".join(
            [
                f"stability certificate over {self.states} states: {'PASSED' if self.ok else 'FAILED'}",
                f"  [{mark(not self.non_finite_states)}] outputs finite           ({len(self.non_finite_states)} states not)",
                f"  [{mark(self.weights_positive)}] weights positive         (min w = {self.min_weight:.3e})",
                f"  [{mark(self.inertia_positive_definite)}] M_r positive definite    (min eig = {self.min_inertia_eigenvalue:.3e})",
                f"  [{mark(self.energy_identity_holds)}] dV/dt = -qd'B qd         (max rel. error = {self.max_energy_identity_error:.3e})",
                f"  [{mark(self.dissipative)}] qd'B qd >= 0",
                *([f"  non-finite states: {self.non_finite_states[:20]}"] if self.non_finite_states else []),
                *([f"  failing states: {self.failing_states[:20]}"] if self.failing_states else []),
            ]
        )


#: how many times narrower the stencils are with which a state that misses the energy identity is checked again
REFINE = (10.0, 100.0)


def _identity_error(tree: RMPTree, q: Tensor, qd: Tensor, qdd: Tensor, aux: Any, diss: Tensor, eps: float) -> Tensor:
    """|dV/dt + q̇ᵀBq̇| relative to 1 + |q̇ᵀBq̇| per state, dV/dt by a central difference of step ``eps`` along
    (q̇, q̈)."""
    Vp = tree(q + eps * qd, qd + eps * qdd, aux).V
    Vm = tree(q - eps * qd, qd - eps * qdd, aux).V
    return ((Vp - Vm) / (2 * eps) + diss).abs() / (1 + diss.abs())


def _per_sample(v: Any, q: Tensor) -> bool:
    """An aux entry given per state (one row each), as opposed to one row shared by every state."""
    return isinstance(v, Tensor) and v.dim() >= 1 and v.shape[0] == q.shape[0]


def _nanmin(x: Tensor) -> float:
    x = x[torch.isfinite(x)]
    return float(x.min()) if x.numel() else float("nan")


def certify(
    tree: RMPTree, q: Tensor, qd: Tensor, aux=None, eps: float = 1e-6, rtol: float = 1e-5, pd_rtol: float | None = None
) -> Certificate:
    """Check Theorem 2's premises and identity at every state of the batch (float64 recommended).

    ``pd_rtol`` (default 100·machine epsilon of the tree's dtype) is how far above zero, relative to the
    largest eigenvalue, the smallest eigenvalue of M_r must be. States where the tree's outputs are not
    finite are listed in ``non_finite_states`` (and fail) instead of raising.
    """
    if pd_rtol is None:
        pd_rtol = 100 * torch.finfo(q.dtype).eps
    was = tree.check_finite
    tree.check_finite = False  # every state gets a verdict; a NaN is a failing state here, not an exception
    try:
        with torch.no_grad(), warnings.catch_warnings():
            warnings.simplefilter("ignore")  # singular M_r is reported below as not positive definite
            out = tree(q, qd, aux, return_nodes=True)
            ws = [e.w for e in out.nodes["edge"].values() if e.w is not None]
            w_all = torch.stack(ws, dim=1) if ws else q.new_ones(q.shape[0], 1)
            finite = torch.ones(q.shape[0], dtype=torch.bool)
            for t in (out.qdd, out.f, out.M, out.B, out.V, w_all):
                finite &= torch.isfinite(t).reshape(t.shape[0], -1).all(-1)
            w_ok = torch.isfinite(w_all).all(1) & (w_all > 0).all(1)
            Msym = 0.5 * (out.M + out.M.transpose(-1, -2))
            Msym = torch.where(finite[:, None, None], Msym, torch.eye(q.shape[1], dtype=q.dtype))
            eigs = torch.linalg.eigvalsh(Msym)
            eig = eigs[:, 0]
            pd = (eig > pd_rtol * eigs.abs().amax(-1)) & finite
            qdd = torch.where(finite[:, None], out.qdd, torch.zeros_like(out.qdd))
            diss = quad(qd, out.B)
            err = _identity_error(tree, q, qd, qdd, aux, diss, eps)
            for factor in REFINE:  # a stencil across a seam of a once-differentiable map: narrower ones (above)
                missed = ((err > rtol) & finite).nonzero().flatten()
                if not len(missed):
                    break
                sub = {k: v[missed] if _per_sample(v, q) else v for k, v in aux.items()} if aux else aux
                err_narrow = _identity_error(tree, q[missed], qd[missed], qdd[missed], sub, diss[missed], eps / factor)
                err[missed] = torch.minimum(err[missed], err_narrow)
    finally:
        tree.check_finite = was
    ident = (err <= rtol) & finite
    dissipative = (diss >= -1e-12 * (1 + diss.abs())) & finite
    good = w_ok & pd & ident & dissipative & finite
    return Certificate(
        states=int(q.shape[0]),
        weights_positive=bool(w_ok.all()),
        min_weight=_nanmin(w_all),
        inertia_positive_definite=bool(pd.all()),
        min_inertia_eigenvalue=_nanmin(eig[finite]),
        energy_identity_holds=bool(ident.all()),
        max_energy_identity_error=float(err[finite].max()) if bool(finite.any()) else float("nan"),
        dissipative=bool(dissipative.all()),
        failing_states=[int(i) for i in (~good).nonzero().flatten()],
        non_finite_states=[int(i) for i in (~finite).nonzero().flatten()],
    )


#: states certified in one batch: bounds the memory of certifying a long rollout of many samples (a 7-joint tree's
#: intermediate tensors for 370,000 states took 22 GB at once)
CHUNK = 20_000


def certify_rollout(
    tree: RMPTree, rollout: Any, aux: Mapping[str, Tensor] | None = None, every: int = 1, **kwargs
) -> Certificate:
    """``certify`` at every ``every``-th recorded state of a rollout (``rollout.q``, ``rollout.qd``: (T, B, d)),
    ``CHUNK`` states at a time.

    ``aux`` is the rollout's per-sample aux state (B, k). Records of samples that ended early (NaN rows) are
    skipped. ``failing_states`` index the flattened time-major records: record ``i`` is time ``i // B``,
    sample ``i % B``.
    """
    q, qd = rollout.q, rollout.qd
    T, B, d = q.shape
    qf, qdf = q.reshape(T * B, d), qd.reshape(T * B, d)
    keep = torch.isfinite(qf).all(-1) & torch.isfinite(qdf).all(-1)
    keep &= (torch.arange(T * B) // B) % every == 0
    idx = keep.nonzero().flatten()
    parts = []
    for chunk in idx.split(CHUNK):
        rep = None
        if aux is not None:
            rep = {k: torch.as_tensor(v).expand(B, -1)[chunk % B] for k, v in aux.items()}
        cert = certify(tree, qf[chunk], qdf[chunk], rep, **kwargs)
        cert.failing_states = [int(chunk[i]) for i in cert.failing_states]
        cert.non_finite_states = [int(chunk[i]) for i in cert.non_finite_states]
        parts.append(cert)
    return merged(parts)


def merged(parts: list[Certificate]) -> Certificate:
    """One certificate of the states of several (each of its own states)."""
    if not parts:
        raise ValueError("no state to certify")
    return Certificate(
        states=sum(c.states for c in parts),
        weights_positive=all(c.weights_positive for c in parts),
        min_weight=min(c.min_weight for c in parts),
        inertia_positive_definite=all(c.inertia_positive_definite for c in parts),
        min_inertia_eigenvalue=min(c.min_inertia_eigenvalue for c in parts),
        energy_identity_holds=all(c.energy_identity_holds for c in parts),
        max_energy_identity_error=max(c.max_energy_identity_error for c in parts),
        dissipative=all(c.dissipative for c in parts),
        failing_states=[i for c in parts for i in c.failing_states],
        non_finite_states=[i for c in parts for i in c.non_finite_states],
    )
