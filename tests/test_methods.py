"""Training methods beyond behavior cloning, each held to an independent computation on a tiny problem:

- the registry: ``train.method`` selects a registered method, a plugin's included; a block without ``method`` is
  behavior cloning (every config, checkpoint and run directory written before methods existed);
- DAgger: the aggregated dataset grows by exactly the counted expert queries, each the expert's own q̈ at a state
  the learner visited; an interrupted run resumes to the uninterrupted weights;
- APG: the gradient it back-propagates through the simulator is the finite-difference slope of the task cost,
  and a few steps lower the cost;
- the policy gradient: its score-function estimate is unbiased, against the exact gradient of a tiny problem by
  Gauss-Hermite quadrature, and bias in its cost-to-go is caught;
- the task cost against closed forms.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
import torch
from torch import nn

from rmpfusion.assembly import tree_with_weights
from rmpfusion.assembly.errors import ConfigError
from rmpfusion.assembly.tree import build_tree
from rmpfusion.envs import Particle2D, collect
from rmpfusion.learn import RMPLearner
from rmpfusion.learn.config import BCParams, upgrade_train_config
from rmpfusion.learn.loop import Steps
from rmpfusion.learn.method import MethodContext, MethodContextError, TrainingMethod
from rmpfusion.learn.methods.apg import APGParams, RolloutCost
from rmpfusion.learn.methods.dagger import DAgger, DAggerParams
from rmpfusion.learn.methods.pg import PGParams, cost_to_go, run_episodes, surrogate
from rmpfusion.learn.task_cost import TaskCost, interval_costs, total
from rmpfusion.pipeline.config import RunConfig
from rmpfusion.pipeline.validate import resolve_and_validate
from rmpfusion.registry import TRAIN_METHODS

F64 = torch.float64
GOAL = {"parent": "q", "map": {"type": "offset", "origin": "goal"}, "rmp": {"type": "goal_attractor"}}
OBSTACLE = {
    "parent": "q",
    "rmp": {"type": "collision_avoidance"},
    "map": {"type": "sphere_distance", "center": "obstacle1_center", "radius": "obstacle1_radius"},
}
METRIC = {"parent": "q", "rmp": {"type": "identity_metric", "scale": 0.01}}
TREE = {"root": {"name": "q", "dim": 2}, "nodes": {"obstacle": OBSTACLE, "goal": GOAL, "metric": METRIC}}
EXPERT = {
    "obstacle": {
        "type": "rbf",
        "center": "obstacle1_center",
        "radius": "obstacle1_radius",
        "low": 1.0,
        "high": 5.0,
        "sigma": 0.5,
    },
    "goal": {"type": "rbf", "center": "goal", "radius": 0.0, "low": 1.0, "high": 2.0, "sigma": 1.0},
}


def _env() -> Particle2D:
    return Particle2D(n_obstacles=1, dt=0.05)


def _expert(env):
    return build_tree(tree_with_weights(TREE, EXPERT), aux_dims=env.aux_dims())


def _learner(seed: int = 0) -> RMPLearner:
    torch.manual_seed(seed)
    return RMPLearner(
        RMPLearner.Params(weights={"type": "mlp", "hidden": [4], "aux": "all"}),
        TREE,
        _env().aux_dims(),
        2,
        expert=EXPERT,
    )


@pytest.fixture(scope="module")
def splits():
    env = _env()
    expert = _expert(env)
    gen = torch.Generator().manual_seed(0)
    return (
        env,
        expert,
        {"train": collect(env, expert, 2, 3, 5, 0.5, gen), "val": collect(env, expert, 1, 2, 5, 0.5, gen)},
    )


def _context(splits, **kw) -> MethodContext:
    env, expert, data = splits
    return MethodContext(data=data, seed=3, env=env, expert=expert, interval=0.5, points=5, **kw)


# ------------------------------------------------------------------------------------------ the registry
def test_the_training_block_is_typed_by_its_method_and_defaults_to_behavior_cloning():
    run = RunConfig.model_validate(
        {"env": {"type": "particle2d"}, "tree": TREE, "train": {"iterations": 7, "snapshots": [7]}}
    )
    assert run.train.method == "bc" and isinstance(run.train, BCParams) and run.train.iterations == 7
    assert RunConfig.model_validate({"env": {"type": "particle2d"}, "tree": TREE}).train.method == "bc"
    dagger = RunConfig.model_validate(
        {"env": {"type": "particle2d"}, "tree": TREE, "train": {"method": "dagger", "rounds": 2}}
    ).train
    assert isinstance(dagger, DAggerParams) and dagger.rounds == 2 and dagger.model_dump()["method"] == "dagger"
    assert upgrade_train_config({"lr_final": 0.1}) == {"lr_final_fraction": 0.1, "method": "bc", "objective": "mse"}
    assert upgrade_train_config({"method": "apg", "horizon": 2.0}) == {"method": "apg", "horizon": 2.0}
    assert set(TRAIN_METHODS.names()) >= {"bc", "dagger", "apg", "pg"}


def _config(train: dict) -> dict:
    return {
        "env": {"type": "particle2d", "n_obstacles": 1, "dt": 0.05},
        "tree": TREE,
        "expert": EXPERT,
        "learners": {"rmp": {"type": "rmp", "weights": {"type": "mlp", "hidden": [4], "aux": "all"}}},
        "data": {
            "train_envs": 1,
            "train_trajectories": 2,
            "test_envs": 1,
            "test_trajectories": 2,
            "points": 3,
            "interval": 0.5,
        },
        "train": train,
        "logger": {"mode": "disabled"},
    }


def test_bad_training_blocks_are_refused_at_their_key():
    with pytest.raises(ConfigError) as err:
        resolve_and_validate(_config({"method": "dager"}))
    assert [(i.path, i.message) for i in err.value.issues] == [
        (
            "train.method",
            "unknown training method 'dager'; did you mean 'dagger', 'apg'? registered: apg, bc, dagger, field, match, pg",
        )
    ]
    with pytest.raises(ConfigError) as err:
        resolve_and_validate(_config({"method": "dagger", "beta": 0.3}))
    assert "beta is not used by beta_schedule=indicator" in str(err.value)
    with pytest.raises(ConfigError) as err:
        resolve_and_validate(_config({"method": "dagger", "initial_trajectories": 5}))
    assert [i.path for i in err.value.issues] == ["train.initial_trajectories"]
    with pytest.raises(ConfigError) as err:  # a window that ends between two records
        resolve_and_validate(_config({"method": "apg", "horizon": 1.0, "truncation": 0.5, "record_every": 0.3}))
    assert {i.path for i in err.value.issues} == {"train.horizon", "train.truncation"}
    with pytest.raises(ConfigError) as err:
        resolve_and_validate(_config({"method": "pg", "horizon": 0.7, "decision_interval": 0.07}))
    assert [i.path for i in err.value.issues] == ["train.decision_interval"]
    with pytest.raises(ConfigError, match="at least one of the weights"):
        resolve_and_validate(_config({"method": "apg", "cost": {"goal_distance": 0}}))


def test_apg_is_refused_for_an_environment_it_cannot_differentiate():
    from rmpfusion.learn.methods.apg import APG

    class Stepped:  # a simulator stepped outside torch: no differentiable goal distance
        dt = 0.01

        def clearance(self, q, aux):
            return q[..., 0]

    [(path, message)] = APG.requirements(APGParams(), Stepped(), 10)
    assert path == "train.method" and "use method pg" in message


def test_a_plugin_method_is_selected_by_its_name_and_runs_in_the_shared_loop(splits, tmp_path):
    """A method registered like a plugin's is a ``train.method`` like the built-ins, validated by its own Params,
    and gets checkpoints and resume from the loop."""
    from typing import Literal

    from pydantic import Field

    from rmpfusion.learn.config import TrainParams
    from rmpfusion.learn.loop import optimizer_step

    class NudgeParams(TrainParams):
        method: Literal["nudge"] = "nudge"
        size: float = Field(0.1, gt=0)

    class NudgeSteps(Steps):
        def __init__(self, model, params, opt):
            self.model, self.params, self.opt, self.count = model, params, opt, 0

        def step(self, it):
            self.opt.zero_grad()
            loss = sum((p**2).sum() for p in self.model.parameters()) * self.params.size
            loss.backward()
            optimizer_step(self.model, self.opt, self.params)
            self.count += 1
            return float(loss.detach())

        def state(self):
            return {"count": self.count}

        def load_state(self, state):
            self.count = state["count"]

        def info(self):
            return {"steps_taken": self.count}

    @TRAIN_METHODS.register("nudge")
    class Nudge(TrainingMethod):
        Params = NudgeParams

        def steps(self, model, ctx, opt, gen):
            return NudgeSteps(model, self.params, opt)

    try:
        run = resolve_and_validate(
            _config({"method": "nudge", "size": 0.5, "iterations": 4, "snapshots": [0, 4], "checkpoint_every": 2})
        )
        assert type(run.train).__name__ == "NudgeParamsSpec" and run.train.size == 0.5
        ctx = _context(splits, checkpoint_dir=tmp_path)
        res = Nudge(run.train).train(_learner(), ctx)
        assert res.info == {"steps_taken": 4} and sorted(res.snapshots) == [0, 4]
        again = Nudge(run.train.model_copy(update={"iterations": 6})).train(_learner(), ctx)
        assert again.resumed_from == 4 and again.info == {"steps_taken": 6}  # its state came back from the file
    finally:
        TRAIN_METHODS.unregister("nudge")


def test_a_method_without_what_it_needs_says_so(splits):
    _env, _expert, data = splits
    with pytest.raises(MethodContextError, match="'dagger' needs env and expert"):
        DAgger(DAggerParams(rounds=1, iterations=2)).train(
            _learner(), MethodContext(data=data, seed=0, interval=0.5, points=5)
        )


# ------------------------------------------------------------------------------------------ DAgger
def test_dagger_grows_its_data_by_the_counted_expert_queries_labelled_by_the_expert(splits):
    _env, expert, data = splits
    params = DAggerParams(
        rounds=2,
        initial_trajectories=4,
        trajectories_per_round=3,
        iterations=9,
        batch_size=8,
        snapshots=[0, 9],
        log_every=3,
        checkpoint_every=100,
    )
    said: list[str] = []
    method = DAgger(params)
    model = _learner()
    steps = method.steps(
        model.double(),
        _context(splits, say=said.append),
        torch.optim.SGD(model.parameters(), 0.0),
        torch.Generator().manual_seed(1),
    )
    assert len(steps.data) == 4 * 5 and steps.data.traj_id.unique().numel() == 4  # round 0: 4 demonstrations
    sizes = []
    for it in range(params.iterations):
        steps.step(it)
        sizes.append(len(steps.data))
    info = steps.info()
    assert [r["iteration"] for r in info["rounds"]] == [0, 3, 6]  # ⌊r·9/3⌋
    assert sizes == [20] * 3 + [35] * 3 + [50] * 3
    assert info["expert_queries_per_round"] == [20, 15, 15] and info["expert_queries"] == 50 == len(steps.data)
    assert info["expert_calls_in_rollouts"] == 0  # β = 0 after round 0: the expert never acted
    new = steps.data.trajectories(steps.data.traj_id[20:].unique())
    with torch.no_grad():
        assert torch.allclose(new.qdd, expert(new.q, new.qd, new.aux).qdd, rtol=0, atol=1e-12)
    visited = new.q[new.t > 0]  # the learner's own states, where the demonstrations never were
    assert not (visited[:, None] == data["train"].q[None]).all(-1).any()
    assert len(said) == 2 and said[0].startswith("dagger round 1/2 at iteration 3")


def test_dagger_beta_mixture_blends_the_expert_and_counts_its_calls(splits):
    """β = 1 rolls out the expert itself: its records are the expert's own trajectories, and every policy call of
    the rollouts is counted as an expert call, apart from the labels."""
    env, expert, _data = splits
    params = DAggerParams(
        rounds=1,
        trajectories_per_round=2,
        iterations=2,
        beta_schedule="constant",
        beta=1.0,
        batch_size=4,
        snapshots=[0, 2],
    )
    model = _learner()
    steps = DAgger(params).steps(
        model, _context(splits), torch.optim.SGD(model.parameters(), 0.0), torch.Generator().manual_seed(1)
    )
    steps.step(0), steps.step(1)
    r = steps.info()["rounds"][1]
    assert r["beta"] == 1.0 and r["labels"] == 10
    assert r["expert_calls_in_rollouts"] == 2 * (4 * round(2.0 / 0.05) + 1)  # 2 starts, 4 RK4 stages a step, the end
    new = steps.data.trajectories(steps.data.traj_id[-10:].unique())
    q0, qd0 = new.q[new.t == 0], new.qd[new.t == 0]
    ro = env.rollout(expert, q0, qd0, {k: v[new.t == 0] for k, v in new.aux.items()}, horizon=2.0, record_every=0.5)
    assert torch.allclose(new.q.reshape(2, 5, 2), ro.q.transpose(0, 1), atol=1e-12)


def test_dagger_interrupted_after_a_round_resumes_to_the_uninterrupted_weights(splits, tmp_path):
    params = DAggerParams(
        rounds=2,
        initial_trajectories=3,
        trajectories_per_round=2,
        iterations=12,
        batch_size=8,
        snapshots=[0, 12],
        log_every=4,
        checkpoint_every=5,
    )
    a = _learner()
    ra = DAgger(params).train(a, _context(splits, checkpoint_dir=tmp_path / "a"))

    class Stop(Exception):
        pass

    def stop_at(done, total):
        if done == 7:
            raise Stop

    with pytest.raises(Stop):  # killed after the checkpoint at 5 (round 1 done at 4), before round 2 (at 8)
        DAgger(params).train(_learner(), _context(splits, checkpoint_dir=tmp_path / "b", progress=stop_at))
    b = _learner(seed=99)
    rb = DAgger(params).train(b, _context(splits, checkpoint_dir=tmp_path / "b"))
    assert rb.resumed_from == 5 and rb.curve == ra.curve and rb.info == ra.info
    for k, v in a.state_dict().items():
        assert torch.equal(v, b.state_dict()[k]), k


# ------------------------------------------------------------------------------------------ task cost
def test_task_cost_terms_match_their_closed_forms():
    """A particle moving straight at the goal at unit speed: ∫d dt, path length and the final distance are known;
    the time beyond the tolerance (smoothed) is the time to reach it; clearance below the margin is penalised."""
    times = torch.linspace(0, 2, 201, dtype=F64)
    q = torch.stack([times - 3.0, torch.zeros_like(times)], -1)[:, None]  # (T, 1, 2), goal at the origin
    d = q[..., 0].abs()
    cost = TaskCost(
        goal_distance=1.0,
        time_to_goal=1.0,
        path_length=1.0,
        clearance=1.0,
        final_distance=1.0,
        goal_tolerance=1.5,
        temperature=1e-3,
        clearance_margin=0.5,
    )
    clear = torch.full((200, 1), 0.3, dtype=F64)
    terms = {k: float(v.sum()) for k, v in interval_costs(cost, times, q, d, clear).items()}
    assert terms["goal_distance"] == pytest.approx(3 * 2 - 2 * 2 / 2, rel=1e-12)  # ∫(3 − t) dt over [0, 2]
    assert terms["path_length"] == pytest.approx(2.0, rel=1e-12)
    assert terms["final_distance"] == pytest.approx(1.0, rel=1e-12)
    assert terms["time_to_goal"] == pytest.approx(1.5, abs=2e-3)  # d > 1.5 until t = 1.5
    assert terms["clearance"] == pytest.approx(0.2 * 2.0, rel=1e-6)  # (0.5 − 0.3) for 2 s
    assert float(total(interval_costs(cost, times, q, d, clear)).sum()) == pytest.approx(sum(terms.values()))


# ------------------------------------------------------------------------------------------ APG
class Linear(nn.Module):
    """μ = −k·(q − goal) − c·q̇: two parameters, so gradients can be checked exactly."""

    def __init__(self, k: float = 0.5, c: float = 1.0):
        super().__init__()
        self.k = nn.Parameter(torch.tensor(k, dtype=F64))
        self.c = nn.Parameter(torch.tensor(c, dtype=F64))

    def forward(self, q, qd, aux):
        return -self.k * (q - aux["goal"]) - self.c * qd


def test_apg_gradient_is_the_slope_of_the_task_cost_through_the_simulator(splits):
    """The gradient back-propagated through RK4 rollouts (one window) against central differences of the cost."""
    env = _env()
    q0, qd0, aux = splits[2]["train"].initial_states()
    params = APGParams(
        horizon=2.0,
        record_every=0.1,
        cost=TaskCost(goal_distance=1.0, path_length=0.5, clearance=5.0, final_distance=1.0, clearance_margin=1.5),
    )
    cost = RolloutCost(env, params)
    model = Linear()
    sums = cost(model, q0, qd0, aux, backward=True)
    assert sums["clearance"] > 0  # the clearance term is active, so its gradient is checked too
    grad = torch.stack([model.k.grad, model.c.grad])
    eps, fd = 1e-6, []
    for p in (model.k, model.c):
        with torch.no_grad():
            p += eps
            up = cost(model, q0, qd0, aux, backward=False)["total"]
            p -= 2 * eps
            down = cost(model, q0, qd0, aux, backward=False)["total"]
            p += eps
        fd.append((up - down) / (2 * eps))
    assert torch.allclose(grad, torch.tensor(fd, dtype=F64), rtol=1e-6, atol=1e-9), (grad, fd)


def test_apg_lowers_the_task_cost_of_a_random_tree(splits):
    from rmpfusion.learn.methods.apg import APG

    params = APGParams(
        horizon=2.0,
        truncation=1.0,
        record_every=0.2,
        batch_size=3,
        iterations=4,
        optimizer="adam",
        lr=0.1,
        snapshots=[0, 4],
        log_every=4,
        cost=TaskCost(goal_distance=1.0, final_distance=1.0),
    )
    res = APG(params).train(_learner(), _context(splits))
    (_, before), (_, after) = res.val_curve
    assert after < 0.95 * before, res.val_curve  # a sign error in the gradient would raise it
    assert res.measure == "cost" and res.info["expert_queries"] == 0


# ------------------------------------------------------------------------------------------ policy gradient
def _gauss_hermite(n: int, dims: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Nodes (n^dims, dims) and weights (n^dims,) of E[f(ε)], ε ~ N(0, I)."""
    x, w = np.polynomial.hermite_e.hermegauss(n)
    nodes = torch.tensor(list(itertools.product(x, repeat=dims)), dtype=F64)
    weights = torch.tensor([math.prod(c) for c in itertools.product(w, repeat=dims)], dtype=F64)
    return nodes, weights / weights.sum()


START = (
    torch.tensor([[-3.0, 0.5]], dtype=F64),
    torch.tensor([[0.2, -0.1]], dtype=F64),
    {"goal": torch.tensor([[2.0, 0.0]], dtype=F64)},
)


def _exact_gradient(model: Linear, params: PGParams) -> torch.Tensor:
    """∇θ E[Σ_d c_d] by Gauss-Hermite quadrature over the draws of both decisions, the constant accelerations
    integrated in closed form (q += h·q̇ + h²a/2, q̇ += h·a) and differentiated pathwise."""
    h, sigma, D = params.decision_interval, params.sigma, params.decisions
    nodes, weights = _gauss_hermite(7, 2 * D)
    q, qd = START[0].expand(len(nodes), 2), START[1].expand(len(nodes), 2)
    aux = {"goal": START[2]["goal"].expand(len(nodes), 2)}
    times = torch.tensor([0.0, h], dtype=F64)
    expected = 0.0
    for d in range(D):
        a = model(q, qd, aux) + sigma * nodes[:, 2 * d : 2 * d + 2]
        q1, qd1 = q + h * qd + 0.5 * h * h * a, qd + h * a
        rec = torch.stack([q, q1])
        c = total(interval_costs(params.cost, times, rec, (rec - aux["goal"]).norm(dim=-1), None, final=d == D - 1))
        expected = expected + (weights * c[0]).sum()
        q, qd = q1, qd1
    return torch.stack(torch.autograd.grad(expected, [model.k, model.c]))


def _estimates(
    model: Linear, params: PGParams, batches: int, episodes: int, baseline: str, shift: int = 0
) -> torch.Tensor:
    """The method's score-function estimate, ``batches`` times from ``episodes`` episodes each; ``shift``
    misaligns the cost-to-go by that many decisions (a deliberately wrong estimator)."""
    env = Particle2D(n_obstacles=0, dt=0.05)
    gen = torch.Generator().manual_seed(0)
    out = []
    for _ in range(batches):
        q, qd = START[0].expand(episodes, 2), START[1].expand(episodes, 2)
        aux = {"goal": START[2]["goal"].expand(episodes, 2)}
        ep = run_episodes(env, model, q, qd, aux, params, params.sigma, gen)
        if shift:
            ep.costs = torch.roll(ep.costs, shifts=shift, dims=0) * (torch.arange(len(ep.costs)) >= shift)[:, None]
        model.zero_grad()
        surrogate(model, ep, params.sigma, baseline).backward()
        out.append(torch.stack([model.k.grad.clone(), model.c.grad.clone()]))
    return torch.stack(out)


def test_the_policy_gradient_estimate_is_unbiased_against_the_exact_gradient():
    params = PGParams(
        horizon=0.2,
        decision_interval=0.1,
        sigma=0.5,
        cost=TaskCost(goal_distance=1.0, path_length=0.5, final_distance=2.0),
    )
    model = Linear()
    exact = _exact_gradient(model, params)
    g = _estimates(model, params, batches=40, episodes=500, baseline="leave_one_out")
    mean, se = g.mean(0), g.std(0) / math.sqrt(len(g))
    assert bool((4 * se < 0.5 * exact.abs()).all()), (exact, se)  # precise enough to tell a wrong estimator apart
    assert bool(((mean - exact).abs() < 4 * se).all()), (mean, exact, se)


def test_a_misaligned_cost_to_go_is_caught_as_biased():
    """Weighing each decision's score by the costs from the decision before it on (one decision late) drops
    the cost the decision causes: the same comparison rejects it."""
    params = PGParams(
        horizon=0.2,
        decision_interval=0.1,
        sigma=0.5,
        cost=TaskCost(goal_distance=1.0, path_length=0.5, final_distance=2.0),
    )
    model = Linear()
    exact = _exact_gradient(model, params)
    g = _estimates(model, params, batches=40, episodes=500, baseline="leave_one_out", shift=1)
    mean, se = g.mean(0), g.std(0) / math.sqrt(len(g))
    assert bool(((mean - exact).abs() > 4 * se).any()), (mean, exact, se)


def test_cost_to_go_sums_the_costs_from_each_decision_on():
    c = torch.tensor([[1.0, 2.0], [3.0, 4.0], [5.0, 6.0]], dtype=F64)
    assert torch.equal(cost_to_go(c), torch.tensor([[9.0, 12.0], [8.0, 10.0], [5.0, 6.0]], dtype=F64))


def test_apg_trains_on_its_own_step_and_leaves_the_environment_s_to_evaluation(splits):
    """``train.dt``: the training rollouts integrate on the coarser step, the environment itself keeps its own
    (an environment built from a run config, as the pipeline builds it)."""
    from rmpfusion.pipeline.construct import make_env

    env = make_env(resolve_and_validate(_config({"method": "apg", "dt": 0.05, "horizon": 1.0})))
    env = env.with_step(0.01)
    assert isinstance(env, Particle2D) and env.params.n_obstacles == 1
    q0, qd0, aux = splits[2]["train"].initial_states()
    params = APGParams(horizon=1.0, record_every=0.1, dt=0.05)
    coarse = RolloutCost(env, params)
    assert coarse.env.dt == 0.05 and env.dt == 0.01
    with torch.no_grad():
        got = coarse(Linear(), q0, qd0, aux, backward=False)
        same = RolloutCost(_env(), params.model_copy(update={"dt": None}))(Linear(), q0, qd0, aux, backward=False)
    assert got == same


@pytest.mark.slow
def test_a_sweep_over_a_method_s_setting_runs_every_job_with_that_method(tmp_path):
    """``rmpfusion-run -m`` sweeps APG's step size as it sweeps behavior cloning's: two jobs, each trained by APG
    with its own lr, each with its metrics, checkpoints and the method's report."""
    import json
    import os
    import subprocess
    import sys
    from pathlib import Path

    script = Path(sys.executable).with_name("rmpfusion-run")
    cmd = [
        str(script),
        "-m",
        "experiment=2d2level",
        "train=apg",
        "data=tiny",
        "eval=fast",
        "logger=disabled",
        "train.iterations=2",
        "train.snapshots=[0,2]",
        "train.horizon=0.5",
        "train.truncation=0.5",
        "train.batch_size=2",
        "train.log_every=1",
        "train.checkpoint_every=1",
        "train.compile=false",  # APG's preset compiles its rollouts: minutes per job, nothing this test checks
        "train.lr=1e-3,3e-3",
        f"hydra.sweep.dir={tmp_path}",
    ]
    env = {**os.environ, "WANDB_MODE": "disabled", "OMP_NUM_THREADS": "1", "MPLBACKEND": "Agg"}
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=1200, env=env, cwd=tmp_path)
    assert r.returncode == 0, r.stderr[-3000:]
    jobs = sorted(p for p in tmp_path.iterdir() if p.is_dir() and not p.name.startswith("."))
    assert len(jobs) == 2, jobs
    for job, lr in zip(jobs, (1e-3, 3e-3)):
        metrics = json.loads((job / "metrics.json").read_text())
        training = metrics["learners"]["rmp"]["training"]
        assert training["method"] == "apg" and training["expert_queries"] == 0, training
        assert json.loads((job / "config.json").read_text())["train"]["lr"] == lr
        assert (job / "checkpoints" / "rmp" / "final.pt").is_file()
        assert metrics["learners"]["rmp"]["certificate"]["ok"], metrics["learners"]["rmp"]["certificate"]


# ------------------------------------------------------------------------------------------------ smoke presets
SMOKE = {
    "bc": "tiny",
    "dagger": "dagger_smoke",
    "apg": "apg_smoke",
    "pg": "pg_smoke",
    "match": "match_smoke",
    "field": "field_smoke",
}


def test_every_registered_method_has_a_smoke_preset_that_validates_with_tiny_data():
    """The README's smoke run works for every method: ``train=<preset> data=tiny`` is a valid run of that method."""
    from rmpfusion.pipeline.compose import compose_run

    assert set(SMOKE) == set(TRAIN_METHODS.names())
    for method, preset in SMOKE.items():
        run = compose_run(["experiment=2d1level", "data=tiny", f"train={preset}", "eval=fast"])
        assert run.train.method == method


@pytest.mark.slow
@pytest.mark.parametrize("method", sorted(SMOKE))
def test_every_smoke_preset_runs_on_tiny_data(method, tmp_path):
    import json
    import os
    import subprocess
    import sys

    cmd = [
        sys.executable,
        "-m",
        "rmpfusion.cli.run",
        "experiment=2d1level",
        "data=tiny",
        f"train={SMOKE[method]}",
        "eval=fast",
        "logger=disabled",
        f"hydra.run.dir={tmp_path}",
    ]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=900, env={**os.environ, "WANDB_MODE": "disabled"})
    assert r.returncode == 0, r.stderr[-3000:]
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    assert metrics["learners"]["rmp"]["online_loss"] is not None
