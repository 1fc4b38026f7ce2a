"""The premises of docs/math.md §12 read off a tree (``assembly/premises.py``), and the outcomes of rollouts from
rest told apart (``evaluate/convergence.py``): a tree planted with a spurious equilibrium is flagged by the first
and found at rest there by the second; the shipped recorded-demonstration trees are reported as they are."""

from __future__ import annotations

import pytest
import torch
from conftest import compose_cfg

from rmpfusion.assembly import build_tree
from rmpfusion.assembly.premises import check_premises
from rmpfusion.cli.validate import summary
from rmpfusion.evaluate.convergence import convergence_outcomes
from rmpfusion.pipeline.construct import build_all
from rmpfusion.pipeline.validate import resolve_and_validate

ATTRACTOR = {"type": "goal_attractor", "gain": 1.0, "alpha": 1.0, "eta": 2.0}


def plane_tree(**nodes) -> dict:
    """A tree on the plane: an attractor to the origin and a damper, and ``nodes`` besides."""
    return {
        "root": {"name": "x", "dim": 2},
        "nodes": {
            "goal": {"parent": "x", "map": {"type": "identity"}, "rmp": ATTRACTOR},
            "damper": {"parent": "x", "map": {"type": "identity"}, "rmp": {"type": "damper", "w": 1.0, "eta": 1.0}},
            **nodes,
        },
    }


#: a second attractor as strong as the goal's, to (1, 0): the two cancel at (0.5, 0), the only place motion stops
PLANTED = plane_tree(
    other={"parent": "x", "map": {"type": "offset", "origin": [1.0, 0.0]}, "rmp": ATTRACTOR},
)
SPURIOUS = torch.tensor([0.5, 0.0], dtype=torch.float64)


def roll_out(tree, q0: torch.Tensor, horizon: float, dt: float = 0.01) -> tuple[torch.Tensor, torch.Tensor]:
    """Semi-implicit Euler from rest: the records' times (T,) and configurations (T, B, 2)."""
    q, qd, qs = q0.clone(), torch.zeros_like(q0), [q0.clone()]
    for _ in range(round(horizon / dt)):
        qd = qd + dt * tree(q, qd).qdd
        q = q + dt * qd
        qs.append(q.clone())
    return torch.arange(len(qs), dtype=torch.float64) * dt, torch.stack(qs)


def test_a_tree_meeting_every_premise_is_reported_so():
    report = check_premises(build_tree(plane_tree()))
    assert report.holds and report.broken == [] and "the goal is the only equilibrium" in report.line()
    assert report.as_dict()["goal_only_equilibrium"]


def test_the_planted_equilibrium_is_flagged_and_found_at_rest_there():
    tree = build_tree(PLANTED)
    report = check_premises(tree)
    assert report.broken == [5]
    assert "premise 5 broken by the leaf 'goal_attractor' on node 'other' (another attractor)" in report.line()
    assert report.line().startswith("equilibria other than the goal are possible")
    starts = torch.tensor([[2.0, 1.0], [-1.0, -1.0], [0.5, 2.0], [3.0, -2.0]], dtype=torch.float64)
    times, q = roll_out(tree, starts, horizon=40.0)
    dist = q.norm(dim=-1)  # the goal is the origin
    o = convergence_outcomes(times, q[-1], dist, tolerance=1e-3)
    assert (o["converged"], o["at_rest_away"], o["still_moving"]) == (0, 4, 0)
    for where in o["at_rest_away_where"]:
        assert torch.allclose(torch.tensor(where["q"], dtype=torch.float64), SPURIOUS, atol=1e-4)
        assert where["distance"] == pytest.approx(0.5, abs=1e-4)
    early = convergence_outcomes(times[:101], q[100], dist[:101], tolerance=1e-3)  # 1 s: on the way there
    assert (early["converged"], early["at_rest_away"], early["still_moving"]) == (0, 0, 4)


def test_without_the_planted_leaf_every_start_converges_and_says_when():
    tree = build_tree(plane_tree())
    starts = torch.tensor([[2.0, 1.0], [-1.0, -1.0], [0.5, 2.0]], dtype=torch.float64)
    times, q = roll_out(tree, starts, horizon=40.0)
    o = convergence_outcomes(times, q[-1], q.norm(dim=-1), tolerance=1e-3)
    assert (o["converged"], o["at_rest_away"], o["still_moving"]) == (3, 0, 0)
    t = o["time_to_tolerance"]
    assert t["starts"] == 3 and 0 < t["median"] <= t["max"] < 40.0


def test_a_weight_that_reads_the_configuration_breaks_premise_3_and_a_radial_one_does_not():
    rbf = {"type": "rbf", "center": [1.0, 1.0], "radius": 0.5, "low": 0.1, "high": 2.0}
    spec = plane_tree()
    spec["nodes"]["goal"]["weight"] = rbf
    report = check_premises(build_tree(spec))
    assert report.broken == [3] and "the weight 'rbf' on edge 'goal', which reads the configuration" in report.line()
    for center, holds in (([0.0, 0.0], True), ([1.0, 0.0], False)):
        spec["nodes"]["goal"]["weight"] = {"type": "radial", "center": center}
        assert check_premises(build_tree(spec)).holds is holds, center
    spec["nodes"]["goal"]["weight"] = {"type": "mlp", "hidden": [4], "use_config": False, "aux": ["goal"]}
    spec["aux"] = {"goal": 2}
    assert check_premises(build_tree(spec)).holds  # aux state only


def test_maps_dampers_and_barriers_break_premises_1_4_and_5():
    spec = plane_tree()
    spec["nodes"]["goal"]["map"] = {"type": "linear", "matrix": [[1.0, 0.0]]}  # onto a line: not a diffeomorphism
    spec["nodes"]["damper"]["rmp"] = {"type": "damper", "w": 1.0, "eta": 0.0}
    spec["nodes"]["obstacle"] = {
        "parent": "x",
        "map": {"type": "sphere_distance", "center": [1.0, 1.0], "radius": 0.2},
        "rmp": {"type": "collision_avoidance"},
    }
    report = check_premises(build_tree(spec))
    assert report.broken == [1, 4, 5]
    assert "the map 'linear' of node 'goal'" in report.line()
    assert "the leaf 'collision_avoidance' on node 'obstacle' (a potential)" in report.line()


@pytest.mark.parametrize("kind", ["collision_avoidance", "joint_limit"])
def test_a_barrier_without_a_potential_gain_keeps_premise_5_and_one_with_any_does_not(kind):
    """Φ = ½·α·w(x)²: α fixed at 0 leaves a barrier of metric and damping only (premise 5 holds); a fixed α > 0,
    however small, or a learned α (whatever its current value: it lives in (0, ∞)) is a potential."""
    barrier = {"parent": "x", "map": {"type": "sphere_distance", "center": [1.0, 1.0], "radius": 0.2}}
    cases = [
        (0.0, True),
        (1e-12, False),
        ({"learn": True, "init": 1e-3}, False),
    ]
    for alpha, holds in cases:
        spec = plane_tree(obstacle={**barrier, "rmp": {"type": kind, "alpha": alpha}})
        tree = build_tree(spec)
        leaf = tree.rmps["obstacle"]
        assert leaf.potential_kind == ("none" if holds else "other"), alpha
        report = check_premises(tree)
        assert report.holds is holds, alpha
        if not holds:
            assert report.broken == [5] and f"the leaf '{kind}' on node 'obstacle' (a potential)" in report.line()


def test_the_arm_tree_with_metric_only_barriers_breaks_premise_5_only_by_its_second_attractor():
    """experiment=recorded_arm with every obstacle and joint-limit barrier's α at 0 (no shipped config's α is 0):
    premise 5 is left broken by its two attractors alone (the posture's, found first, and the end effector's)."""
    run = resolve_and_validate(
        compose_cfg(["experiment=recorded_arm", "tree.obstacle_rmp.alpha=0.0", "tree.joint_limit_rmp.alpha=0.0"])
    )
    _, expert, _ = build_all(run)
    five = check_premises(expert).premises[4]
    assert five.number == 5 and five.broken_by == ["the leaf 'goal_attractor' on node 'attractor' (another attractor)"]


#: the lasa study's both_radial variant: the attractor's weight a radial profile about the latent origin
RADIAL_LASA = [
    "lasa_variant=cloned",
    "~learners.rmp.weights",
    "+learners.rmp.weights={type: radial, center: [0.0, 0.0], reach: 3.0}",
]


@pytest.mark.parametrize(
    "overrides, tree_broken, learner_broken",
    [
        # the default: the learned flow, every weight 1, for the reference and the learner alike
        (["experiment=lasa"], [], []),
        # the cloned variant's attractor weight is an MLP of the latent position: premise 3 broken, and spurious
        # equilibria are possible
        (["experiment=lasa", "lasa_variant=cloned"], [], [3]),
        (["experiment=lasa", "lasa_variant=cloned", "learners.rmp.edges=[]"], [], []),  # its learned map alone
        (["experiment=lasa", *RADIAL_LASA], [], []),  # the lasa study's both_radial
        # an arm: forward kinematics onto the end effector, a posture attractor beside the end effector's, joint
        # limits and obstacle barriers
        (["experiment=recorded_arm"], [1, 5], [1, 3, 5]),
        (["experiment=recorded_arm", "attractor_weight=radial"], [1, 5], [1, 5]),
    ],
)
def test_the_shipped_recorded_trees_are_reported_as_they_are(overrides, tree_broken, learner_broken):
    run = resolve_and_validate(compose_cfg(overrides))
    env, expert, learners = build_all(run)
    assert check_premises(expert).broken == tree_broken
    assert check_premises(learners["rmp"].tree).broken == learner_broken
    text = summary(run, env, expert, learners)  # rmpfusion-validate prints both
    assert f"premises (rmp): {check_premises(learners['rmp'].tree).line()}" in text
    assert f"premises (tree): {check_premises(expert).line()}" in text
