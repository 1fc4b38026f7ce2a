"""A Gaussian mixture fitted by expectation-maximisation, started from the demonstrations' phase.

SEDS (``seds.py``) starts from a mixture of the joint position-velocity data, as its authors' code does: each
demonstration is cut into K equal stretches of its duration and the k-th stretches of all demonstrations seed
component k, then EM refines the mixture. Starting from the phase (not from random centres) makes the fit a
deterministic function of the data, so a resumed run rebuilds the same starting point, and it places the
components in the order the motion visits them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Mixture:
    """K Gaussians in D dimensions: priors (K,), means (K, D), covariances (K, D, D); and the mean log-likelihood
    per sample after every EM iteration (the first entry is the phase start's)."""

    priors: np.ndarray
    means: np.ndarray
    covariances: np.ndarray
    log_likelihood: tuple[float, ...]


def phase_assignment(t: np.ndarray, trajectory: np.ndarray, components: int) -> np.ndarray:
    """The component (N,) each sample seeds: its demonstration's time since the start, in K equal stretches."""
    phase = np.empty_like(t, dtype=float)
    for traj in np.unique(trajectory):
        at = trajectory == traj
        span = t[at].max() - t[at].min()
        phase[at] = (t[at] - t[at].min()) / span if span > 0 else 0.0
    return np.minimum((phase * components).astype(int), components - 1)


def _log_densities(x: np.ndarray, means: np.ndarray, covariances: np.ndarray) -> np.ndarray:
    """log N(x_i; μ_k, Σ_k) (N, K), through each covariance's Cholesky factor."""
    n, d = x.shape
    out = np.empty((n, len(means)))
    for k, (mu, cov) in enumerate(zip(means, covariances, strict=True)):
        L = np.linalg.cholesky(cov)
        z = np.linalg.solve(L, (x - mu).T)
        out[:, k] = -0.5 * (z * z).sum(0) - np.log(np.diag(L)).sum() - 0.5 * d * np.log(2 * np.pi)
    return out


def _log_joint(x: np.ndarray, priors: np.ndarray, means: np.ndarray, covariances: np.ndarray) -> np.ndarray:
    return _log_densities(x, means, covariances) + np.log(priors)


def _responsibilities(log_joint: np.ndarray) -> tuple[np.ndarray, float]:
    """Posterior of each component per sample (N, K) and the mean log-likelihood per sample."""
    top = log_joint.max(1, keepdims=True)
    log_total = top[:, 0] + np.log(np.exp(log_joint - top).sum(1))
    return np.exp(log_joint - log_total[:, None]), float(log_total.mean())


def _m_step(x: np.ndarray, resp: np.ndarray, regularisation: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Priors, means and covariances (each with ``regularisation``·I added, so none collapses) from posteriors."""
    mass = resp.sum(0) + 1e-300
    means = (resp.T @ x) / mass[:, None]
    covariances = np.empty((len(mass), x.shape[1], x.shape[1]))
    for k in range(len(mass)):
        c = x - means[k]
        covariances[k] = (resp[:, k, None] * c).T @ c / mass[k] + regularisation * np.eye(x.shape[1])
    return mass / mass.sum(), means, covariances


def fit_mixture(
    x: np.ndarray, seed_component: np.ndarray, components: int, iterations: int = 100, regularisation: float = 1e-6
) -> Mixture:
    """EM on ``x`` (N, D) from hard assignments ``seed_component`` (N,): at most ``iterations`` rounds, stopping
    once the mean log-likelihood gains less than 1e-10 in one. An empty seed stretch cannot happen with every
    demonstration cut into ``components`` stretches, but is refused clearly if a caller seeds one."""
    seeded = np.bincount(seed_component, minlength=components)
    if (seeded == 0).any():
        raise ValueError(f"mixture components {np.flatnonzero(seeded == 0).tolist()} have no seed samples")
    priors, means, covariances = _m_step(x, np.eye(components)[seed_component], regularisation)
    resp, ll = _responsibilities(_log_joint(x, priors, means, covariances))
    history = [ll]
    for _ in range(iterations):
        priors, means, covariances = _m_step(x, resp, regularisation)
        resp, ll = _responsibilities(_log_joint(x, priors, means, covariances))
        history.append(ll)
        if history[-1] - history[-2] < 1e-10:
            break
    return Mixture(priors, means, covariances, tuple(history))
