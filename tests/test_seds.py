"""SEDS, the stable Gaussian-mixture baseline: its stability holds for any parameter values (checked on rollouts
against the Lyapunov bound it implies), its EM start recovers a linear system it was fitted to, EM never lowers the
likelihood, and training starts from the EM fit."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg
import torch

from rmpfusion.envs.demonstrations import Dataset
from rmpfusion.learn.config import BCParams
from rmpfusion.learn.gmm import fit_mixture, phase_assignment
from rmpfusion.learn.train import train
from rmpfusion.registry import LEARNERS


def learner(**params):
    entry = LEARNERS.get("seds")
    return entry.obj(entry.validate({"scale": 0.5, **params}), None, {"goal": 2}, 2)


def randomised(seed: int, **params):
    """A SEDS learner with every parameter drawn at random (far from any fitted value)."""
    m = learner(**params)
    gen = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for p in m.parameters():
            p.copy_(torch.randn(p.shape, generator=gen, dtype=p.dtype))
    return m


def dataset(q: np.ndarray, qd: np.ndarray, t: np.ndarray, traj: np.ndarray, goal: np.ndarray) -> Dataset:
    as_t = lambda a: torch.as_tensor(a, dtype=torch.float64)
    n = len(q)
    return Dataset(
        q=as_t(q),
        qd=as_t(qd),
        aux={"goal": as_t(np.broadcast_to(goal, q.shape).copy())},
        qdd=torch.zeros(n, 2, dtype=torch.float64),
        env_id=torch.zeros(n, dtype=torch.long),
        traj_id=torch.as_tensor(traj, dtype=torch.long),
        t=as_t(t),
    )


def linear_demonstrations(A: np.ndarray, goal: np.ndarray, starts: np.ndarray, seconds: float = 4.0) -> Dataset:
    """Samples of x(t) = g + e^{At}(x0 − g) and ẋ = A(x − g) from each start, 100 per demonstration."""
    t = np.linspace(0.0, seconds, 100)
    qs, qds, ts, trajs = [], [], [], []
    for i, x0 in enumerate(starts):
        x = goal + np.stack([scipy.linalg.expm(A * s) @ (x0 - goal) for s in t])
        qs.append(x), qds.append((x - goal) @ A.T), ts.append(t), trajs.append(np.full(len(t), i))
    return dataset(np.vstack(qs), np.vstack(qds), np.concatenate(ts), np.concatenate(trajs), goal)


@pytest.mark.parametrize("seed", range(4))
def test_every_component_contracts_whatever_the_parameters(seed):
    m = randomised(seed, margin=0.05)
    A = m.matrices().detach()
    assert float(torch.linalg.eigvalsh(A + A.transpose(-1, -2)).max()) <= -2 * 0.05 + 1e-12
    gen = torch.Generator().manual_seed(100 + seed)
    goal = torch.randn(1, 2, generator=gen, dtype=torch.float64).expand(256, 2)
    x = goal + 3.0 * torch.randn(256, 2, generator=gen, dtype=torch.float64)
    f = m.field(x, {"goal": goal}).detach()
    assert bool(((x - goal) * f).sum(-1).lt(0).all())  # V = |x − g|² falls everywhere but at the goal
    assert float(m.field(goal[:1], {"goal": goal[:1]}).detach().abs().max()) == 0.0


@pytest.mark.parametrize("seed", range(3))
def test_rollouts_of_a_random_model_fall_at_least_as_fast_as_the_margin_promises(seed):
    """nᵀA_k n ≤ −ε|n|² for every component, so |n(t)|² ≤ |n(0)|² e^{−2εt}: checked along RK4 rollouts."""
    eps = 0.3
    m = randomised(seed, margin=eps)
    gen = torch.Generator().manual_seed(200 + seed)
    goal = {"goal": torch.zeros(64, 2, dtype=torch.float64)}
    x = 4.0 * torch.randn(64, 2, generator=gen, dtype=torch.float64)
    s = m.params.scale
    v0, dt = ((x / s) ** 2).sum(-1), 1e-2
    with torch.no_grad():
        for step in range(1, 1001):  # 10 s
            k1 = m.field(x, goal)
            k2 = m.field(x + 0.5 * dt * k1, goal)
            k3 = m.field(x + 0.5 * dt * k2, goal)
            k4 = m.field(x + dt * k3, goal)
            x = x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
            v = ((x / s) ** 2).sum(-1)
            assert bool((v <= v0 * np.exp(-2 * eps * step * dt) * (1 + 1e-6) + 1e-300).all()), step
    assert float(v.max() / v0.max()) < np.exp(-6)


def test_the_em_start_recovers_the_linear_system_the_demonstrations_came_from():
    A = np.array([[-0.8, 1.5], [-1.1, -0.5]])  # A + Aᵀ ≺ 0: meets SEDS's condition, so nothing is clipped
    goal = np.array([0.3, -0.2])
    data = linear_demonstrations(A, goal, np.array([[2.0, 1.0], [-1.5, 2.5], [1.0, -2.0]]))
    m = learner(components=3)
    m.initialise(data)
    gen = torch.Generator().manual_seed(5)
    x = torch.as_tensor(goal) + 3.0 * torch.randn(50, 2, generator=gen, dtype=torch.float64)  # off the data too
    g = {"goal": torch.as_tensor(goal).expand(50, 2)}
    expected = (x - g["goal"]) @ torch.as_tensor(A).T
    torch.testing.assert_close(m.field(x, g).detach(), expected, rtol=1e-4, atol=1e-6)


def test_em_never_lowers_the_likelihood_and_finds_separated_clusters():
    rng = np.random.default_rng(0)
    centres = np.array([[0.0, 0.0], [5.0, 0.0], [0.0, 5.0]])
    x = np.vstack([c + 0.5 * rng.standard_normal((200, 2)) for c in centres])
    wrong_start = np.tile(np.arange(3), 200)  # every cluster seeds every component equally: EM must untangle them
    mix = fit_mixture(x, wrong_start, 3, regularisation=0.0)
    gains = np.diff(mix.log_likelihood)
    assert (gains >= -1e-12).all() and gains.sum() > 0.5
    found = sorted(map(tuple, np.round(mix.means)))
    assert found == sorted(map(tuple, centres))


def test_phase_assignment_cuts_each_demonstration_into_equal_stretches():
    t = np.concatenate([np.linspace(0, 1, 11), np.linspace(2, 6, 5)])
    traj = np.array([0] * 11 + [1] * 5)
    assert phase_assignment(t, traj, 2).tolist() == [0] * 5 + [1] * 6 + [0, 0, 1, 1, 1]


def test_training_starts_from_the_em_fit():
    A = np.array([[-1.0, 0.7], [-0.7, -1.0]])
    data = linear_demonstrations(A, np.zeros(2), np.array([[2.0, 0.0], [0.0, 2.0]]))
    fitted = learner(components=2)
    fitted.initialise(data)
    m = learner(components=2)
    res = train(m, data, BCParams(iterations=1, snapshots=[0], lr=1e-3, batch_size=16), seed=0)
    for name, value in fitted.state_dict().items():
        torch.testing.assert_close(res.snapshots[0][name].to(value), value)
