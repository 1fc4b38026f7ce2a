"""Reported numbers recomputed by independent formulas, and checks that hold at every record, not at some.

Each test here is written so that a plausible one-line slip in the code it covers makes it fail: a monitor that
accepts a trajectory when any step (not every step) is non-increasing, a certificate that accepts a zero weight, a
dataset loss or training loss normalised by the wrong count, the time-out distance read from the wrong record,
minibatches that never draw some sample. ``tools/mutants.py`` applies exactly those slips and checks that these
tests fail on each.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from torch import nn

import rmpfusion
from rmpfusion.envs.demonstrations import Dataset
from rmpfusion.evaluate import certify, lyapunov_monotone, max_relative_increase
from rmpfusion.learn.objectives import dataset_loss, make_objective
from rmpfusion.learn.train import TrainConfig, train
from rmpfusion.weights.neural import MLPWeight

F64 = torch.float64


# ---------------------------------------------------------------- the Lyapunov monitor


def test_lyapunov_monitor_fails_a_trajectory_that_rises_at_one_record_among_many():
    """Theorem 2 holds at every record: one rise among many decreasing steps fails the whole trajectory."""
    T = 12
    falling = torch.linspace(2.0, 1.0, T, dtype=F64)
    one_rise = falling.clone()
    one_rise[7] = one_rise[6] * 1.01  # +1 % between records 6 and 7, every other step falls
    rise_at_end = falling.clone()
    rise_at_end[-1] = falling[-2] + 1e-3
    V = torch.stack([falling, one_rise, rise_at_end], dim=1)  # (T, B)
    assert lyapunov_monotone(V).tolist() == [True, False, False]
    inc = max_relative_increase(V)
    assert inc[0] <= 0 and inc[1] == pytest.approx(0.01 / 1.01, rel=1e-6) and inc[2] > 0


def test_lyapunov_monitor_agrees_with_a_direct_comparison_on_random_series():
    """The monitor's verdict equals the rule of evaluate/lyapunov.py's docstring applied record by record."""
    g = torch.Generator().manual_seed(0)
    steps = -torch.rand(30, 64, generator=g, dtype=F64)
    rises = torch.rand(30, 64, generator=g, dtype=F64) < 0.02  # about half the trajectories rise once or more
    V = 10.0 + (steps + rises * 0.5).cumsum(0)
    rtol, atol = 1e-6, 1e-9
    direct = []
    for b in range(V.shape[1]):
        v = V[:, b].tolist()
        direct.append(all(v[t + 1] - v[t] <= atol + rtol * max(abs(v[t]), abs(v[t + 1])) for t in range(len(v) - 1)))
    assert 0 < sum(direct) < len(direct)
    assert lyapunov_monotone(V, rtol=rtol, atol=atol).tolist() == direct


# ---------------------------------------------------------------- the certificate


def _tree_with_one_weight_exactly_zero():
    """A 2-D tree whose goal edge has an MLP weight pushed to exactly 0 (its floor removed, as a plugin's weight
    function might lack one, and softplus of −1e4 underflowing to 0.0), while a weightless identity leaf keeps M_r
    positive definite and the energy identity holds."""
    spec = {
        "root": {"name": "q", "dim": 2},
        "aux": {"goal": 2},
        "nodes": {
            "goal": {
                "parent": "q",
                "map": {"type": "offset", "origin": "goal"},
                "weight": {"type": "mlp", "hidden": [4], "positivity": "softplus", "aux": ["goal"]},
                "rmp": {"type": "goal_attractor"},
            },
            "regulariser": {"parent": "q", "map": {"type": "identity"}, "rmp": {"type": "identity_metric"}},
        },
    }
    tree = rmpfusion.build_tree(spec).to(F64)
    (weight,) = [m for m in tree.modules() if isinstance(m, MLPWeight)]
    weight.floor = 0.0
    last = weight.layers[-1]
    with torch.no_grad():
        last.weight.zero_()
        last.bias.fill_(-1e4)
    return tree


def test_certificate_rejects_a_weight_that_is_exactly_zero():
    """Theorem 2 asks w > 0: a zero weight (still ≥ 0) must fail the certificate, even with M_r ≻ 0."""
    tree = _tree_with_one_weight_exactly_zero()
    g = torch.Generator().manual_seed(1)
    q, qd = torch.randn(5, 2, generator=g, dtype=F64), torch.randn(5, 2, generator=g, dtype=F64)
    aux = {"goal": torch.randn(5, 2, generator=g, dtype=F64)}
    out = tree(q, qd, aux, return_nodes=True)
    assert (out.nodes["edge"]["goal"].w == 0).all()  # the premise of this test: exactly zero, not tiny
    cert = certify(tree, q, qd, aux)
    assert cert.min_weight == 0.0
    assert cert.inertia_positive_definite and cert.energy_identity_holds  # only the weights are wrong
    assert not cert.weights_positive and not cert.ok


# ---------------------------------------------------------------- losses


class _Fixed(nn.Module):
    """A model answering a fixed table of accelerations per sample index (read from q[:, 0]); one parameter that
    receives zero gradient, so training steps leave it, and its answers, unchanged."""

    def __init__(self, answers: torch.Tensor):
        super().__init__()
        self.answers = answers
        self.p = nn.Parameter(torch.zeros(()))

    def forward(self, q, qd, aux):
        return self.answers[q[:, 0].round().long()] + 0.0 * self.p


def _indexed_dataset(targets: torch.Tensor) -> Dataset:
    """N samples whose q[:, 0] is the sample's index and whose expert labels are ``targets`` (N, d)."""
    n, d = targets.shape
    q = torch.zeros(n, d, dtype=F64)
    q[:, 0] = torch.arange(n, dtype=F64)
    return Dataset(
        q=q,
        qd=torch.zeros(n, d, dtype=F64),
        aux={},
        qdd=targets,
        env_id=torch.zeros(n, dtype=torch.long),
        traj_id=torch.arange(n),
        t=torch.zeros(n, dtype=F64),
    )


def test_dataset_loss_is_the_mean_squared_error_over_every_entry():
    """batch-loss and the validation loss: the mean over samples AND coordinates, whatever the chunking."""
    rng = np.random.default_rng(0)
    targets, answers = rng.normal(size=(37, 3)), rng.normal(size=(37, 3))
    data = _indexed_dataset(torch.tensor(targets))
    model = _Fixed(torch.tensor(answers))
    expected = float(np.mean((answers - targets) ** 2))
    for chunk in (4096, 10, 1):
        assert dataset_loss(model, data, chunk=chunk) == pytest.approx(expected, rel=1e-12)


def test_training_loss_is_the_minibatch_mean_and_minibatches_reach_every_sample():
    """The loss behavior cloning reports at every step is the mean squared error of that step's minibatch, and
    minibatches are drawn uniformly from all N samples (the last one included).

    Sample i's expert label is i on each of its 3 coordinates and the model answers 0, so a minibatch of one
    sample i has loss i²: a summed loss would read 3·i², and the step's loss names the sample it drew."""
    n, d, steps = 5, 3, 400
    data = _indexed_dataset(torch.arange(n, dtype=F64)[:, None].repeat(1, d))
    model = _Fixed(torch.zeros(n, d, dtype=F64))
    cfg = TrainConfig(
        optimizer="sgd",
        lr=1e-3,
        batch_size=1,
        iterations=steps,
        snapshots=[steps],
        checkpoint_every=steps,
        log_every=steps,
    )
    res = train(model, data, cfg, seed=0)
    losses = [v for _, v in res.curve]
    assert len(losses) == steps
    drawn = [math.sqrt(v) for v in losses]
    assert all(abs(i - round(i)) < 1e-12 for i in drawn), sorted(set(losses))
    counts = np.bincount([round(i) for i in drawn], minlength=n)
    assert len(counts) == n and (counts > 0).all(), counts
    # uniform: each of the 5 samples is drawn 80 ± 4σ (σ ≈ 8) times in 400 draws
    assert (abs(counts - steps / n) < 4 * math.sqrt(steps / n * (1 - 1 / n))).all(), counts


def test_the_minibatch_loss_and_the_dataset_loss_are_the_same_quantity():
    """A minibatch holding the whole dataset (with replacement) and dataset_loss agree with the same formula."""
    rng = np.random.default_rng(1)
    targets, answers = rng.normal(size=(6, 4)), rng.normal(size=(6, 4))
    pred, target = torch.tensor(answers), torch.tensor(targets)
    assert float(make_objective("mse")(pred, target)) == pytest.approx(
        float(np.mean((answers - targets) ** 2)), rel=1e-12
    )
    data, model = _indexed_dataset(target), _Fixed(pred)
    assert dataset_loss(model, data) == pytest.approx(float(make_objective("mse")(pred, target)), rel=1e-12)


# ---------------------------------------------------------------- the Franka: time-out distance and Theorem 2

pybullet = pytest.importorskip("pybullet")


@pytest.fixture(scope="module")
def franka_1khz():
    from manipulators import franka_env

    env = franka_env(control_rate=1000.0)
    yield env
    env.close()


def _learner0(env):
    """learner-0 of experiment=franka: the tree with every weight network at its random initialisation."""
    import yaml
    from manipulators import CONF, franka_tree_spec

    from rmpfusion.learn.rmp_learner import RMPLearner

    torch.manual_seed(0)
    expert = yaml.safe_load((CONF / "expert" / "franka.yaml").read_text())
    return RMPLearner(
        RMPLearner.Params(weights={"type": "mlp", "hidden": [32, 32], "aux": ["goal"], "positivity": "exp"}),
        franka_tree_spec(1),
        env.aux_dims(),
        7,
        expert=expert,
    ).tree.to(F64)


def test_learner_rollout_on_the_franka_never_raises_V_at_any_record_at_1khz(franka_1khz):
    """Theorem 2 at the evaluation's own 1 kHz, for a learner's tree (learner-0's random positive weights): V_r
    recorded at every control step (1 ms) never rises by more than 1e-6 relative, at EVERY record."""
    env = franka_1khz
    tree = _learner0(env)
    g = torch.Generator().manual_seed(3)
    q0, qd0, aux = env.sample_initial_states(env.sample_envs(1, g), 2, g)
    qd0 = qd0 + 0.5 * torch.randn(qd0.shape, generator=g, dtype=F64)  # moving from the start: V has work to do
    with torch.no_grad():
        ro = env.rollout(tree, q0, qd0, aux, horizon=0.25, record_every=0.001)
    assert ro.error == [None, None] and ro.V.shape == (251, 2)
    V = ro.V
    assert (V[-1] < V[0] * 0.999).all()  # V falls: the check below is not about a robot at rest
    rise = V[1:] - V[:-1]
    allowed = 1e-6 * torch.maximum(V[1:].abs(), V[:-1].abs()) + 1e-9
    assert (rise <= allowed).all(), f"V rose at records {torch.nonzero(rise > allowed).tolist()}"
    assert lyapunov_monotone(V, rtol=1e-6).all(), max_relative_increase(V)


def test_time_out_goal_distance_is_the_last_record_recomputed_from_the_kinematics(franka_1khz):
    """The time-out distance is |ee(q at the time-out) − goal| from the robot's forward kinematics (independent of
    the rollout's own record), and it differs from the record before it on a moving arm."""
    from rmpfusion.envs.manipulator.metrics import task_metrics

    env = franka_1khz
    tree = _learner0(env)
    g = torch.Generator().manual_seed(4)
    q0, qd0, aux = env.sample_initial_states(env.sample_envs(1, g), 2, g)
    with torch.no_grad():
        ro = env.rollout(tree, q0, qd0, aux, horizon=0.2, record_every=0.05)
    m = task_metrics(ro, F64)
    at_timeout = (env.ee_position(ro.q[-1]) - aux["goal"]).norm(dim=-1)
    before = (env.ee_position(ro.q[-2]) - aux["goal"]).norm(dim=-1)
    assert ((at_timeout - before).abs() > 1e-4).all()  # the last two records tell apart
    torch.testing.assert_close(m["timeout_goal_distance"], at_timeout, rtol=1e-9, atol=1e-12)
    closest = torch.stack([(env.ee_position(q) - aux["goal"]).norm(dim=-1) for q in ro.q]).min(0).values
    torch.testing.assert_close(m["min_goal_distance"], closest, rtol=1e-9, atol=1e-12)
