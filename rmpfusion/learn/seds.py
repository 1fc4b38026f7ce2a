"""SEDS, the Stable Estimator of Dynamical Systems (Khansari-Zadeh & Billard, IEEE T-RO 2011), as a baseline for
recorded demonstrations: the classic stable learner the LASA handwriting dataset was made for. Not an RMP tree.

The field is Gaussian mixture regression with SEDS's stability constraint built in. With n = (x − g)/scale,

    ṅ = Σ_k h_k(n) A_k n,    h_k(n) = π_k N(n; μ_k, Σ_k) / Σ_j π_j N(n; μ_j, Σ_j),    A_k + A_kᵀ ≺ 0,

which is GMR of a joint mixture over (n, ṅ) whose components satisfy SEDS's conditions (A_k = Σ_k^{ṅn}(Σ_k^n)⁻¹
with the velocity mean μ_k^ṅ = A_k μ_k, so the goal is an equilibrium). Then V(n) = |n|² is a Lyapunov function:
V̇ = 2 Σ_k h_k nᵀA_k n < 0 for n ≠ 0, and the goal is reached from everywhere. SEDS enforces the constraint in a
constrained optimiser; here it holds by construction, for any parameter values, by writing
A_k = −(B_k B_kᵀ + εI) + (S_k − S_kᵀ) with B_k, S_k free (ε the ``margin``), so gradient training cannot break it.

Fitting follows SEDS: a mixture of the joint (n, ṅ) training data by EM started from the demonstrations' phase
(``gmm.py``), each A_k taken from it and its symmetric part moved to the nearest matrix meeting the margin, then
the whole model trained by the run's training method (SEDS's mean-square objective on velocities; here the same
behavior cloning on accelerations as every learner, through the velocity tracking of ``velocity_tracking.py``,
which on a motion that follows the field is the same fit). The EM start is what snapshot 0 holds: SEDS's own
starting point, made from the training data, not random.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
import torch
from pydantic import Field
from torch import Tensor, nn

from ..envs.demonstrations import Dataset
from ..registry import LEARNERS
from .gmm import fit_mixture, phase_assignment
from .velocity_tracking import TrackedField, TrackedFieldParams


def _strictly_lower(m: Tensor) -> Tensor:
    return torch.tril(m, diagonal=-1)


def _cholesky_with_log_diagonal(raw: Tensor) -> Tensor:
    """A Cholesky factor from free numbers: the strictly lower triangle as given, the diagonal as exp(raw)."""
    return _strictly_lower(raw) + torch.diag_embed(torch.diagonal(raw, dim1=-2, dim2=-1).exp())


@LEARNERS.register("seds")
class SedsLearner(TrackedField["SedsLearner.Params"]):
    """ẋ = scale·Σ_k h_k(n) A_k n with A_k + A_kᵀ ≼ −2εI, n = (x − goal)/scale; tracked like every first-order
    baseline."""

    kind = "seds"

    class Params(TrackedFieldParams):
        components: int = Field(
            10,
            ge=1,
            le=32,
            description="K, the Gaussians of the mixture (10: chosen on LASA's validation among 3, 6, 10)",
        )
        margin: float = Field(
            0.01, gt=0, le=100, description="ε (1/s, normalised units): every A_k + A_kᵀ is at most −2ε·I"
        )
        em_iterations: int = Field(100, ge=0, le=10000, description="EM rounds of the starting mixture")

    def __init__(
        self,
        params: Params,
        tree_spec: Mapping[str, Any] | None,
        aux_dims: Mapping[str, int],
        dim: int,
        expert: Mapping[str, Any] | None = None,
    ):
        super().__init__(params, tree_spec, aux_dims, dim, expert)
        k, f64 = params.components, torch.float64
        # before any data: K equal components at the goal, each A_k = −I (a stable field, replaced by `initialise`)
        self.logits = nn.Parameter(torch.zeros(k, dtype=f64))
        self.means = nn.Parameter(torch.zeros(k, dim, dtype=f64))
        self.covariance_factor = nn.Parameter(torch.zeros(k, dim, dim, dtype=f64))  # Σ_k = L_k L_kᵀ, log diagonal
        eye = torch.eye(dim, dtype=f64).expand(k, dim, dim)
        self.contraction = nn.Parameter(((1.0 - params.margin) ** 0.5 * eye).clone())  # B_k
        self.rotation = nn.Parameter(torch.zeros(k, dim, dim, dtype=f64))  # S_k

    def matrices(self) -> Tensor:
        """A_k (K, d, d): symmetric part −(B_k B_kᵀ + εI), antisymmetric part S_k − S_kᵀ."""
        B, S = torch.tril(self.contraction), _strictly_lower(self.rotation)
        eye = torch.eye(self.dim, dtype=B.dtype, device=B.device)
        return -(B @ B.transpose(-1, -2) + self.params.margin * eye) + (S - S.transpose(-1, -2))

    def _posterior(self, n: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """(h_k(n) (B, K), each component's posterior at the normalised position; the whitened offsets
        z_k = L_k⁻¹(n − μ_k) (B, K, d); the factors L_k, one per sample (B, K, d, d))."""
        L = _cholesky_with_log_diagonal(self.covariance_factor).expand(n.shape[0], -1, -1, -1)
        diff = (n.unsqueeze(1) - self.means).unsqueeze(-1)  # (B, K, d, 1)
        z = torch.linalg.solve_triangular(L, diff, upper=False).squeeze(-1)
        log_det = torch.diagonal(self.covariance_factor, dim1=-2, dim2=-1).sum(-1)  # ½ log det Σ_k
        log_joint = torch.log_softmax(self.logits, 0) - log_det - 0.5 * (z * z).sum(-1)
        return torch.softmax(log_joint, -1), z, L

    def _per_component(self, v: Tensor) -> Tensor:
        """A_k v for every component (B, K, d) of vectors v (B, d)."""
        return torch.einsum("kij,bj->bki", self.matrices().to(v), v)

    def field(self, q: Tensor, aux: Mapping[str, Tensor]) -> Tensor:
        n = self.normalised(q, aux)
        h = self._posterior(n)[0]
        return self.params.scale * (h.unsqueeze(-1) * self._per_component(n)).sum(1)

    def field_and_rate(self, q: Tensor, qd: Tensor, aux: Mapping[str, Tensor]) -> tuple[Tensor, Tensor]:
        """(f, (∂f/∂q)q̇) in closed form: with ṅ = q̇/scale and d/dt log N_k = −z_k·L_k⁻¹ṅ,
        ḣ_k = h_k (d/dt log N_k − Σ_j h_j d/dt log N_j), and (∂f/∂q)q̇ = Σ_k ḣ_k·scale·A_k n + h_k A_k q̇."""
        n, n_rate = self.normalised(q, aux), qd / self.params.scale
        h, z, L = self._posterior(n)
        rhs = n_rate[:, None, :, None].expand(-1, L.shape[1], -1, -1)  # ṅ for every component (B, K, d, 1)
        log_rate = -(z * torch.linalg.solve_triangular(L, rhs, upper=False).squeeze(-1)).sum(-1)  # (B, K)
        h_rate = h * (log_rate - (h * log_rate).sum(-1, keepdim=True))
        pull = self.params.scale * self._per_component(n)  # scale·A_k n (B, K, d)
        f = (h.unsqueeze(-1) * pull).sum(1)
        along = (h_rate.unsqueeze(-1) * pull).sum(1) + (h.unsqueeze(-1) * self._per_component(qd)).sum(1)
        return f, along

    def export_refusal(self) -> str | None:
        return None  # the closed-form derivative is plain tensor algebra

    def initialise(self, train: Dataset) -> None:
        """SEDS's start: EM on the joint (n, ṅ) training samples from the demonstrations' phase; π_k, μ_k and Σ_k
        of the position block, A_k = Σ_k^{ṅn}(Σ_k^n)⁻¹ with its symmetric part clipped to at most −2ε."""
        d, eps = self.dim, self.params.margin
        n = self.normalised(train.q, train.aux).detach().cpu().double().numpy()
        nd = (train.qd / self.params.scale).detach().cpu().double().numpy()
        seeds = phase_assignment(train.t.cpu().numpy(), train.traj_id.cpu().numpy(), self.params.components)
        mix = fit_mixture(np.hstack([n, nd]), seeds, self.params.components, self.params.em_iterations)
        cov_x, cov_vx = mix.covariances[:, :d, :d], mix.covariances[:, d:, :d]
        A = cov_vx @ np.linalg.inv(cov_x)
        sym, skew = 0.5 * (A + A.transpose(0, 2, 1)), 0.5 * (A - A.transpose(0, 2, 1))
        w, V = np.linalg.eigh(sym)
        clipped = V @ (np.minimum(w, -2 * eps)[..., None] * V.transpose(0, 2, 1))
        B = np.linalg.cholesky(-clipped - eps * np.eye(d))  # −clipped − εI ≽ εI: positive definite
        L = np.linalg.cholesky(cov_x)
        L_free = np.tril(L, -1) + np.eye(d) * np.log(np.diagonal(L, axis1=1, axis2=2))[:, None, :]
        with torch.no_grad():
            for param, value in (
                (self.logits, np.log(mix.priors)),
                (self.means, mix.means[:, :d]),
                (self.covariance_factor, L_free),
                (self.contraction, B),
                (self.rotation, np.tril(skew, -1)),
            ):
                param.copy_(torch.as_tensor(value, dtype=param.dtype))

    def describe(self) -> dict[str, Any]:
        return {"components": self.params.components}
