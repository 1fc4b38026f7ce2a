"""An exported policy is the tree, in a file that runs without rmpfusion: equal to the tree to 1e-10 at any batch
size (the pseudo-inverse where M is singular included), its metadata naming the inputs; ``rmpfusion-export``
writes it from a checkpoint, refuses to overwrite, and its AOTInductor package agrees too (slow)."""

import json
import subprocess
import sys

import pytest
import torch
from conftest import compose_cfg
from trees import TWO_LEVEL, two_level_inputs

import rmpfusion
from rmpfusion.core.export import export_tree
from rmpfusion.learn.export import METADATA

#: Load an exported file in a fresh interpreter where rmpfusion cannot be imported, run it, print its outputs.
RUN_WITHOUT_RMPFUSION = """
import sys, json, torch
sys.modules["rmpfusion"] = None  # any import of rmpfusion now fails
program = torch.export.load(sys.argv[1]).module()
inputs = torch.load(sys.argv[2])
out = program(*inputs)
torch.save(out if isinstance(out, tuple) else (out,), sys.argv[3])
"""


def _run_elsewhere(path, inputs, tmp_path):
    torch.save(inputs, tmp_path / "inputs.pt")
    r = subprocess.run(
        [sys.executable, "-c", RUN_WITHOUT_RMPFUSION, str(path), str(tmp_path / "inputs.pt"), str(tmp_path / "out.pt")],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 0, r.stderr[-2000:]
    return torch.load(tmp_path / "out.pt")


def test_the_exported_tree_runs_without_rmpfusion_and_equals_the_tree(tmp_path):
    tree = rmpfusion.build_tree(TWO_LEVEL)
    names = sorted(tree.aux_dims)
    q, qd, aux = two_level_inputs(4, torch.Generator().manual_seed(0))
    program = export_tree(tree, q, qd, aux, names, with_rmp=True)
    torch.export.save(program, tmp_path / "policy.pt2", extra_files={METADATA: json.dumps({"aux_names": names})})
    for B in (1, 7):
        q, qd, aux = two_level_inputs(B, torch.Generator().manual_seed(B))
        qdd, M, f = _run_elsewhere(tmp_path / "policy.pt2", (q, qd, *(aux[n] for n in names)), tmp_path)
        with torch.no_grad():
            ref = tree(q, qd, aux)
        for got, want in ((qdd, ref.qdd), (M, ref.M), (f, ref.f)):
            assert got.shape == want.shape and (got - want).abs().max() <= 1e-10
    extra = {METADATA: ""}
    torch.export.load(tmp_path / "policy.pt2", extra_files=extra)
    assert json.loads(extra[METADATA])["aux_names"] == names


def test_the_exported_tree_answers_with_the_pseudo_inverse_where_m_is_singular(tmp_path):
    spec = {
        "root": {"name": "q", "dim": 2},
        "nodes": {
            "x": {
                "parent": "q",
                "map": {"type": "select", "indices": [0]},
                "rmp": {"type": "damper", "w": 1.0, "eta": 1.0},
            }
        },
    }
    tree = rmpfusion.build_tree(spec)
    q = torch.zeros(3, 2, dtype=torch.float64)
    qd = torch.tensor([[1.0, 2.0], [-1.0, 0.5], [0.0, 3.0]], dtype=torch.float64)
    program = export_tree(tree, q, qd, {}, [])
    torch.export.save(program, tmp_path / "singular.pt2")
    (qdd,) = _run_elsewhere(tmp_path / "singular.pt2", (q, qd), tmp_path)
    with pytest.warns(RuntimeWarning):
        expect = tree(q, qd).qdd
    torch.testing.assert_close(qdd, expect, rtol=1e-10, atol=1e-10)


def test_a_tree_exports_only_from_a_batch_of_two_or_more():
    tree = rmpfusion.build_tree(TWO_LEVEL)
    q, qd, aux = two_level_inputs(1, torch.Generator().manual_seed(0))
    with pytest.raises(ValueError, match="at least 2"):
        export_tree(tree, q, qd, aux, sorted(tree.aux_dims))


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    """A finished tiny 2d1level run: its final checkpoint."""
    run_dir = tmp_path_factory.mktemp("run")
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "rmpfusion.cli.run",
            "experiment=2d1level",
            "data=tiny",
            "train=tiny",
            "eval=fast",
            "eval.figures=false",
            "logger=disabled",
            f"hydra.run.dir={run_dir}",
        ],
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert r.returncode == 0, r.stderr[-3000:]
    return run_dir / "checkpoints" / "rmp" / "final.pt"


@pytest.mark.slow
def test_rmpfusion_export_writes_a_checked_file_and_refuses_to_overwrite_it(tiny_run, tmp_path):
    from rmpfusion.cli.export import main

    out = tmp_path / "policy.pt2"
    assert main([str(tiny_run), "--out", str(out), "--with-rmp"]) == 0 and out.exists()
    extra = {METADATA: ""}
    torch.export.load(out, extra_files=extra)
    meta = json.loads(extra[METADATA])
    assert meta["outputs"] == ["qdd", "M", "f"] and meta["aux_names"] == [
        "goal",
        "obstacle1_center",
        "obstacle1_radius",
    ]
    assert meta["inputs"][0] == "q ({B}, 2)" and meta["learner"] == "rmp"
    before = out.read_bytes()
    assert main([str(tiny_run), "--out", str(out)]) == 2
    assert out.read_bytes() == before


@pytest.mark.slow
def test_the_aoti_package_equals_the_tree(tiny_run, tmp_path):
    from rmpfusion.cli.export import main

    out = tmp_path / "policy.pt2"
    assert main([str(tiny_run), "--out", str(out), "--aoti"]) == 0
    runner = torch._inductor.aoti_load_package(str(tmp_path / "policy-aoti.pt2"))
    program = torch.export.load(out).module()
    g = torch.Generator().manual_seed(5)
    q, qd = torch.rand(3, 2, generator=g, dtype=torch.float64), torch.randn(3, 2, generator=g, dtype=torch.float64)
    aux = (
        torch.rand(3, 2, generator=g, dtype=torch.float64),
        torch.rand(3, 2, generator=g, dtype=torch.float64),
        torch.full((3, 1), 0.5, dtype=torch.float64),
    )
    with torch.no_grad():
        assert (runner(q, qd, *aux) - program(q, qd, *aux)).abs().max() <= 1e-10


def test_a_learner_without_a_tree_exports_its_policy(tmp_path):
    """learner-un is no tree: its forward is exported (q̈ only), and asking for M and f says why not."""
    from rmpfusion.learn.export import export_learner
    from rmpfusion.pipeline.construct import build_learners, make_env
    from rmpfusion.pipeline.validate import resolve_and_validate

    cfg = resolve_and_validate(compose_cfg(["experiment=2d2level_unstructured", "logger=disabled"]))
    env = make_env(cfg)
    learner = build_learners(cfg, env.aux_dims())["un"].double()
    q, qd, aux = env.sample(n_envs=1, n_per_env=3, seed=0)
    names = sorted(env.aux_dims())
    with pytest.raises(ValueError, match="M and f exist for learners whose policy is an RMP tree"):
        export_learner(learner, q, qd, aux, names, with_rmp=True)
    torch.export.save(export_learner(learner, q, qd, aux, names), tmp_path / "un.pt2")
    (qdd,) = _run_elsewhere(tmp_path / "un.pt2", (q[:1], qd[:1], *(aux[n][:1] for n in names)), tmp_path)
    with torch.no_grad():
        assert (qdd - learner(q[:1], qd[:1], {k: v[:1] for k, v in aux.items()})).abs().max() <= 1e-10


@pytest.fixture(scope="module")
def tiny_franka_run(tmp_path_factory):
    """A finished tiny Franka run (one fixed cylinder): its final checkpoint."""
    run_dir = tmp_path_factory.mktemp("franka")
    r = subprocess.run(
        [sys.executable, "-m", "rmpfusion.cli.run", "experiment=franka", "data=tiny", "train=tiny", "eval=fast",
         "eval.figures=false", "logger=disabled", f"hydra.run.dir={run_dir}"],
        capture_output=True, text=True, timeout=1800,
    )  # fmt: skip
    assert r.returncode == 0, r.stderr[-3000:]
    return run_dir / "checkpoints" / "rmp" / "final.pt"


@pytest.mark.slow
def test_a_learner_trained_among_fixed_obstacles_exports_for_run_time_sets(tiny_franka_run, tiny_run, tmp_path):
    """``rmpfusion-export --set``: the Franka learner (trained with one cylinder) written once for a sphere set and a
    box set; the loaded program runs any world (members appear, move, vanish) and answers an obstacle in the way;
    what cannot be exported this way is refused with a message."""
    from rmpfusion.cli.export import main
    from rmpfusion.scenes import ObstacleSet, World

    out = tmp_path / "sets.pt2"
    assert main([str(tiny_franka_run), "--set", "sphere:3", "--set", "box:2", "--out", str(out)]) == 0
    extra = {METADATA: ""}
    program = torch.export.load(out, extra_files=extra).module()
    meta = json.loads(extra[METADATA])
    assert [s["shape"] for s in meta["sets"]] == ["sphere", "box"] and meta["inputs"][2].startswith("goal ")
    world = World([ObstacleSet(shape="sphere", n_max=3), ObstacleSet(shape="box", n_max=2)], goal=[0.55, -0.3, 0.4])
    q = torch.tensor([[0.8, -0.3, 0.0, -2.2, 0.0, 2.0, 0.785]], dtype=torch.float64)
    qd = torch.zeros_like(q)
    empty = program(q, qd, *world.set_aux().values())
    world.add("sphere", name="ball", center=[0.45, 0.15, 0.45], radius=0.08)
    with_ball = program(q, qd, *world.set_aux().values())
    world.add("box", center=[0.3, -0.4, 0.3], half_extents=[0.05, 0.1, 0.2])
    world.move("ball", center=[0.5, 0.1, 0.5])
    world.remove("ball")
    later = program(q, qd, *world.set_aux().values())
    assert all(t.isfinite().all() for t in (empty, with_ball, later))
    assert (with_ball - empty).abs().max() > 1e-6  # the ball near the arm changes the command
    nearest = tmp_path / "nearest.pt2"  # each control point's 2 nearest of 6 spheres, selected inside the program
    assert main([str(tiny_franka_run), "--set", "sphere:6:nearest=2", "--out", str(nearest)]) == 0
    selecting = torch.export.load(nearest).module()
    spheres = World([ObstacleSet(shape="sphere", n_max=6, nearest=2)], goal=[0.55, -0.3, 0.4])
    far = selecting(q, qd, *spheres.set_aux().values())
    spheres.add("sphere", center=[0.45, 0.15, 0.45], radius=0.08)
    assert (selecting(q, qd, *spheres.set_aux().values()) - far).abs().max() > 1e-6
    assert main([str(tiny_run), "--set", "sphere:3", "--out", str(tmp_path / "2d.pt2")]) == 2  # no control points
    assert main([str(tiny_franka_run), "--set", "torus:3"]) == 2
    assert main([str(tiny_franka_run), "--set", "sphere:3", "--with-rmp"]) == 2
