"""The Franka Panda environment and tree: spec generation, stability, pybullet torque control vs. the
kinematic integration, collision checks, shared obstacle weights with several obstacles, rendering."""

from __future__ import annotations

import io
import os

import numpy as np
import pytest
import torch
import yaml
from pydantic import ValidationError

pytest.importorskip("pybullet")

from conftest import compose_cfg
from manipulators import cylinders, franka_env, franka_tree_spec, make_aux, robot

import rmpfusion
from rmpfusion.envs import Rollout
from rmpfusion.envs.manipulator import Manipulator
from rmpfusion.envs.manipulator_tree import (
    copy_weights,
    manipulator_tree_spec,
    with_weights,
)
from rmpfusion.evaluate import lyapunov_monotone, max_relative_increase
from rmpfusion.pipeline.progress import Progress
from rmpfusion.registry import ENVS

F64 = torch.float64
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
NOMINAL = [0.6, -0.3, 0.0, -2.2, 0.0, 2.0, 0.785]


@pytest.fixture(scope="module")
def expert_weights():
    with open(os.path.join(ROOT, "conf", "expert", "franka.yaml"), encoding="utf-8") as f:
        return yaml.safe_load(f)


@pytest.fixture(scope="module")
def env():
    e = franka_env()
    yield e
    e.close()


@pytest.fixture(scope="module")
def expert(env, expert_weights):
    return rmpfusion.build_tree(with_weights(franka_tree_spec(1), expert_weights), aux_dims=env.aux_dims())


# ---------------------------------------------------------------- spec and tree


def test_spec_structure_follows_the_paper():
    spec = franka_tree_spec(2)
    nodes = spec["nodes"]
    assert nodes["attractor"]["parent"] == "ee" and nodes["attractor"]["map"]["origin"] == "goal"
    assert sum(n.startswith("jl") for n in nodes) == 14
    limits = {n: v["map"]["limit"] for n, v in nodes.items() if n.startswith("jl")}
    assert limits["jl4_upper"] == pytest.approx(0.0) and limits["jl4_lower"] == pytest.approx(-3.1416)
    ncp = len(robot("panda")["control_points"])
    assert sum(n.startswith("cp") and "_obstacle" in n for n in nodes) == 2 * ncp
    assert set(spec["shared_weights"]) == {f"cp{i}_obstacle" for i in range(1, ncp + 1)}
    for k in (1, 2):
        w = nodes[f"cp3_obstacle{k}"]["weight"]
        assert w == {
            "shared": "cp3_obstacle",
            "bind": {"obstacle_center": f"obstacle{k}_center", "obstacle_radius": f"obstacle{k}_radius"},
        }
    for n in ("damper", "identity_metric"):
        assert "weight" not in nodes[n] and nodes[n]["parent"] == "q"
    bad = {**robot("panda"), "control_points": [{"link": "panda_link3", "radius": 0.1, "size": 2}]}
    with pytest.raises(ValueError, match=r"control_points\.0\.size"):  # the robot description's model
        manipulator_tree_spec(bad)


def test_tree_finite_qdd_and_positive_definite_M(env, expert, expert_weights):
    learner = rmpfusion.build_tree(franka_tree_spec(1), aux_dims=env.aux_dims())
    g = torch.Generator().manual_seed(0)
    B = 8
    lo, hi = env.lower + 0.05, env.upper - 0.05
    q = lo + (hi - lo) * torch.rand(B, 7, generator=g, dtype=F64)
    qd = torch.randn(B, 7, generator=g, dtype=F64)
    aux = env.sample_envs(B, g)
    for tree in (expert, learner):
        with torch.no_grad():
            out = tree(q, qd, aux)
        assert out.qdd.shape == (B, 7) and out.qdd.isfinite().all()
        assert torch.linalg.eigvalsh(out.M).min() > 0
        assert out.V.isfinite().all()


# ---------------------------------------------------------------- rollouts


def test_torque_control_tracks_the_kinematic_rollout(expert):
    """pybullet's computed-torque loop realises the tree's q̈ (same semi-implicit Euler step), and V falls."""
    env = franka_env(control_rate=120.0)
    q0 = torch.tensor([NOMINAL], dtype=F64)
    qd0 = torch.tensor([[0.3, -0.2, 0.1, 0.2, -0.3, 0.1, 0.2]], dtype=F64)
    aux = make_aux([0.4, -0.3, 0.35], [[0.5, 0.0, 0.25]], [0.06])
    with torch.no_grad():
        rt = env.rollout(expert, q0, qd0, aux, horizon=0.5, record_every=0.05, mode="torque")
        rk = env.rollout(expert, q0, qd0, aux, horizon=0.5, record_every=0.05, mode="kinematic")
    env.close()
    assert rt.error == [None] and rk.error == [None]
    assert rt.q.shape == rk.q.shape == (11, 1, 7)
    err = (rt.q - rk.q).abs().max().item()
    print(f"torque vs kinematic: max |Δq| over 0.5 s = {err:.2e} rad")
    assert err < 1e-3
    moved = (rk.q[-1] - rk.q[0]).abs().max().item()
    assert moved > 10 * err  # the comparison is not trivially satisfied by a robot at rest
    for r in (rt, rk):
        assert bool(lyapunov_monotone(r.V, rtol=1e-3).all()), max_relative_increase(r.V)
        assert r.V[-1, 0] < r.V[0, 0]
        assert not r.collided.any()


def test_kinematic_batch_equals_single_rollouts(env, expert):
    q0, qd0, aux = env.sample(3, 1, seed=1)
    with torch.no_grad():
        rb = env.rollout(expert, q0, qd0, aux, horizon=0.1, record_every=0.05)
        r1 = env.rollout(expert, q0[1:2], qd0[1:2], {k: v[1:2] for k, v in aux.items()}, horizon=0.1, record_every=0.05)
    assert isinstance(rb, Rollout) and rb.q.shape == (3, 3, 7) and rb.V.shape == (3, 3)
    torch.testing.assert_close(rb.q[:, 1:2], r1.q, rtol=1e-10, atol=1e-12)
    assert (rb.q[-1] != rb.q[0]).any()


def test_kinematic_progress_counts_the_records_then_each_samples_collision_replay(env, expert):
    """A kinematic rollout's long part after the records (each sample's path checked for collisions) is reported
    too: to a plain callback, progress climbs to records + samples, one unit per sample checked, never back."""
    q0, qd0, aux = env.sample(3, 1, seed=2)
    calls: list[tuple[int, int]] = []
    with torch.no_grad():
        env.rollout(expert, q0, qd0, aux, horizon=0.1, record_every=0.05, progress=lambda i, n: calls.append((i, n)))
    records, samples = 2, 3
    assert {n for _, n in calls} == {records + samples}
    done = [i for i, _ in calls]
    assert done == sorted(done) and done[-samples:] == [records + 1, records + 2, records + 3]


def test_kinematic_progress_reports_the_collision_check_as_a_stage_of_its_own(env, expert):
    """A callback with stages (pipeline/progress.py::Bar) counts the records to their own total, then the collision
    check on ``stage("collision check")``, from 0 to the samples: no bar waits at 99 % of another's count."""
    q0, qd0, aux = env.sample(3, 1, seed=2)
    calls: dict[str, list[tuple[int, int]]] = {"records": [], "collision check": []}

    class Staged:
        def __call__(self, done, total):
            calls["records"].append((done, total))

        def stage(self, name):
            return lambda done, total: calls[name].append((done, total))

    with torch.no_grad():
        env.rollout(expert, q0, qd0, aux, horizon=0.1, record_every=0.05, progress=Staged())
    assert calls["records"] == [(0, 2), (1, 2), (2, 2)]
    assert calls["collision check"] == [(0, 3), (1, 3), (2, 3), (3, 3)]


def test_a_progress_bar_draws_each_stage_under_its_own_label():
    stream = io.StringIO()
    bar = Progress(stream=stream).bar("rollout expert")
    bar(2, 2)
    bar.stage("collision check")(3, 3)
    lines = stream.getvalue().splitlines()
    assert lines[0].startswith("rollout expert [") and "2/2 100%" in lines[0]
    assert lines[1].startswith("rollout expert: collision check [") and "3/3 100%" in lines[1]


def test_collision_detection_on_hand_made_configurations(env):
    q = torch.tensor([NOMINAL, NOMINAL], dtype=F64)
    ee = env.ee_position(q[:1])[0].tolist()
    hit = make_aux([0.4, -0.3, 0.3], [ee], [0.03])
    far = make_aux([0.4, -0.3, 0.3], [[-0.8, -0.8, 0.25]], [0.05])
    both = {k: torch.cat([hit[k], far[k]]) for k in hit}
    assert env.in_collision(q, both).tolist() == [True, False]
    c = env.clearance(q, both)
    assert c[0] <= 0 and c[1] > 0.2


def test_rollout_flags_a_collision_and_isolates_a_failing_sample(env):
    """A policy that coasts sweeps the arm into the obstacle; a NaN policy row ends only its own rollout."""
    q0 = torch.tensor([NOMINAL] * 2, dtype=F64)
    qd0 = torch.tensor([[-1.5, 0, 0, 0, 0, 0, 0]] * 2, dtype=F64)  # joint 1 swings the arm towards −y
    aux = {k: v.repeat(2, 1) for k, v in make_aux([0.4, -0.3, 0.3], [[0.45, 0.0, 0.25]], [0.06]).items()}

    def coast(q, qd, aux):
        a = torch.zeros_like(q)
        a[1] = float("nan")
        return a

    for mode in ("kinematic", "torque"):
        r = env.rollout(coast, q0, qd0, aux, horizon=0.5, record_every=0.1, mode=mode)
        assert r.error[0] is None and "non-finite" in r.error[1]
        assert bool(r.collided[0]) and r.min_clearance[0] <= 0
        assert r.q[:, 0].isfinite().all() and r.q[-1, 1].isnan().all()
        assert not r.success.any()


def test_expert_reaches_a_goal_in_front_of_the_obstacle(expert):
    env = franka_env(control_rate=60.0)
    q0 = torch.tensor([NOMINAL], dtype=F64)
    aux = make_aux([0.35, -0.2, 0.35], [[0.55, 0.0, 0.25]], [0.06])
    with torch.no_grad():
        r = env.rollout(expert, q0, torch.zeros_like(q0), aux, horizon=3.0, record_every=0.1)
    env.close()
    print(f"expert: time to goal {r.time_to_goal.item():.2f} s, min clearance {r.min_clearance.item():.3f} m")
    assert r.error == [None]
    assert bool(r.success[0]) and not bool(r.collided[0])
    assert r.goal_distance[-1, 0] < env.params.goal_tolerance


# ---------------------------------------------------------------- shared weights, several obstacles


def test_weights_trained_with_one_obstacle_run_with_two(env):
    tree1 = rmpfusion.build_tree(franka_tree_spec(1), aux_dims=env.aux_dims())
    g = torch.Generator().manual_seed(3)
    with torch.no_grad():  # stand-in for training: move every parameter away from its initialisation
        for p in tree1.parameters():
            p.add_(0.3 * torch.randn(p.shape, generator=g, dtype=p.dtype))
    env2 = franka_env(cylinders([(0.5, 0.0, 0.25), (0.3, 0.4, 0.25)], [0.06, 0.05], height=0.5))
    tree2 = rmpfusion.build_tree(franka_tree_spec(2), aux_dims=env2.aux_dims())
    copied = copy_weights(tree1, tree2)
    assert "attractor" in copied and "cp5_obstacle" in copied
    n_params = lambda t: sum(p.numel() for p in t.parameters())
    assert n_params(tree1) == n_params(tree2)  # the second obstacle adds no parameters
    assert tree2.weights["cp5_obstacle2"].fn is tree2.shared["cp5_obstacle"] is tree2.weights["cp5_obstacle1"].fn

    q = torch.tensor([NOMINAL], dtype=F64)
    qd = torch.full((1, 7), 0.2, dtype=F64)
    aux1 = make_aux([0.4, -0.3, 0.35], [[0.5, 0.05, 0.25]], [0.06])
    # the second obstacle as the trained one: the shared weight must see it exactly as obstacle 1
    aux2 = make_aux([0.4, -0.3, 0.35], [[0.9, 0.9, 0.25], [0.5, 0.05, 0.25]], [0.05, 0.06])
    x = torch.randn(4, 3, generator=g, dtype=F64)
    w1, gw1 = tree1.weights["cp5_obstacle1"](x, {k: v.expand(4, -1) for k, v in aux1.items()})
    w2, gw2 = tree2.weights["cp5_obstacle2"](x, {k: v.expand(4, -1) for k, v in aux2.items()})
    torch.testing.assert_close(w2, w1)
    torch.testing.assert_close(gw2, gw1)
    # an obstacle beyond every barrier's support changes nothing; a nearby one does
    with torch.no_grad():
        a1 = tree1(q, qd, aux1).qdd
        a2 = tree2(q, qd, aux2).qdd
        torch.testing.assert_close(a2, a1, rtol=1e-9, atol=1e-10)
        near = make_aux(
            [0.4, -0.3, 0.35],
            [[0.5, 0.05, 0.25], list(env.ee_position(q)[0] + torch.tensor([0.0, 0.2, 0.0]))],
            [0.06, 0.05],
        )
        out = tree2(q, qd, near)
    assert out.qdd.isfinite().all() and torch.linalg.eigvalsh(out.M).min() > 0
    assert (out.qdd - a1).abs().max() > 1e-3


# ---------------------------------------------------------------- env plumbing


def test_registered_params_and_sampling(env):
    entry = ENVS.get("manipulator")
    assert entry.obj is Manipulator
    p = entry.validate({"mode": "torque", "control_rate": 100, "robot": robot("panda")})
    assert p.mode == "torque" and not p.gui and Manipulator(p).dt == pytest.approx(0.01)
    with pytest.raises(ValidationError, match="control_hz"):
        entry.validate({"control_hz": 100, "robot": robot("panda")})
    q0, qd0, aux = env.sample(3, 2, seed=5)
    assert q0.shape == (6, 7) and aux["goal"].shape == (6, 3) and aux["obstacle1_radius"].shape == (6, 1)
    assert (q0 >= env.lower).all() and (q0 <= env.upper).all()
    assert (env.clearance(q0, aux) >= env.params.start_clearance).all()
    q0b, _, auxb = env.sample(3, 2, seed=5)
    torch.testing.assert_close(q0b, q0)
    torch.testing.assert_close(auxb["goal"], aux["goal"])
    horiz = (aux["goal"][:, :2] - aux["obstacle1_center"][:, :2]).norm(dim=-1) - aux["obstacle1_radius"][:, 0]
    assert (horiz >= env.params.goal_clearance).all()
    with pytest.raises(ValueError, match="multiple of"):
        env.rollout(lambda q, qd, a: torch.zeros_like(q), q0, qd0, aux, horizon=0.1, record_every=0.013)


def test_render_returns_an_rgb_image(env):
    aux = make_aux([0.4, -0.3, 0.35], [[0.5, 0.0, 0.25]], [0.06])
    img = env.render(torch.tensor(NOMINAL, dtype=F64), aux, width=64, height=48)
    assert img.shape == (48, 64, 3) and img.dtype == np.uint8
    assert img.std() > 5  # robot and obstacle are drawn, not a blank frame


# ---------------------------------------------------------------- execution metrics, demonstrations


def test_execution_metrics_match_the_recorded_path(expert):
    """The rollout's execution metrics (paper §4.2) agree with the path recorded at every integration step."""
    env = franka_env(control_rate=60.0)
    q0 = torch.tensor([NOMINAL], dtype=F64)
    aux = make_aux([0.35, -0.2, 0.35], [[0.55, 0.0, 0.25]], [0.06])
    with torch.no_grad():
        r = env.rollout(expert, q0, torch.zeros_like(q0), aux, horizon=3.0, record_every=env.dt)
    env.close()
    assert bool(r.reached[0])
    k = round(r.time_to_goal.item() / env.dt)  # the record where the execution ended
    assert r.goal_distance[k, 0] <= env.params.goal_tolerance < r.goal_distance[k - 1, 0]
    torch.testing.assert_close(r.cspace_length[0], (r.q[1 : k + 1, 0] - r.q[:k, 0]).norm(dim=-1).sum())
    torch.testing.assert_close(r.ee_length[0], (r.ee[1 : k + 1, 0] - r.ee[:k, 0]).norm(dim=-1).sum())
    torch.testing.assert_close(r.end_goal_distance[0], r.goal_distance[k, 0])
    m = env.task_metrics(r)
    assert m["time"].item() == pytest.approx(r.time_to_goal.item())
    assert m["ee_length"].item() >= (r.ee[k, 0] - r.ee[0, 0]).norm().item()  # no shorter than the straight line
    assert m["timeout_goal_distance"].item() < m["goal_distance"].item()  # it kept converging after the execution
    assert m["min_goal_distance"].item() == pytest.approx(r.goal_distance[:, 0].min().item())
    assert m["min_goal_distance"].item() <= m["timeout_goal_distance"].item()


def _fake_rollout(gd, speed, dt=0.1):
    """A Franka rollout with given goal distances and joint speeds (T, B) for the bookkeeping tests."""
    gd, speed = torch.as_tensor(gd, dtype=F64), torch.as_tensor(speed, dtype=F64)
    T, B = gd.shape
    qd = torch.zeros(T, B, 7, dtype=F64)
    qd[..., 0] = speed
    q = torch.zeros(T, B, 7, dtype=F64)
    z = torch.zeros(B, dtype=F64)
    return Rollout(
        mode="kinematic",
        times=torch.arange(T, dtype=F64) * dt,
        q=q,
        qd=qd,
        qdd=qd.clone(),
        ee=torch.zeros(T, B, 3, dtype=F64),
        goal_distance=gd,
        collided=torch.zeros(B, dtype=torch.bool),
        min_clearance=z + 0.1,
        first_collision_time=z + float("inf"),
        reached=torch.ones(B, dtype=torch.bool),
        time_to_goal=z + 0.1,
        success=torch.ones(B, dtype=torch.bool),
        error=[None] * B,
        cspace_length=z,
        ee_length=z,
        end_goal_distance=z,
    )


def test_demonstrations_last_until_the_expert_rests_at_the_goal():
    env = franka_env(demo_min_duration=0.3, demo_settle_distance=0.01, demo_settle_speed=0.05)
    far, near = 0.2, 0.001
    gd = torch.tensor(
        [[far, far, far], [near, far, far], [near, near, far], [near, near, far], [near, near, far], [near, near, far]]
    )
    speed = torch.tensor(
        [[1.0, 1.0, 1.0], [0.0, 1.0, 1.0], [0.0, 0.5, 1.0], [0.0, 0.01, 1.0], [0.0, 0.0, 1.0], [0.0, 0.0, 1.0]]
    )
    r = _fake_rollout(gd, speed)
    # 0: at rest from t = 0.1 but kept to the minimum 0.3 s; 1: at rest from t = 0.3; 2: never -> whole rollout
    assert env.demonstration_lengths(r).tolist() == [4, 4, 6]
    r.q[4:, 2] = float("nan")  # an error ends a demonstration at its last finite record
    assert env.demonstration_lengths(r).tolist() == [4, 4, 4]


def test_collected_demonstrations_have_per_trajectory_goals_lengths_and_split_obstacles(expert):
    env = franka_env(
        cylinders([(0.5, 0.0, 0.25)], [0.06], height=0.5),
        control_rate=30.0,
        demo_min_duration=0.2,
        demo_settle_distance=0.3,
        demo_settle_speed=100.0,
        test_scene=cylinders([(0.45, 0.1, 0.25)], [0.05], height=0.5),
    )
    g = torch.Generator().manual_seed(0)
    ds = env.demonstrations(expert, 1, 3, n_points=6, interval=0.1, generator=g, split="train")
    assert ds.traj_id.unique().tolist() == [0, 1, 2] and (ds.env_id == 0).all()
    assert len({tuple(ds.aux["goal"][ds.traj_id == b][0].tolist()) for b in range(3)}) == 3  # a goal per trajectory
    for b in range(3):
        rows = ds.traj_id == b
        t = ds.t[rows]
        assert t[0] == 0 and (t.diff() > 0).all() and 0.2 - 1e-9 <= t[-1] <= 0.5 + 1e-9
        # the label is the expert's acceleration at the recorded state
        out = expert(ds.q[rows], ds.qd[rows], {k: v[rows] for k, v in ds.aux.items()})
        torch.testing.assert_close(out.qdd, ds.qdd[rows])
    torch.testing.assert_close(ds.aux["obstacle1_center"][0], torch.tensor([0.5, 0.0, 0.25], dtype=F64))
    test = env.demonstrations(expert, 1, 2, n_points=3, interval=0.1, generator=g, split="test")
    assert (test.aux["obstacle1_center"] == torch.tensor([0.45, 0.1, 0.25], dtype=F64)).all()
    assert (test.aux["obstacle1_radius"] == 0.05).all()
    with pytest.raises(ValueError, match="test_scene must have the obstacles of the training scene"):
        franka_env(test_scene=cylinders([(0.45, 0.1, 0.25)] * 2, [0.05] * 2))


def test_ratios_to_the_expert_are_per_trajectory():
    from rmpfusion.evaluate.metrics import ratios_to_expert, summarize

    expert = {"time": torch.tensor([2.0, 4.0, 1.0]), "x": torch.tensor([1.0, 0.0, 2.0])}
    learner = {"time": torch.tensor([3.0, 4.0, float("nan")]), "x": torch.tensor([2.0, 1.0, 2.0])}
    r = ratios_to_expert(learner, expert, ["time", "x"])
    assert r["time"]["n"] == 2 and r["time"]["mean"] == pytest.approx(1.25)
    assert r["time"]["std"] == pytest.approx(torch.tensor([1.5, 1.0], dtype=F64).std().item())
    assert r["x"]["n"] == 2 and r["x"]["mean"] == pytest.approx(1.5)  # the zero expert value is left out
    s = summarize(expert)
    assert s["time"]["mean"] == pytest.approx(7 / 3) and s["time"]["max"] == 4.0 and s["time"]["n"] == 3


# (a learner trained with one obstacle, run with three: tests/test_franka_trained.py)


# ---------------------------------------------------------------- the whole experiment, tiny


@pytest.mark.parametrize("rate", [60, pytest.param(1000, marks=pytest.mark.slow)])
def test_tiny_franka_experiment_end_to_end(tmp_path, rate):
    """experiment=franka on tiny sizes: data -> training -> evaluation in pybullet -> Franka metrics, ratios to the
    expert, collisions, Lyapunov monitor and the figures (ratio chart, V_r, render strip, GIF) in the run dir.

    At the configured 1 kHz every tree policy's V_r never rises (Theorem 2), trained or not. At 60 Hz (the fast
    variant) semi-implicit Euler steps of a briefly trained learner can raise V_r (by ~1 %: an integration error,
    see conf/env/franka.yaml), so there only the expert is held to Theorem 2."""
    import json

    from rmpfusion.pipeline.run import run_experiment
    from rmpfusion.pipeline.validate import resolve_and_validate

    overrides = [
        "experiment=franka",
        "logger=disabled",
        f"env.control_rate={rate}",
        "data.train_trajectories=3",
        "data.test_trajectories=2",
        "data.points=6",
        "env.demo_min_duration=0.2",
        "train.iterations=3",
        "train.batch_size=8",
        "train.snapshots=[0,3]",
        "train.checkpoint_every=3",
        "train.log_every=1",
        "eval.horizon=0.5",
        "eval.compile=false",
        "env.render_times=[0.0,0.5]",
        "env.render_size=[64,48]",
    ]
    run = resolve_and_validate(compose_cfg(overrides))
    run_experiment(run, tmp_path, progress=False)
    m = json.loads((tmp_path / "metrics.json").read_text())
    keys = {"time", "cspace_length", "ee_length", "timeout_goal_distance", "min_goal_distance"}
    assert keys | {"goal_distance"} <= set(m["expert"]["task"]) and m["expert"]["task"]["time"]["n"] == 2
    assert m["data"]["train"]["trajectories"] == 3 and m["data"]["test"]["trajectories"] == 2
    assert 0.2 - 1e-9 <= m["data"]["train"]["trajectory_seconds"]["min"] <= 0.5 + 1e-9
    snaps = m["learners"]["rmp"]["snapshots"]
    assert set(snaps) == {"0", "3"}
    for s in snaps.values():
        assert set(s["ratio_to_expert"]) == keys
        for v in s["ratio_to_expert"].values():  # statistics of the 2 per-trajectory ratios
            assert v["n"] == 2 and 0 < v["min"] <= v["max"]
            assert v["mean"] == pytest.approx((v["min"] + v["max"]) / 2)
            assert v["std"] == pytest.approx((v["max"] - v["min"]) / 2**0.5)  # sample std of two values
        lyap = s["lyapunov"]
        assert lyap["monotone_fraction"] == s["task"]["lyapunov_monotone"]["mean"]  # the per-trajectory flags
        # the verdict and the worst rise agree both ways (eval.lyapunov_rtol = 1e-6, atol = 1e-9): a trajectory that
        # fails rose by more than 1e-6 relative; when all pass, no rise exceeds 1e-6 + 1e-9/|V| (|V| > 0.1 here)
        all_monotone, worst = lyap["monotone_fraction"] == 1.0, lyap["max_relative_increase"]
        assert all_monotone == (worst <= 1e-6 + 1e-8), lyap
        if rate == 1000:
            assert lyap["monotone_fraction"] == 1.0, lyap  # Theorem 2, at every snapshot
    rows = {r["policy"]: r for r in m["task_table"]}
    assert set(rows) == {"expert", "learner-0", "learner-3"}
    assert rows["expert"]["lyapunov"]["monotone_fraction"] == 1.0  # Theorem 2 for the expert tree
    for r in rows.values():
        assert r["trajectories"] == 2 and r["collisions"] == round(2 * r["collided"]["mean"])
        assert r["close_passes"] == round(2 * r["close_pass"]["mean"])
        c = r["clearance"]  # the least and the (lower) median of the two rollouts' closest approaches: the smaller
        mean, std = r["min_clearance"]["mean"], r["min_clearance"]["std"]
        assert c["least"] == c["median"] == pytest.approx(mean - std / 2**0.5)  # sample std of two values
    assert rows["expert"]["collisions"] == 0
    # the task's data splits say how many straight reaches cross the cylinder (scenes/crossing.py)
    assert 0.0 <= m["data"]["train"]["crossing"]["crossing_fraction"] <= 1.0
    assert m["data"]["train"]["crossing"]["paths"] == 3 and m["data"]["train"]["crossing"]["radius"] == pytest.approx(
        0.095
    )
    assert rows["learner-3"]["ratio"]["time"]["mean"] == pytest.approx(snaps["3"]["ratio_to_expert"]["time"]["mean"])
    figs = {os.path.basename(f) for f in m["figures"]}
    assert {
        "task_ratios.png",
        "task_lyapunov.png",
        "task_execution.png",
        "task_execution.gif",
        "task_ee_paths.png",
        "learning_curve_rmp.png",
    } <= figs
    assert not any(f.startswith(("trajectories_", "progression_")) for f in figs)  # no 2-D plots of a 7-D robot
    for f in m["figures"]:
        assert os.path.getsize(f) > 1000
    from PIL import Image

    with Image.open(tmp_path / "figures" / "task_execution.gif") as gif:
        assert gif.n_frames == 6  # 0.5 s at 10 frames per second, both ends included
