"""Learnable leaf parameters: any ranged number of a leaf written ``{learn: true, init: x}`` is trained with the
learner, stays inside its field's range, flows into the place the constant would (one leaf or a stacked group of
them), and the tree stays a GDS tree (Theorem 2's identity at random states, for raw values far out).

Independent computations: the same tree with the number as a constant, the node-by-node reference evaluation
(tests/reference_tree.py), central differences in the number itself.
"""

from __future__ import annotations

import copy
import math

import pytest
import torch
from reference_tree import node_by_node

from rmpfusion.assembly.errors import ConfigError
from rmpfusion.assembly.tree import build_tree
from rmpfusion.core.learnable import LearnedFloat, Range, learned_values
from rmpfusion.envs import Particle2D, collect
from rmpfusion.evaluate.certificate import certify
from rmpfusion.learn import RMPLearner
from rmpfusion.learn.config import TrainConfig
from rmpfusion.learn.train import train
from rmpfusion.rmps import CollisionAvoidance, GoalAttractor

F64 = torch.float64


def _obstacle(k: int, **rmp) -> dict:
    return {
        "parent": "q",
        "map": {"type": "sphere_distance", "center": f"obstacle{k}_center", "radius": f"obstacle{k}_radius"},
        "rmp": {"type": "collision_avoidance", "r_w": 2.0, **rmp},
    }


def _tree(goal: dict | None = None, o1: dict | None = None, o2: dict | None = None) -> dict:
    return {
        "root": {"name": "q", "dim": 2},
        "nodes": {
            "goal": {
                "parent": "q",
                "map": {"type": "offset", "origin": "goal"},
                "rmp": {"type": "goal_attractor", **(goal or {})},
            },
            "obstacle1": _obstacle(1, **(o1 or {})),
            "obstacle2": _obstacle(2, **(o2 or {})),
            "metric": {"parent": "q", "rmp": {"type": "identity_metric", "scale": 0.01}},
        },
    }


def _learn(x: float, **bounds) -> dict:
    return {"learn": True, "init": x, **bounds}


@pytest.fixture(scope="module")
def states():
    env = Particle2D(n_obstacles=2)
    q, qd, aux = env.sample(3, 4, seed=2)
    return env, q, 2.0 * qd, aux


# ------------------------------------------------------------------------------------------ the config
def test_a_learnable_number_is_validated_by_its_field_and_written_back_as_declared():
    p = GoalAttractor.Params.model_validate({"gain": _learn(2.0), "eta": _learn(1.0, max=3.0)})
    assert isinstance(p.gain, LearnedFloat) and (p.gain, p.gain.lower, p.gain.upper) == (2.0, 0.0, None)
    assert (p.eta.lower, p.eta.upper) == (0.0, 3.0) and p.alpha == 1.0 and not isinstance(p.alpha, LearnedFloat)
    assert p.model_dump()["gain"] == {"learn": True, "init": 2.0}
    assert p.model_dump()["eta"] == {"learn": True, "init": 1.0, "max": 3.0}
    again = GoalAttractor.Params.model_validate(p.model_dump())
    assert again.learned().keys() == {"gain", "eta"} and again.eta.upper == 3.0
    assert GoalAttractor.Params.model_validate({"gain": {"learn": False, "init": 2.0}}).model_dump()["gain"] == 2.0


@pytest.mark.parametrize(
    "given, says",
    [
        ({"gain": _learn(-1.0)}, "Input should be greater than 0"),
        ({"eta": _learn(0.0)}, "eta: a learned value must start strictly inside its range (0.0, None)"),
        (
            {"eta": _learn(1.0, min=-1.0)},
            "eta: min=-1.0 lies outside the parameter's own range (0.0, None); min can only narrow it",
        ),
        ({"gain": _learn(5.0, max=4.0)}, "gain: a learned value must start strictly inside its range (0.0, 4.0)"),
        ({"gain": {"learn": True}}, "gain: init: Field required (a learnable number is written {learn: true, init: x}"),
        ({"gain": {"learn": True, "init": 1.0, "maxi": 2}}, "gain: maxi: Extra inputs are not permitted"),
    ],
)
def test_bad_learnable_numbers_are_refused_saying_why(given, says):
    with pytest.raises(ValueError, match=_escaped(says)):
        GoalAttractor.Params.model_validate(given)


def _escaped(text: str) -> str:
    import re

    return re.escape(text)


def test_a_bad_learnable_number_in_a_run_config_is_refused_at_its_leaf():
    from rmpfusion.pipeline.validate import resolve_and_validate

    cfg = {
        "env": {"type": "particle2d", "n_obstacles": 2},
        "tree": _tree(goal={"eta": _learn(0.0)}),
        "logger": {"mode": "disabled"},
        "train": {"iterations": 1, "snapshots": [1]},
    }
    with pytest.raises(ConfigError) as err:
        resolve_and_validate(cfg)
    assert [i.path for i in err.value.issues] == ["tree.nodes.goal.rmp"]
    assert "eta: a learned value must start strictly inside its range" in err.value.issues[0].message


# ------------------------------------------------------------------------------------------ the numbers
@pytest.mark.parametrize("lower, upper", [(0.0, None), (0.5, 4.0), (None, 3.0), (None, None)])
def test_the_parameterisation_never_leaves_its_range_and_starts_at_init(lower, upper):
    rng = Range(lower, upper)
    init = {(0.0, None): 0.3, (0.5, 4.0): 1.0, (None, 3.0): -2.0, (None, None): 0.7}[(lower, upper)]
    assert rng.value(torch.tensor(rng.raw(init), dtype=F64)).item() == pytest.approx(init, rel=1e-12)
    values = rng.value(torch.linspace(-40, 40, 801, dtype=F64))
    assert bool((values >= (lower if lower is not None else -math.inf)).all())
    assert bool((values <= (upper if upper is not None else math.inf)).all())


def test_a_learned_number_is_a_parameter_that_computes_what_the_constant_does(states):
    env, q, qd, aux = states
    learned = build_tree(
        _tree(goal={"gain": _learn(1.7), "eta": _learn(0.8)}, o1={"alpha": _learn(0.05)}), aux_dims=env.aux_dims()
    )
    const = build_tree(_tree(goal={"gain": 1.7, "eta": 0.8}, o1={"alpha": 0.05}), aux_dims=env.aux_dims())
    assert sorted(n for n, _ in learned.named_parameters()) == [
        "rmps.goal.eta_raw",
        "rmps.goal.gain_raw",
        "rmps.obstacle1.alpha_raw",
    ]
    a, b = learned(q, qd, aux), const(q, qd, aux)
    for k in ("qdd", "f", "M", "V"):
        assert torch.allclose(getattr(a, k), getattr(b, k), rtol=1e-12, atol=1e-12), k
    assert learned_values(learned.rmps["goal"]) == pytest.approx({"gain": 1.7, "eta": 0.8}, rel=1e-12)


def test_gradients_reach_each_member_of_a_stacked_group_as_central_differences_say(states):
    """Two obstacle leaves with learned alphas evaluate as one group (the tree plans them together); the
    gradient of V_r in each one's raw parameter is the central difference of the constant tree in that number,
    times dα/draw, and the whole answer equals the node-by-node reference."""
    env, q, qd, aux = states
    away = (q - aux["obstacle1_center"]) / (q - aux["obstacle1_center"]).norm(dim=-1, keepdim=True)
    q = aux["obstacle1_center"] + (aux["obstacle1_radius"] + 0.3) * away  # 0.3 from obstacle 1: its barrier acts
    spec = _tree(o1={"alpha": _learn(0.3)}, o2={"alpha": _learn(0.2)})
    tree = build_tree(spec, aux_dims=env.aux_dims())
    assert any(g.nodes == ["obstacle1", "obstacle2"] for g in tree.plan.groups)  # one stacked group
    out = tree(q, qd, aux)
    ref = node_by_node(tree, q, qd, aux)
    assert torch.allclose(out.qdd, ref["qdd"], rtol=1e-10, atol=1e-10)
    out.V.sum().backward()
    for name, alpha in (("obstacle1", 0.3), ("obstacle2", 0.2)):
        raw = tree.rmps[name].alpha_raw
        eps = 1e-6
        vals = []
        for a in (alpha + eps, alpha - eps):
            s = _tree(o1={"alpha": a if name == "obstacle1" else 0.3}, o2={"alpha": a if name == "obstacle2" else 0.2})
            vals.append(build_tree(s, aux_dims=env.aux_dims())(q, qd, aux).V.sum())
        dV_dalpha = (vals[0] - vals[1]) / (2 * eps)
        dalpha_draw = alpha  # alpha = 0 + exp(raw)
        assert raw.grad is not None and float(raw.grad) == pytest.approx(float(dV_dalpha) * dalpha_draw, rel=1e-6)
        assert abs(float(raw.grad)) > 1e-6  # the barrier acts: the check is not of two zeros


def test_a_learned_and_a_constant_member_never_share_a_group(states):
    env, q, qd, aux = states
    tree = build_tree(_tree(o1={"alpha": _learn(0.3)}, o2={"alpha": 0.2}), aux_dims=env.aux_dims())
    assert tree.rmps["obstacle1"].stack_key() != tree.rmps["obstacle2"].stack_key()
    assert not any(g.nodes == ["obstacle1", "obstacle2"] for g in tree.plan.groups)
    ref = node_by_node(tree, q, qd, aux)
    assert torch.allclose(tree(q, qd, aux).qdd, ref["qdd"], rtol=1e-10, atol=1e-10)


@pytest.mark.parametrize("raw", [-6.0, 0.0, 4.0])
def test_the_tree_stays_a_gds_tree_wherever_its_learned_numbers_go(states, raw):
    """Theorem 2's premises and identity (the certificate) at random states with every learned number's raw
    parameter pushed far out (e^4 = 55 times, e^-6 = 1/400 of the range's scale, sigmoids within 2 % of a bound):
    the parameterisation keeps each inside the range where its leaf is a GDS."""
    env, q, qd, aux = states
    tree = build_tree(
        _tree(
            goal={"gain": _learn(1.0), "eta": _learn(1.0, max=5.0), "sigma": _learn(1.0)},
            o1={"alpha": _learn(0.1), "epsilon": _learn(0.2)},
            o2={"eta": _learn(0.5)},
        ),
        aux_dims=env.aux_dims(),
    )
    with torch.no_grad():
        for p in tree.parameters():
            p.fill_(raw)
    cert = certify(tree, q, qd, aux)
    assert cert.ok, cert.summary()


# ------------------------------------------------------------------------------------------ learning them
def test_behavior_cloning_learns_a_learner_s_own_leaf_numbers_and_reports_them():
    """The expert's goal gain is 1 and damping 2; a learner that starts at 0.3 and 0.5 with the expert's weights
    as constants has nothing else to learn: behavior cloning brings both to the expert's."""
    env = Particle2D(n_obstacles=2, dt=0.05)
    expert_spec = _tree(goal={"gain": 1.0, "eta": 2.0})
    expert = build_tree(expert_spec, aux_dims=env.aux_dims())
    data = collect(env, expert, 2, 3, 6, 0.5, torch.Generator().manual_seed(0))
    learner = RMPLearner(
        RMPLearner.Params(
            weights={"type": "constant", "value": 1.0},
            edges=["goal"],
            leaves={"goal": {"gain": _learn(0.3), "eta": _learn(0.5)}},
        ),
        expert_spec,
        env.aux_dims(),
        2,
    )
    assert learner.describe() == {"learned_leaf_parameters": pytest.approx({"goal.gain": 0.3, "goal.eta": 0.5})}
    assert learner.num_parameters() == 2
    train(
        learner,
        data,
        TrainConfig(optimizer="adam", lr=0.05, iterations=300, batch_size=32, snapshots=[300], log_every=300),
        seed=0,
    )
    got = learner.learned_numbers()
    assert got == pytest.approx({"goal.gain": 1.0, "goal.eta": 2.0}, rel=1e-3), got


def test_a_learner_leaf_that_is_no_leaf_is_refused():
    with pytest.raises(ConfigError) as err:
        RMPLearner(
            RMPLearner.Params(leaves={"obstacle": {"gain": _learn(1.0)}}),
            _tree(),
            Particle2D(n_obstacles=2).aux_dims(),
            2,
            where="learners.rmp",
        )
    assert err.value.issues[0].path == "learners.rmp.leaves.obstacle"
    assert "'obstacle' is not a leaf of the tree; leaves: goal, obstacle1, obstacle2, metric" in str(err.value)


def test_a_deep_copy_or_a_state_dict_carries_the_learned_numbers(states):
    env, q, qd, aux = states
    tree = build_tree(_tree(goal={"gain": _learn(1.3)}), aux_dims=env.aux_dims())
    with torch.no_grad():
        tree.rmps["goal"].gain_raw += 0.5
    copied = copy.deepcopy(tree)
    fresh = build_tree(_tree(goal={"gain": _learn(1.3)}), aux_dims=env.aux_dims())
    fresh.load_state_dict(tree.state_dict())
    expected = 1.3 * math.exp(0.5)
    for t in (copied, fresh):
        assert learned_values(t.rmps["goal"])["gain"] == pytest.approx(expected, rel=1e-12)
        assert torch.allclose(t(q, qd, aux).qdd, tree(q, qd, aux).qdd, rtol=0, atol=0)
    assert isinstance(CollisionAvoidance.Params().r_w, float)
