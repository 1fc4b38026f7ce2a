"""Experiments on recorded demonstrations (``data.source: recorded``): the LASA preset and a user's CSV run end to
end without an expert, the measures are those of the demonstrations themselves, Theorem 2 holds for the trained
tree, and every bad input is one error naming the key or file."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from conftest import compose_cfg

from rmpfusion.assembly.errors import ConfigError
from rmpfusion.envs.rollout import Rollout
from rmpfusion.evaluate.reproduction import dtw_distance
from rmpfusion.pipeline.recorded import Batch, convergence, grid_starts, reproduction
from rmpfusion.pipeline.run import run_experiment
from rmpfusion.pipeline.validate import resolve_and_validate
from rmpfusion.recordings.signals import States

#: the smallest LASA run: 20 iterations, 4 starts, rollouts as long as the longest demonstration
TINY_LASA = [
    "experiment=lasa",
    "logger=disabled",
    "train.iterations=20",
    "train.snapshots=[0,20]",
    "data.starts=4",
    "data.horizon_factor=1.0",
    "data.convergence_horizon_factor=3.0",
]


def validated(overrides):
    return resolve_and_validate(compose_cfg(overrides))


def test_a_tiny_lasa_run_end_to_end_then_resumed(tmp_path, capsys):
    run = validated(TINY_LASA + ["data.shape=Sshape"])
    m = run_experiment(run, tmp_path, progress=True)
    said = capsys.readouterr().out.splitlines()
    # the convergence check is a progress stage of its own, counted in its own records, then its collision check
    check = [line for line in said if line.startswith("rollout tree: convergence check, from rest to ")]
    assert check and check[-1].split("] ")[1].split()[1] == "100%"
    for name in ("tree", "rmp"):  # smoke-sized: eval.compile=auto leaves both eager, and the run says why
        assert m["evaluation"][name]["mode"].startswith("eager (eval.compile=auto: ")
        assert any(line.startswith(f"{name}: evaluated eager (eval.compile=auto") for line in said)
    assert set(m["timing"]) >= {"training_s", "evaluation_s", "figures_s", "total_s"}
    assert m["source"] == "recorded" and json.loads((tmp_path / "metrics.json").read_text())["name"] == "lasa_Sshape"
    used = [set(m["data"][s]["demonstrations"]) for s in ("train", "val", "test")]
    assert [len(u) for u in used] == [5, 1, 1] and len(set.union(*used)) == 7  # split by whole demonstration
    rmp = m["learners"]["rmp"]
    for policy in (m["tree"], rmp, rmp["snapshots"]["0"]):
        assert policy["convergence"]["lyapunov_monotone_fraction"] == 1.0  # Theorem 2, any parameters
        assert policy["reproduction_test"]["dtw"] > 0 and policy["reproduction_val"]["dtw"] > 0
    assert rmp["certificate"]["ok"] and rmp["certificate"]["failing_states"] == 0
    assert m["tree"]["premises"]["goal_only_equilibrium"]  # every weight 1: §12's premises hold
    assert rmp["premises"]["goal_only_equilibrium"]  # the learned flow keeps every weight 1
    for policy in (m["tree"], rmp):  # the starts at rest went on to 3 durations, each told apart
        o = policy["convergence"]["at_long_horizon"]
        assert (
            o["starts"] == policy["convergence"]["starts"] and o["horizon_s"] > 2.9 * policy["convergence"]["horizon_s"]
        )
        assert o["converged"] + o["at_rest_away"] + o["still_moving"] + o["ended_early"] == o["starts"]
    assert "at_long_horizon" not in rmp["snapshots"]["0"]["convergence"]  # only the final policy goes on
    assert set(rmp["learned_leaf_parameters"]) == {"attractor.gain"}  # the softness and the damping stay fixed
    assert m["objective"] == rmp["reproduction_val"]["dtw"]  # a sweep chooses on validation
    assert (tmp_path / "figures" / "rollouts.png").stat().st_size > 0
    assert m["figures"]["latent_rmp"].endswith("latent_rmp.png")  # the learned map's latent space
    assert (tmp_path / "figures" / "latent_rmp.png").stat().st_size > 0
    again = run_experiment(run, tmp_path, progress=False)
    assert all(again["data"][s]["reused"] for s in ("train", "val", "test"))
    assert again["learners"]["rmp"]["reproduction_test"] == rmp["reproduction_test"]


@pytest.fixture(scope="module")
def eager_sshape_run(tmp_path_factory):
    """One finished tiny Sshape run, evaluated eagerly without figures: (its directory, its metrics). Shared by the
    tests that compare another evaluation of the same run with it."""
    out = tmp_path_factory.mktemp("eager_sshape")
    run = validated(TINY_LASA + ["data.shape=Sshape", "eval.compile=false", "eval.figures=false"])
    return out, run_experiment(run, out, progress=False)


@pytest.mark.slow
def test_a_compiled_recorded_evaluation_equals_the_eager_one(tmp_path, eager_sshape_run):
    """eval.compile=true: the tree and the learner (every snapshot loaded into one compiled copy) roll out compiled,
    batched over every start, with the eager evaluation's numbers; metrics.json says how each ran."""
    run = validated(TINY_LASA + ["data.shape=Sshape", "eval.compile=true", "eval.figures=false"])
    fast, slow = run_experiment(run, tmp_path, progress=False), eager_sshape_run[1]
    assert fast["evaluation"]["tree"]["mode"] == fast["evaluation"]["rmp"]["mode"] == "compiled"
    assert slow["evaluation"]["rmp"]["mode"] == "eager (eval.compile is false)"
    for a, b in ((fast["tree"], slow["tree"]), (fast["learners"]["rmp"], slow["learners"]["rmp"])):
        assert a["reproduction_test"]["dtw"] == pytest.approx(b["reproduction_test"]["dtw"], rel=1e-9)
        assert a["convergence"]["at_long_horizon"]["converged"] == b["convergence"]["at_long_horizon"]["converged"]
        assert a["convergence"]["final_distance_max"] == pytest.approx(b["convergence"]["final_distance_max"], rel=1e-9)


def via_point_demonstrations(n: int, seed: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """Demonstrations no RMP tree made: cubic splines through jittered via-points, sampled at irregular times
    (a 100 Hz recorder with jitter), with 0.2 mm of measurement noise and a second of rest at either end."""
    from scipy.interpolate import CubicSpline

    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        via = np.array([[-0.05, 0.02], [-0.03, 0.04], [-0.01, 0.03], [0.0, 0.0]]) + rng.normal(0, 0.003, (4, 2))
        via[-1] = 0.0
        path = CubicSpline([0.0, 1.0, 2.0, 3.0], via, bc_type="clamped")
        t = np.cumsum(rng.uniform(0.007, 0.013, 500))
        s = np.clip(t - 1.0, 0.0, 3.0)  # at rest for a second, moving for three, at rest again
        out.append((t, path(s) + rng.normal(0, 2e-4, (len(t), 2))))
    return out


def write_csv(path, demos) -> None:
    lines = ["demo,t,x_mm,y_mm"] + [
        f"d{k},{ti:.6f},{1e3 * p[0]:.5f},{1e3 * p[1]:.5f}" for k, (t, pos) in enumerate(demos) for ti, p in zip(t, pos)
    ]
    path.write_text("\n".join(lines) + "\n")


def test_a_users_csv_of_noisy_irregular_recordings_runs(tmp_path):
    csv = tmp_path / "recorded.csv"
    write_csv(csv, via_point_demonstrations(5, seed=3))
    run = validated(
        TINY_LASA
        + [
            "data.format=csv",
            "data.shape=null",
            f"data.files=[{csv}]",
            "data.demo_column=demo",
            "data.units=mm",
            "data.goal=[0.0,0.0]",
            "name=csv_demo",
        ]
    )
    m = run_experiment(run, tmp_path / "run", progress=False)
    assert m["data"]["test"]["demonstrations"][0].startswith(str(csv))
    assert m["learners"]["rmp"]["convergence"]["lyapunov_monotone_fraction"] == 1.0


def test_bad_recorded_configs_are_one_error_naming_the_key(tmp_path):
    cases = [
        (["train=dagger"], "train.method", "learns from recordings: bc, field, match"),
        (["+expert.attractor=1.0"], "expert", "have no expert"),
        (["data.shape=Sshap"], "data", "did you mean 'Sshape'"),
        (["data.window=10"], "data", "must be odd"),
        (["data.format=csv", "data.shape=null"], "data", "needs data.files"),
        (["data.source=robot"], "data", "data.source must be expert"),
        (["data=recorded", f"data.files=[{tmp_path / 'missing.csv'}]"], "data", "no such file"),
    ]
    three = tmp_path / "three.csv"
    three.write_text("t,x,y,z\n" + "".join(f"{0.01 * k},{k},{2 * k},{3 * k}\n" for k in range(60)))
    cases.append((["data.format=csv", f"data.files=[{three}]"], "data", "data.shape='Angle' is not read by format csv"))
    cases.append(
        (
            ["data=recorded", f"data.files=[{three}]", "data.split=all"],
            "data",
            "3 coordinates (read from the columns 'x', 'y', 'z') but the environment",
        )
    )
    for extra, path, words in cases:
        with pytest.raises(ConfigError) as err:
            validated(TINY_LASA + extra)
        found = [i for i in err.value.issues if i.path == path]
        assert found and words in found[0].message, (extra, err.value.issues)


def demo_states(T: int = 50) -> States:
    t = 0.02 * np.arange(T)
    q = np.stack([np.cos(t) - 1.0, np.sin(2 * t)], -1)
    return States(
        t=t,
        q=q,
        qd=np.gradient(q, axis=0) / 0.02,
        qdd=np.zeros_like(q),
        goal=np.array([0.0, 0.0]),
        source="demo",
        aux={},
    )


def replay(states: States, extra: int, grid: np.ndarray) -> Rollout:
    """A rollout that follows the demonstration exactly (then rests at its end), beside starts that stay put."""
    path = np.concatenate([states.q, np.repeat(states.q[-1:], extra, axis=0)])
    T = len(path)
    q = np.concatenate([path[:, None], np.repeat(grid[None], T, axis=0)], axis=1)
    qt = torch.as_tensor(q)
    goal = np.zeros(2)
    return Rollout(
        times=torch.arange(T, dtype=torch.float64) * 0.02,
        q=qt,
        qd=torch.zeros_like(qt),
        qdd=torch.zeros_like(qt),
        collided=torch.zeros(q.shape[1], dtype=torch.bool),
        reached=torch.zeros(q.shape[1], dtype=torch.bool),
        success=torch.zeros(q.shape[1], dtype=torch.bool),
        min_clearance=torch.zeros(q.shape[1]),
        first_collision_time=torch.zeros(q.shape[1]),
        goal_distance=torch.as_tensor(np.linalg.norm(q - goal, axis=-1)),
    )


def test_reproduction_of_an_exact_replay_is_zero_and_stalled_starts_are_found():
    demo = demo_states()
    grid = np.array([[0.0, 0.0005], [0.3, 0.3]])  # one at the goal (within 1 mm), one stalled away from it
    ro = replay(demo, 20, grid)
    batch = Batch(
        q0=ro.q[0],
        qd0=torch.zeros(3, 2),
        aux={"goal": torch.zeros(3, 2)},
        demos={"test": [demo]},
        index={"test": slice(0, 1)},
        grid=slice(1, 3),
        horizon=float(ro.times[-1]),
    )
    rep = reproduction(batch, ro, "test", tolerance=1e-3)
    assert rep["dtw"] == 0.0 and rep["swept_error_area"] == 0.0
    assert rep["final_distance"] == pytest.approx(np.linalg.norm(demo.q[-1]))
    shifted = demo.q + [0.01, 0.0]  # against the demonstration moved 1 cm along x: at most 1 cm per sample (the
    assert 0.005 < dtw_distance(demo.q, shifted) <= 0.01 + 1e-12  # warping may pair samples closer than the shift

    class D:
        tolerance = 1e-3

    conv = convergence(batch, ro, D, rtol=1e-6, atol=1e-9, dt=0.02)
    assert conv["converged"] == 0.5 and conv["stalled_count"] == 1 and conv["stalled"] == [[0.3, 0.3]]


def test_a_stalled_start_names_the_leaves_that_hold_it():
    """Two equal attractors, onto the goal and onto (0.6, 0.6), balance halfway: a start resting at (0.3, 0.3) is
    held there by the two, with equal and opposite forces that account for the whole root force."""
    from rmpfusion import build_tree

    attractor = {"type": "goal_attractor", "gain": 1.0, "eta": 1.0}
    tree = build_tree(
        {
            "root": {"name": "x", "dim": 2},
            "aux": {"goal": 2},
            "nodes": {
                "goal": {"parent": "x", "map": {"type": "offset", "origin": "goal"}, "rmp": attractor},
                "home": {"parent": "x", "map": {"type": "offset", "origin": [0.6, 0.6]}, "rmp": attractor},
                "damper": {"parent": "x", "map": {"type": "identity"}, "rmp": {"type": "damper", "eta": 1.0}},
            },
        }
    ).double()
    demo = demo_states()
    ro = replay(demo, 20, np.array([[0.0, 0.0005], [0.3, 0.3]]))
    ro.q = ro.q.double()
    batch = Batch(
        q0=ro.q[0],
        qd0=torch.zeros(3, 2),
        aux={"goal": torch.zeros(3, 2, dtype=torch.float64)},
        demos={"test": [demo]},
        index={"test": slice(0, 1)},
        grid=slice(1, 3),
        horizon=float(ro.times[-1]),
    )

    class D:
        tolerance = 1e-3

    conv = convergence(batch, ro, D, rtol=1e-6, atol=1e-9, dt=0.02, tree=tree)
    assert list(conv["held_by"]) in (["goal", "home"], ["home", "goal"])
    assert conv["held_by"]["goal"] == pytest.approx(conv["held_by"]["home"], rel=1e-9) and conv["held_by"]["goal"] > 0.1
    assert conv["held_by_unexplained"] < 1e-12
    assert "held_by" not in convergence(batch, ro, D, rtol=1e-6, atol=1e-9, dt=0.02)  # no tree, no account


def test_the_convergence_grid_covers_the_enlarged_box():
    class D:
        starts, enlarge = 100, 0.5

    demo = demo_states()
    g = grid_starts([demo], D)
    lo, hi = demo.q.min(0), demo.q.max(0)
    assert g.shape == (100, 2)
    np.testing.assert_allclose(g.min(0), lo - 0.25 * (hi - lo))
    np.testing.assert_allclose(g.max(0), hi + 0.25 * (hi - lo))


def test_the_latent_figure_finds_the_learned_map_and_only_it():
    """plots/recorded.py draws the latent space of the node whose map has parameters: tree=lasa_map's ``latent``;
    the weights-only tree (tree=lasa) has none, so no latent figure."""
    from rmpfusion.pipeline.construct import build_learners, make_env
    from rmpfusion.plots.recorded import learned_map_nodes

    for tree, expected in (("lasa_map", ["latent"]), ("lasa", [])):
        run = validated(TINY_LASA + ["data.shape=Sshape", f"tree={tree}"])
        learner = build_learners(run, make_env(run).aux_dims())["rmp"]
        assert learned_map_nodes(learner.tree) == expected, tree


@pytest.mark.slow
def test_a_finished_run_re_evaluates_on_a_finer_step_without_training(eager_sshape_run):
    """tools/recorded_step_check.py: the trained learner of a finished run on its own step reproduces the run's own
    metrics (the same learner, demonstrations and starts), and on half the step integrates twice as finely."""
    from tools.recorded_step_check import check

    run_dir, m = eager_sshape_run
    own, finer = check(run_dir, 1.0), check(run_dir, 2.0)
    rmp = m["learners"]["rmp"]
    assert own["test_dtw"] == pytest.approx(rmp["reproduction_test"]["dtw"], rel=1e-12)
    assert own["monotone"] == rmp["convergence"]["lyapunov_monotone_fraction"] == 1.0
    assert finer["dt"] == pytest.approx(own["dt"] / 2) and finer["monotone"] == 1.0 and finer["worst_rise"] <= 0
