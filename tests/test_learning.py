"""Learning pipeline: datasets (determinism, tamper detection), learners, behavior cloning with exact resume,
and the whole 2D experiment end to end on tiny sizes."""

import itertools
import json
import os
from pathlib import Path

import pytest
import torch

from rmpfusion.assembly import tree_with_weights
from rmpfusion.assembly.errors import ConfigError
from rmpfusion.assembly.tree import build_tree
from rmpfusion.envs import DatasetError, Particle2D, collect, load_dataset, save_dataset
from rmpfusion.learn import RMPLearner, train, width_for_parameters
from rmpfusion.learn.config import TrainConfig
from rmpfusion.learn.learners import build_learner
from rmpfusion.learn.unstructured import mlp_parameters
from rmpfusion.pipeline.config import RunConfig
from rmpfusion.pipeline.run import run_experiment
from rmpfusion.registry import LEARNERS


def _rbf(center, radius, low, high, sigma):
    return {"type": "rbf", "center": center, "radius": radius, "low": low, "high": high, "sigma": sigma}


def _obstacle(parent, k):
    return {
        "parent": parent,
        "rmp": {"type": "collision_avoidance"},
        "map": {"type": "sphere_distance", "center": f"obstacle{k}_center", "radius": f"obstacle{k}_radius"},
    }


GOAL = {"parent": "q", "map": {"type": "offset", "origin": "goal"}, "rmp": {"type": "goal_attractor"}}
METRIC = {"parent": "q", "rmp": {"type": "identity_metric", "scale": 0.01}}

TREE_1LEVEL = {
    "root": {"name": "q", "dim": 2},
    "nodes": {"obstacle": _obstacle("q", 1), "goal": GOAL, "metric": METRIC},
}
EXPERT_1LEVEL = {
    "obstacle": _rbf("obstacle1_center", "obstacle1_radius", 1.0, 5.0, 0.5),
    "goal": _rbf("goal", 0.0, 1.0, 2.0, 1.0),
}
TREE_2LEVEL = {
    "root": {"name": "q", "dim": 2},
    "nodes": {
        "goal": GOAL,
        "obstacles": {"parent": "q", "map": {"type": "identity"}},
        "obstacle1": _obstacle("obstacles", 1),
        "obstacle2": _obstacle("obstacles", 2),
        "metric": METRIC,
    },
}
EXPERT_2LEVEL = {
    "goal": _rbf("goal", 0.0, 1.0, 2.0, 1.0),
    "obstacles": {
        "type": "logistic",
        "center": "goal",
        "radius": 0.0,
        "low": 0.5,
        "high": 2.0,
        "steepness": 2.0,
        "switch_distance": 1.0,
    },
    "obstacle1": _rbf("obstacle1_center", "obstacle1_radius", 1.0, 5.0, 0.5),
    "obstacle2": _rbf("obstacle2_center", "obstacle2_radius", 1.0, 5.0, 0.5),
}
RMP_LEARNER = {"type": "rmp", "weights": {"type": "mlp", "hidden": [8, 8], "aux": "all"}}


def tiny_config(level: int = 1, learners=None, iterations: int = 50, **data) -> RunConfig:
    tree, expert = (TREE_1LEVEL, EXPERT_1LEVEL) if level == 1 else (TREE_2LEVEL, EXPERT_2LEVEL)
    return RunConfig(
        name=f"tiny-2d{level}level",
        seed=3,
        env={"type": "particle2d", "n_obstacles": level, "dt": 0.01},  # coarser RK4 steps break V's monotonicity
        tree=tree,
        expert=expert,
        learners=learners or {"learner-rmp": RMP_LEARNER},
        data={
            "train_envs": 2,
            "train_trajectories": 3,
            "test_envs": 2,
            "test_trajectories": 2,
            "points": 4,
            "interval": 0.25,
            **data,
        },
        train={
            "iterations": iterations,
            "batch_size": 16,
            "snapshots": [0, iterations // 2, iterations],
            "log_every": 10,
            "checkpoint_every": 25,
            "lr": 1e-3,
        },
        eval={"figures": True},
        logger={"mode": "disabled"},
    )


def _expert(level=1):
    env = Particle2D(n_obstacles=level, dt=0.05)
    tree, w = (TREE_1LEVEL, EXPERT_1LEVEL) if level == 1 else (TREE_2LEVEL, EXPERT_2LEVEL)
    return env, build_tree(tree_with_weights(tree, w), aux_dims=env.aux_dims())


@pytest.fixture(scope="module")
def small_data():
    env, expert = _expert()
    ds = collect(env, expert, 2, 3, 5, 0.5, torch.Generator().manual_seed(0))
    return env, expert, ds


# ------------------------------------------------------------------------------------------ weighting
def test_tree_with_weights_names_missing_node_and_copies():
    with pytest.raises(ConfigError, match="nodes.obstacel|'obstacel' is not a node"):
        tree_with_weights(TREE_1LEVEL, {"obstacel": {"type": "constant"}})
    with pytest.raises(ConfigError, match="root"):
        tree_with_weights(TREE_1LEVEL, {"q": {"type": "constant"}})
    out = tree_with_weights(TREE_1LEVEL, {"goal": {"type": "constant", "value": 2.0}})
    assert out["nodes"]["goal"]["weight"] == {"type": "constant", "value": 2.0}
    assert "weight" not in TREE_1LEVEL["nodes"]["goal"]  # the input spec is untouched


# ------------------------------------------------------------------------------------------ datasets
def test_dataset_layout_labels_are_expert_accelerations(small_data):
    _env, expert, ds = small_data
    assert len(ds) == 2 * 3 * 5
    assert ds.env_id.tolist() == [i // 15 for i in range(30)]
    assert torch.allclose(ds.t[:5], torch.tensor([0.0, 0.5, 1.0, 1.5, 2.0]))
    with torch.no_grad():
        again = expert(ds.q, ds.qd, ds.aux).qdd
    assert torch.allclose(again, ds.qdd, atol=1e-12)
    # consecutive records of one trajectory are the rollout, not independent samples
    assert not torch.allclose(ds.q[0], ds.q[1])
    assert torch.equal(ds.aux["goal"][0], ds.aux["goal"][4])


def test_dataset_determinism_and_roundtrip(tmp_path, small_data):
    env, expert, ds = small_data
    ds2 = collect(env, expert, 2, 3, 5, 0.5, torch.Generator().manual_seed(0))
    ds3 = collect(env, expert, 2, 3, 5, 0.5, torch.Generator().manual_seed(1))
    assert ds.checksum() == ds2.checksum()
    assert ds.checksum() != ds3.checksum()
    meta = {"seed": 0, "config_hash": "abc"}
    s1 = save_dataset(tmp_path / "a.pt", ds, meta)
    s2 = save_dataset(tmp_path / "b.pt", ds2, meta)
    assert s1 == s2 == ds.checksum()
    back = load_dataset(tmp_path / "a.pt", meta)
    assert back.checksum() == s1 and torch.equal(back.qdd, ds.qdd)
    assert not [p for p in os.listdir(tmp_path) if ".tmp" in p]  # atomic write leaves no temp files


def test_dataset_tamper_truncation_meta_and_missing(tmp_path, small_data):
    _, _, ds = small_data
    meta = {"seed": 0, "config_hash": "abc"}
    p = tmp_path / "d.pt"
    save_dataset(p, ds, meta)
    with pytest.raises(DatasetError, match="different configuration.*seed"):
        load_dataset(p, {"seed": 1, "config_hash": "abc"})
    # tamper: same format, one label changed, old checksum kept
    payload = torch.load(p, weights_only=True)
    payload["tensors"]["qdd"][3, 0] += 1e-9
    torch.save(payload, p)
    with pytest.raises(DatasetError, match=r"checksum.*delete .*d\.pt"):
        load_dataset(p, meta)
    save_dataset(p, ds, meta)
    raw = p.read_bytes()
    p.write_bytes(raw[: len(raw) // 2])
    with pytest.raises(DatasetError, match=r"unreadable or truncated.*delete"):
        load_dataset(p, meta)
    with pytest.raises(DatasetError, match="does not exist"):
        load_dataset(tmp_path / "nope.pt", meta)


# ------------------------------------------------------------------------------------------ learners
def test_learners_registered_and_rmp_edges():
    assert {"rmp", "unstructured"} <= set(LEARNERS.names())
    env = Particle2D(n_obstacles=2)
    aux = env.aux_dims()
    p = RMPLearner.Params(weights={"type": "mlp", "hidden": [8], "aux": "all"})
    with_expert = RMPLearner(p, TREE_2LEVEL, aux, 2, expert=EXPERT_2LEVEL)
    assert with_expert.edges == ["goal", "obstacles", "obstacle1", "obstacle2"]
    without = RMPLearner(p, TREE_2LEVEL, aux, 2)
    assert "metric" not in without.edges and "obstacles" in without.edges
    w = with_expert.tree.weights["goal"].fn
    assert w.aux_names == sorted(aux)  # aux: all
    with pytest.raises(ConfigError, match="nope"):
        RMPLearner(RMPLearner.Params(edges=["nope"]), TREE_2LEVEL, aux, 2)
    q, qd, a = env.sample(2, 2, seed=0)
    assert with_expert(q, qd, a).shape == (4, 2)
    assert with_expert.policy(q, qd, a).V.shape == (4,)


def test_edge_weights_override_the_shared_spec_per_edge():
    aux = Particle2D(n_obstacles=2).aux_dims()
    own = {"obstacle1": {"aux": ["obstacle1_center", "obstacle1_radius"]}, "goal": {"aux": ["goal"], "hidden": [4]}}
    m = RMPLearner(
        RMPLearner.Params(weights={"type": "mlp", "hidden": [8], "aux": "all"}, edge_weights=own),
        TREE_2LEVEL,
        aux,
        2,
        expert=EXPERT_2LEVEL,
    )
    w = {n: m.tree.weights[n].fn for n in m.edges}
    assert w["obstacle1"].aux_names == ["obstacle1_center", "obstacle1_radius"]
    assert w["obstacle1"].layers[0].in_features == 2 + 3  # q, then the obstacle's centre and radius
    assert w["goal"].aux_names == ["goal"] and w["goal"].layers[0].out_features == 4
    assert w["obstacle2"].aux_names == sorted(aux)  # untouched edges keep the shared spec
    with pytest.raises(ConfigError, match=r"learners\.rmp\.edge_weights\.metric: 'metric' is not a learned edge"):
        RMPLearner(
            RMPLearner.Params(edge_weights={"metric": {"aux": ["goal"]}}), TREE_2LEVEL, aux, 2, expert=EXPERT_2LEVEL
        )


@pytest.mark.parametrize("target,depth", [(1000, 2), (5800, 2), (300, 1), (20000, 3)])
def test_width_for_parameters_is_closest(target, depth):
    w = width_for_parameters(target, 9, 2, depth)
    best = min(range(1, 400), key=lambda k: abs(mlp_parameters(9, 2, [k] * depth) - target))
    assert abs(mlp_parameters(9, 2, [w] * depth) - target) == abs(mlp_parameters(9, 2, [best] * depth) - target)


def test_unstructured_matches_parameter_count():
    env = Particle2D(n_obstacles=2)
    aux = env.aux_dims()
    rmp = build_learner(RMP_LEARNER, TREE_2LEVEL, aux, 2, expert=EXPERT_2LEVEL)
    un = build_learner(
        {"type": "unstructured", "hidden": [1, 1], "match_parameters_of": "rmp"},
        TREE_2LEVEL,
        aux,
        2,
        built={"rmp": rmp},
    )
    big = build_learner(
        {"type": "unstructured", "hidden": [1, 1], "match_parameters_of": "rmp", "parameter_ratio": 5.8},
        TREE_2LEVEL,
        aux,
        2,
        built={"rmp": rmp},
    )
    n = rmp.num_parameters()
    assert abs(un.num_parameters() - n) / n < 0.1
    assert abs(big.num_parameters() / n - 5.8) < 0.3
    with pytest.raises(ValueError, match="not built"):
        build_learner({"type": "unstructured", "match_parameters_of": "ghost"}, TREE_2LEVEL, aux, 2, built={})
    q, qd, a = env.sample(1, 3, seed=0)
    assert un(q, qd, a).shape == (3, 2)


def _every_tensor(model: torch.nn.Module) -> dict[str, torch.Tensor]:
    """Parameters, buffers and plain tensor attributes of every submodule (constants included)."""
    out = {}
    for name, mod in model.named_modules():
        for k, v in [*vars(mod).items(), *mod._parameters.items(), *mod._buffers.items()]:
            if isinstance(v, torch.Tensor):
                out[f"{name}.{k}"] = v.detach().clone()
    return out


_BLOCKS = {
    "rmp": RMP_LEARNER,
    "rmp_bias": {
        "type": "rmp",
        "weights": {"type": "mlp", "hidden": [8], "aux": "all", "init_bias": 1.5, "activation": "softplus"},
    },
    "un": {"type": "unstructured", "hidden": [4, 4], "match_parameters_of": "rmp"},
    "un_relu": {"type": "unstructured", "hidden": [5, 3], "activation": "relu"},
}


def _build_all(default_dtype: torch.dtype) -> dict[str, dict[str, torch.Tensor]]:
    old = torch.get_default_dtype()
    torch.set_default_dtype(default_dtype)
    try:
        aux, built = Particle2D(n_obstacles=2).aux_dims(), {}
        for name, block in _BLOCKS.items():
            torch.manual_seed(7)
            built[name] = build_learner(block, TREE_2LEVEL, aux, 2, expert=EXPERT_2LEVEL, built=built)
        return {name: _every_tensor(m) for name, m in built.items()}
    finally:
        torch.set_default_dtype(old)


def test_initial_weights_are_float64_and_the_same_whatever_the_default_dtype():
    """Learners build every layer in float64 themselves: under torch's float32 default a seed draws exactly the
    weights (and constants) it drew when construction ran under a float64 default (as build_learner once forced)."""
    got, reference = _build_all(torch.float32), _build_all(torch.float64)
    for name, tensors in reference.items():
        assert got[name].keys() == tensors.keys(), name
        for k, v in tensors.items():
            assert got[name][k].dtype == v.dtype and torch.equal(got[name][k], v), f"{name}: {k}"
    params = [v for name in reference for k, v in reference[name].items() if "weight" in k or "bias" in k]
    assert params and all(v.dtype == torch.float64 for v in params)


def test_learners_state_what_they_offer():
    """What callers used to probe for is part of every learner: its tree (or None), what metrics.json reports
    about it, and compiling it; a registered class that is no Learner is refused by name."""
    from rmpfusion.core.tree import RMPTree
    from rmpfusion.learn import Learner, UnstructuredLearner
    from rmpfusion.registry import Params as NoParams

    aux = Particle2D(n_obstacles=2).aux_dims()
    rmp = build_learner(RMP_LEARNER, TREE_2LEVEL, aux, 2, expert=EXPERT_2LEVEL)
    un = build_learner({"type": "unstructured", "hidden": [4, 3]}, TREE_2LEVEL, aux, 2)
    assert isinstance(rmp, Learner) and isinstance(un, UnstructuredLearner)
    assert isinstance(rmp.tree, RMPTree) and un.tree is None
    assert rmp.describe() == {} and un.describe() == {"hidden": [4, 3]}
    assert any(k.startswith("tree.weights.goal.fn.") for k in rmp.state_dict())  # checkpoints keep their keys
    q, qd, a = Particle2D(n_obstacles=2).sample(1, 3, seed=0)
    assert torch.is_tensor(un.policy(q, qd, a)) and rmp.policy(q, qd, a).V.shape == (3,)
    assert un.compile() is un and rmp.compile() is rmp and rmp.tree._compile_args is not None  # compiles on use

    @LEARNERS.register("not_a_learner")
    class Plain(torch.nn.Module):
        Params = NoParams

    try:
        with pytest.raises(TypeError, match="'not_a_learner'.*not a subclass of rmpfusion.learn.learner.Learner"):
            build_learner({"type": "not_a_learner"}, TREE_2LEVEL, aux, 2)
    finally:
        LEARNERS.unregister("not_a_learner")


# ------------------------------------------------------------------------------------------ training
def _learner(seed=0):
    torch.manual_seed(seed)
    return RMPLearner(
        RMPLearner.Params(weights={"type": "mlp", "hidden": [8], "aux": "all"}),
        TREE_1LEVEL,
        Particle2D().aux_dims(),
        2,
        expert=EXPERT_1LEVEL,
    )


def test_training_reduces_loss_and_keeps_snapshots(small_data):
    _, _, ds = small_data
    cfg = TrainConfig(iterations=60, batch_size=16, snapshots=[0, 30, 60], log_every=20, lr=3e-3)
    model = _learner()
    logged = []
    res = train(model, ds, cfg, seed=0, test_data=ds, log=logged.append)
    assert sorted(res.snapshots) == [0, 30, 60]
    assert [m["iteration"] for m in logged] == [20.0, 40.0, 60.0]
    assert res.test_curve[-1][1] < res.test_curve[0][1]
    assert not torch.equal(
        res.snapshots[0]["tree.weights.goal.fn.layers.0.weight"],
        res.snapshots[60]["tree.weights.goal.fn.layers.0.weight"],
    )


@pytest.mark.parametrize("optimizer", ["rmsprop", "adam"])
def test_resume_equals_uninterrupted(tmp_path, small_data, optimizer):
    _, _, ds = small_data
    full = TrainConfig(
        optimizer=optimizer, iterations=40, batch_size=8, snapshots=[0, 10, 40], checkpoint_every=20, log_every=10
    )
    a = _learner()
    ra = train(a, ds, full, seed=5, checkpoint_dir=tmp_path / "a")
    b = _learner()
    half = full.model_copy(update={"iterations": 20})
    train(b, ds, half, seed=5, checkpoint_dir=tmp_path / "b")
    b2 = _learner(seed=99)  # a fresh process: different init, everything must come from the checkpoint
    rb = train(b2, ds, full, seed=5, checkpoint_dir=tmp_path / "b")
    assert rb.resumed_from == 20
    for k, v in a.state_dict().items():
        assert torch.equal(v, b2.state_dict()[k]), k
    assert ra.curve == rb.curve
    assert all(torch.equal(ra.snapshots[i][k], rb.snapshots[i][k]) for i in ra.snapshots for k in ra.snapshots[i])
    with pytest.raises(RuntimeError, match="different training settings"):
        train(_learner(), ds, full.model_copy(update={"lr": 0.5}), seed=5, checkpoint_dir=tmp_path / "b")


def test_cosine_schedule_anneals_and_resumes_exactly(tmp_path, small_data):
    """The step size is a function of the iteration alone: lr at the start, lr·lr_final_fraction at the end, and a run
    interrupted after a checkpoint resumes on the same schedule to the same weights."""
    from rmpfusion.learn.train import learning_rate

    _, _, ds = small_data
    cfg = TrainConfig(
        optimizer="rmsprop",
        lr=1e-2,
        lr_schedule="cosine",
        lr_final_fraction=0.1,
        iterations=40,
        batch_size=8,
        snapshots=[0, 40],
        checkpoint_every=20,
        log_every=10,
    )
    lrs = [learning_rate(cfg, i) for i in range(40)]
    assert lrs[0] == pytest.approx(1e-2) and lrs[-1] == pytest.approx(1e-3)
    assert all(a >= b for a, b in itertools.pairwise(lrs))
    a = _learner()
    train(a, ds, cfg, seed=5, checkpoint_dir=tmp_path / "a")

    class Interrupted(Exception):
        pass

    def stop_after_25(done, total):
        if done == 25:
            raise Interrupted

    with pytest.raises(Interrupted):
        train(_learner(), ds, cfg, seed=5, checkpoint_dir=tmp_path / "b", progress=stop_after_25)
    b = _learner(seed=99)
    rb = train(b, ds, cfg, seed=5, checkpoint_dir=tmp_path / "b")
    assert rb.resumed_from == 20
    for k, v in a.state_dict().items():
        assert torch.equal(v, b.state_dict()[k]), k
    with pytest.raises(RuntimeError, match="different training settings"):  # the schedule spans `iterations`
        train(_learner(), ds, cfg.model_copy(update={"iterations": 60}), seed=5, checkpoint_dir=tmp_path / "b")


def _as_before_the_rename(path: Path) -> None:
    """Rewrite a checkpoint as it was written while ``train.lr_final_fraction`` was called ``lr_final``."""
    from rmpfusion.learn.checkpoints import load_checkpoint, save_checkpoint

    state = load_checkpoint(path)
    payload = {k: v for k, v in state.items() if k not in ("sha256", "format")}
    tc = dict(payload["train_config"])
    tc["lr_final"] = tc.pop("lr_final_fraction")
    payload["train_config"] = tc
    run = json.loads(json.dumps(payload["config"]))
    run["train"]["lr_final"] = run["train"].pop("lr_final_fraction")
    payload["config"] = run
    save_checkpoint(payload, path)
    assert "lr_final_fraction" not in load_checkpoint(path)["train_config"]


def test_a_checkpoint_that_stored_lr_final_still_resumes(tmp_path, small_data):
    """``train.lr_final`` was renamed ``lr_final_fraction``: a checkpoint written under the old name resumes to
    the weights of an uninterrupted run, its embedded config still validates (rmpfusion-evaluate-checkpoint),
    and its old value is still compared with the new setting."""
    from rmpfusion.learn.checkpoints import load_checkpoint
    from rmpfusion.pipeline.config import upgrade_run_config

    _, _, ds = small_data
    cfg = TrainConfig(
        optimizer="rmsprop",
        lr=1e-2,
        lr_schedule="cosine",
        lr_final_fraction=0.1,
        iterations=40,
        batch_size=8,
        snapshots=[0, 40],
        checkpoint_every=20,
        log_every=10,
    )
    run_config = tiny_config(iterations=40).model_copy(update={"train": cfg}).model_dump(mode="json")
    a = _learner()
    train(a, ds, cfg, seed=5, checkpoint_dir=tmp_path / "a")
    with pytest.raises(_Interrupted):  # killed after the checkpoint at iteration 20
        train(
            _learner(),
            ds,
            cfg,
            seed=5,
            checkpoint_dir=tmp_path / "b",
            run_config=run_config,
            progress=lambda done, total: _interrupt_at(done, 25),
        )
    ck = tmp_path / "b" / "ckpt-00000020.pt"
    _as_before_the_rename(ck)
    old = load_checkpoint(ck)
    assert old["train_config"]["lr_final"] == 0.1 and old["config"]["train"]["lr_final"] == 0.1
    assert RunConfig.model_validate(upgrade_run_config(old["config"])).train.lr_final_fraction == 0.1
    with pytest.raises(RuntimeError, match=r"different training settings \(lr_final_fraction: 0.1 vs 0.5\)"):
        train(_learner(), ds, cfg.model_copy(update={"lr_final_fraction": 0.5}), seed=5, checkpoint_dir=tmp_path / "b")
    b = _learner(seed=99)
    rb = train(b, ds, cfg, seed=5, checkpoint_dir=tmp_path / "b", run_config=run_config)
    assert rb.resumed_from == 20
    for k, v in a.state_dict().items():
        assert torch.equal(v, b.state_dict()[k]), k


class _Interrupted(Exception):
    pass


def _interrupt_at(done: int, at: int) -> None:
    if done == at:
        raise _Interrupted


def test_the_old_name_lr_final_is_reported_with_the_new_one(tmp_path):
    """A config that still says train.lr_final is told the new name; a run directory saved under the old name is
    still the same configuration (a rerun there resumes instead of being refused)."""
    import yaml

    from rmpfusion.cli.rundir import RESOLVED, check_same_config
    from rmpfusion.pipeline.validate import resolve_and_validate

    data = tiny_config().model_dump(mode="json")
    data["train"]["lr_final"] = data["train"].pop("lr_final_fraction")
    with pytest.raises(ConfigError) as err:
        resolve_and_validate(data)
    assert [(i.path, i.message) for i in err.value.issues] == [
        ("train.lr_final", "was renamed train.lr_final_fraction; write train.lr_final_fraction=0.01 instead")
    ]
    (tmp_path / RESOLVED).write_text(yaml.safe_dump(data))
    check_same_config(tiny_config().model_dump(mode="json"), tmp_path)  # no RunDirError
    changed = tiny_config().model_copy(update={"train": TrainConfig(lr_final_fraction=0.5)}).model_dump(mode="json")
    with pytest.raises(Exception, match=r"train.lr_final_fraction: 0.01 \(saved\) vs 0.5 \(now\)"):
        check_same_config(changed, tmp_path)


def test_a_registered_objective_and_optimiser_train_without_editing_train(small_data):
    """A plugin's objective and optimiser are named in the training block like the built-in ones."""
    from rmpfusion.learn.objectives import Objective, dataset_loss
    from rmpfusion.registry import OBJECTIVES, OPTIMIZERS, Params

    _, _, ds = small_data
    calls = {"objective": 0, "optimizer": 0}

    @OBJECTIVES.register("test_l1")
    class L1(Objective):
        def __call__(self, pred, target):
            calls["objective"] += 1
            return (pred - target).abs().mean()

        def total(self, pred, target):
            return (pred - target).abs().sum()

    @OPTIMIZERS.register("test_momentum", params=Params)
    def momentum(parameters, lr):
        calls["optimizer"] += 1
        return torch.optim.SGD(parameters, lr=lr, momentum=0.9)

    try:
        cfg = TrainConfig(
            optimizer="test_momentum", objective="test_l1", iterations=2, batch_size=8, snapshots=[0, 2], log_every=1
        )
        model = _learner()
        before = dataset_loss(model, ds, "test_l1")
        res = train(model, ds, cfg, seed=0, test_data=ds)
        assert calls == {"objective": 2, "optimizer": 1} and len(res.curve) == 2
        assert res.test_curve[0] == (0, before)  # the held-out curve is the run's own objective
        assert res.test_curve[-1][1] == dataset_loss(model, ds, L1())
    finally:
        OBJECTIVES.unregister("test_l1")
        OPTIMIZERS.unregister("test_momentum")


def test_an_unknown_optimiser_or_objective_names_the_registered_ones():
    from pydantic import ValidationError

    from rmpfusion.pipeline.validate import resolve_and_validate

    with pytest.raises(
        ValidationError,
        match=r"unknown optimizer 'adamm'; did you mean 'adam'\? "
        r"registered: adam, rmsprop, sgd",
    ):
        TrainConfig(optimizer="adamm")
    with pytest.raises(ValidationError, match=r"unknown objective 'mes'; did you mean 'mse'\? registered: mse"):
        TrainConfig(objective="mes")
    data = tiny_config().model_dump(mode="json")
    data["train"]["optimizer"] = "rmsprob"
    with pytest.raises(ConfigError) as err:
        resolve_and_validate(data)
    assert [i.path for i in err.value.issues] == ["train.optimizer"]
    assert "did you mean 'rmsprop'?" in err.value.issues[0].message


def test_files_stored_before_train_objective_existed_still_resume(tmp_path, small_data):
    """A checkpoint (and a run directory) written before ``train.objective`` existed trained the MSE: it resumes
    to the weights of an uninterrupted run, and its embedded config still validates."""
    import yaml

    from rmpfusion.cli.rundir import RESOLVED, check_same_config
    from rmpfusion.learn.checkpoints import load_checkpoint, save_checkpoint
    from rmpfusion.pipeline.config import upgrade_run_config

    _, _, ds = small_data
    cfg = TrainConfig(iterations=40, batch_size=8, snapshots=[0, 40], checkpoint_every=20, log_every=10)
    run_config = tiny_config(iterations=40).model_copy(update={"train": cfg}).model_dump(mode="json")
    a = _learner()
    train(a, ds, cfg, seed=5, checkpoint_dir=tmp_path / "a")
    with pytest.raises(_Interrupted):
        train(
            _learner(),
            ds,
            cfg,
            seed=5,
            checkpoint_dir=tmp_path / "b",
            run_config=run_config,
            progress=lambda done, total: _interrupt_at(done, 25),
        )
    ck = tmp_path / "b" / "ckpt-00000020.pt"
    state = load_checkpoint(ck)
    payload = {k: v for k, v in state.items() if k not in ("sha256", "format")}
    payload["train_config"] = {k: v for k, v in payload["train_config"].items() if k != "objective"}
    old_run = json.loads(json.dumps(payload["config"]))
    del old_run["train"]["objective"]
    payload["config"] = old_run
    save_checkpoint(payload, ck)
    assert RunConfig.model_validate(upgrade_run_config(load_checkpoint(ck)["config"])).train.objective == "mse"
    b = _learner(seed=99)
    rb = train(b, ds, cfg, seed=5, checkpoint_dir=tmp_path / "b", run_config=run_config)
    assert rb.resumed_from == 20
    for k, v in a.state_dict().items():
        assert torch.equal(v, b.state_dict()[k]), k
    (tmp_path / RESOLVED).write_text(yaml.safe_dump({**run_config, "train": old_run["train"]}))
    check_same_config(run_config, tmp_path)  # the same run: no RunDirError


# ------------------------------------------------------------------------------------------ pipeline
@pytest.mark.slow
def test_pipeline_end_to_end_2d1level(tmp_path, capsys):
    cfg = tiny_config(1)
    logged = []
    m = run_experiment(cfg, tmp_path / "run", progress=True, log=logged.append)
    on_disk = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert on_disk["learners"].keys() == m["learners"].keys() == {"learner-rmp"}
    r = on_disk["learners"]["learner-rmp"]
    assert set(r["snapshots"]) == {"0", "25", "50"}
    final = r["snapshots"]["50"]
    for k in ("batch_loss", "online_loss", "success", "collision", "lyapunov_monotone_fraction"):
        assert r[k] == final[k], k  # the reported metrics are the last snapshot's
    # numbers, not null (a diverged learner's inf is written as null), and training lowered the online loss too
    assert 0 < r["batch_loss"] < float("inf") and 0 < r["online_loss"] < float("inf")
    assert r["online_loss"] < r["snapshots"]["0"]["online_loss"]
    # the barrier leaves keep the structured learner out of the obstacle, like the expert
    assert r["collision"] == 0.0 and on_disk["expert"]["collision"] == 0.0
    assert isinstance(r["num_parameters"], int) and r["num_parameters"] > 0
    # Theorem 2: learner-rmp's V_r never rises, at every snapshot including the untrained one
    assert all(s["lyapunov_monotone_fraction"] == 1.0 for s in r["snapshots"].values())
    assert r["snapshots"]["50"]["batch_loss"] < r["snapshots"]["0"]["batch_loss"]
    assert on_disk["expert"]["lyapunov_monotone_fraction"] == 1.0
    figs = {os.path.basename(f) for f in on_disk["figures"]}
    assert {
        "trajectories_learner-rmp.png",
        "lyapunov_learner-rmp.png",
        "learning_curve_learner-rmp.png",
        "progression_learner-rmp.png",
        "learning_curves.png",
    } <= figs
    for f in on_disk["figures"]:
        assert Path(f).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert any("learner-rmp/train_loss" in e for e in logged)
    out = capsys.readouterr().out
    assert "collecting train set" in out and "\r" not in out  # plain lines when not a TTY
    # a rerun reuses the dataset and the finished checkpoints, and lands on the same numbers
    m2 = run_experiment(cfg, tmp_path / "run", progress=False)
    assert m2["data"]["train"]["reused"] and m2["data"]["train"]["sha256"] == m["data"]["train"]["sha256"]
    assert m2["learners"]["learner-rmp"]["batch_loss"] == m["learners"]["learner-rmp"]["batch_loss"]
    # a tampered cache is refused, not silently retrained on
    path = m["data"]["train"]["path"]
    payload = torch.load(path, weights_only=True)
    payload["tensors"]["q"][0, 0] += 1.0
    torch.save(payload, path)
    with pytest.raises(DatasetError, match="checksum"):
        run_experiment(cfg, tmp_path / "run", progress=False)


@pytest.mark.slow
def test_pipeline_2d2level_structured_and_unstructured(tmp_path):
    learners = {
        "learner-rmp": RMP_LEARNER,
        "learner-un": {"type": "unstructured", "hidden": [4, 4], "match_parameters_of": "learner-rmp"},
        "learner-un-large": {
            "type": "unstructured",
            "hidden": [4, 4],
            "match_parameters_of": "learner-rmp",
            "parameter_ratio": 5.8,
        },
    }
    cfg = tiny_config(2, learners=learners, iterations=20)
    m = run_experiment(cfg, tmp_path / "run2", progress=False)
    L = m["learners"]
    n = L["learner-rmp"]["num_parameters"]
    assert abs(L["learner-un"]["num_parameters"] / n - 1) < 0.1
    assert abs(L["learner-un-large"]["num_parameters"] / n - 5.8) < 0.3
    assert "lyapunov_monotone_fraction" not in L["learner-un"]
    assert all(s["lyapunov_monotone_fraction"] == 1.0 for s in L["learner-rmp"]["snapshots"].values())
    assert (tmp_path / "run2" / "figures" / "progression_learner-un.png").exists()


def _final_is_a_checksummed_checkpoint(final: Path, last: Path) -> None:
    """``final.pt`` holds the trained learner in the format of every checkpoint: read back through the checksum
    check (an edited weight is refused), with the last checkpoint's weights and the run config."""
    from rmpfusion.learn.checkpoints import CheckpointError, load_checkpoint

    state, ckpt = load_checkpoint(final), load_checkpoint(last)
    assert state["iteration"] == ckpt["iteration"] and state["config"] == ckpt["config"]
    assert state["model"].keys() == ckpt["model"].keys()
    assert all(torch.equal(v, ckpt["model"][k]) for k, v in state["model"].items())
    raw = torch.load(final, weights_only=True)
    next(iter(raw["model"].values())).view(-1)[0] += 1e-9
    edited = final.with_name("edited.pt")
    torch.save(raw, edited)
    with pytest.raises(CheckpointError, match="fails its checksum"):
        load_checkpoint(edited)
    edited.unlink()


def test_evaluation_from_a_checkpoint_alone(tmp_path):
    """A training checkpoint carries the run config: rebuilding everything from it alone gives exactly the
    pipeline's final metrics, and a damaged checkpoint is refused with the file named (exit code 2)."""
    from rmpfusion.cli.from_checkpoint import evaluate_checkpoint, main

    cfg = tiny_config(1, iterations=20)
    m = run_experiment(cfg, tmp_path / "run", progress=False)
    ck = tmp_path / "run" / "checkpoints" / "learner-rmp" / "ckpt-00000020.pt"
    assert ck.exists()
    _final_is_a_checksummed_checkpoint(ck.parent / "final.pt", ck)
    res = evaluate_checkpoint(ck, tmp_path / "eval", progress=False)
    want = m["learners"]["learner-rmp"]
    for k in ("batch_loss", "online_loss", "success", "collision", "lyapunov_monotone_fraction"):
        assert res["metrics"][k] == want[k], k
    assert res["test_data"]["reused"] and res["iteration"] == 20
    assert json.loads((tmp_path / "eval" / "metrics.json").read_text())["metrics"] == res["metrics"]
    assert {Path(p).name for p in res["figures"]} == {"lyapunov_learner-rmp.png", "trajectories_learner-rmp.png"}
    data = bytearray(ck.read_bytes())
    data[len(data) // 2] ^= 0xFF
    bad = tmp_path / "bad" / "checkpoints" / "learner-rmp" / "ckpt-00000020.pt"
    bad.parent.mkdir(parents=True)
    bad.write_bytes(bytes(data))
    assert main([str(bad), "--out", str(tmp_path / "bad_eval")]) == 2
    assert not (tmp_path / "bad_eval" / "metrics.json").exists()


def test_normalised_mse_weighs_coordinates_by_their_spread_and_samples_by_their_speed():
    """The recorded-demonstration objective, against its formula written out: each coordinate in units of its
    spread over the training set, each sample weighted by its speed over its demonstration's mean speed (floored,
    mean 1); whole-dataset losses are the same quantity, and the reported loss of a run trained on it is the MSE."""
    from rmpfusion.envs.demonstrations import Dataset
    from rmpfusion.learn.objectives import dataset_loss, make_objective

    gen = torch.Generator().manual_seed(0)
    n = 40
    traj = torch.arange(n) // 20  # two demonstrations of 20 samples
    qd = torch.rand(n, 2, generator=gen, dtype=torch.float64) * torch.tensor([1.0, 0.1], dtype=torch.float64)
    qd[:3] = 0.0  # a start at rest
    qdd = torch.randn(n, 2, generator=gen, dtype=torch.float64) * torch.tensor([10.0, 0.5], dtype=torch.float64)
    ds = Dataset(
        q=torch.arange(n, dtype=torch.float64)[:, None].expand(n, 2),  # the row, for the model below
        qd=qd,
        qdd=qdd,
        aux={},
        env_id=traj,
        traj_id=traj,
        t=torch.arange(n, dtype=torch.float64),
    )
    objective = make_objective("normalised_mse")
    objective.fit(ds)
    w = objective.sample_weights(ds)
    speed = qd.norm(dim=1)
    expected = torch.cat([speed[k * 20 : (k + 1) * 20] / speed[k * 20 : (k + 1) * 20].mean() for k in (0, 1)])
    expected = expected.clamp(min=0.1)
    torch.testing.assert_close(w, expected / expected.mean())
    assert torch.all(w[:3] == w.min())  # at rest: the floor
    pred = torch.randn(n, 2, generator=gen, dtype=torch.float64)
    scale = qdd.std(0)
    by_formula = (w[:, None] * ((pred - qdd) / scale) ** 2).mean()
    torch.testing.assert_close(objective(pred, qdd, w), by_formula)

    class Fixed(torch.nn.Module):
        def forward(self, q, qd_, aux):
            return pred[q[:, 0].long()]

    assert dataset_loss(Fixed(), ds, objective, chunk=7) == pytest.approx(float(by_formula), rel=1e-12)
    with pytest.raises(RuntimeError, match="call fit"):
        make_objective("normalised_mse")(pred, qdd)
    assert TrainConfig(objective="normalised_mse").batch_loss_objective == "mse"
