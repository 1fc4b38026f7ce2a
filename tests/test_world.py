"""A world that changes at run time (scenes/world.py) through the Fig. 1b tree's obstacle sets: the Panda's tree built
once with sets of spheres and boxes, with the world's obstacles added, moved, resized and removed between calls,
equals at every call the tree generated for a scene holding exactly the obstacles present (values and parameter
gradients), and every change the world cannot make is one error naming what is allowed."""

from __future__ import annotations

import math

import pytest
import torch
import yaml

from rmpfusion import build_tree
from rmpfusion.assembly.generated import expand_tree
from rmpfusion.scenes import ObstacleSet, World, WorldError
from tests.conftest import CONF

SETS = [ObstacleSet(shape="sphere", n_max=3), ObstacleSet(shape="box", n_max=2)]


def declaration(scene: dict, sets: list[ObstacleSet]) -> dict:
    decl = yaml.safe_load((CONF / "tree" / "arm_reach.yaml").read_text())
    decl.pop("defaults", None)
    decl["robot"] = yaml.safe_load((CONF / "robot" / "panda.yaml").read_text())
    decl["scene"] = scene
    decl["obstacle_sets"] = [s.model_dump() for s in sets]
    decl["obstacle_weight"] = {"hidden": [8]}
    return decl


def scene_of(world: World) -> dict:
    """The scene (conf/scene/ form) holding exactly the world's present obstacles, in set order."""
    obstacles = []
    for oid in world.present():
        prefix, slot = world.where[oid]
        s = world.sets[prefix]
        t = {f: world.tensors[f"{prefix}_{f}"][0, slot].tolist() for f in s.fields()}
        if s.shape == "sphere":
            obstacles.append({"type": "sphere", "center": t["center"], "radius": t["radius"][0]})
        else:
            R = torch.tensor(t["rotation"]).reshape(3, 3)
            yaw = math.atan2(float(R[1, 0]), float(R[0, 0]))
            obstacles.append(
                {"type": "box", "center": t["center"], "half_extents": t["half_extents"], "rpy": [0.0, 0.0, yaw]}
            )
    return {"obstacles": obstacles, "ground": None}


def scene_aux(world: World) -> dict:
    """The fixed-obstacle tree's aux of the same obstacles (scenes/aux.py names), in the scene's order."""
    out = {"goal": world.goal}
    for k, oid in enumerate(world.present(), start=1):
        prefix, slot = world.where[oid]
        for f in world.sets[prefix].fields():
            out[f"obstacle{k}_{f}"] = world.tensors[f"{prefix}_{f}"][:, slot]
    return out


def yaw_rotation(yaw: float) -> list[float]:
    c, s = math.cos(yaw), math.sin(yaw)
    return [c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0]


@pytest.fixture(scope="module")
def tree_with_sets():
    torch.manual_seed(0)
    tree = build_tree(expand_tree(declaration({"obstacles": [], "ground": None}, SETS))).double()
    with torch.no_grad():  # weights away from their initial values, so every parameter matters
        for p in tree.parameters():
            p.add_(0.3 * torch.randn(p.shape, generator=torch.Generator().manual_seed(p.numel()), dtype=p.dtype))
    return tree


def changes():
    """A sequence of worlds: obstacles appear, move, grow, vanish, a second sphere appears in the freed member."""
    w = World(SETS, goal=[0.5, 0.2, 0.4])
    w.add("sphere", name="ball", center=[0.45, 0.0, 0.5], radius=0.08)
    yield w
    w.add("box", center=[0.3, -0.3, 0.3], half_extents=[0.05, 0.1, 0.2], rotation=yaw_rotation(0.4))
    yield w
    w.move("ball", center=[0.4, 0.15, 0.55])
    w.resize("boxes1", half_extents=[0.08, 0.1, 0.2])
    w.add("sphere", center=[0.2, 0.3, 0.6], radius=0.05)
    yield w
    w.remove("ball")
    w.set_goal([0.4, -0.3, 0.5])
    yield w


def test_the_world_equals_the_tree_of_its_present_obstacles_at_every_change(tree_with_sets):
    gen = torch.Generator().manual_seed(1)
    q = torch.tensor([[0.0, -0.3, 0.0, -2.2, 0.0, 2.0, 0.8]], dtype=torch.float64) + 0.2 * torch.randn(
        2, 7, generator=gen, dtype=torch.float64
    )
    qd = torch.randn(2, 7, generator=gen, dtype=torch.float64)
    for step, world in enumerate(changes()):
        world_b = World(SETS, batch=2)  # the same world for a batch of two states
        world_b.tensors = {k: v.expand(2, *v.shape[1:]).clone() for k, v in world.tensors.items()}
        world_b.where, world_b.goal = dict(world.where), world.goal.expand(2, 3).clone()
        fixed = build_tree(expand_tree(declaration(scene_of(world), []))).double()
        fixed.shared.load_state_dict(tree_with_sets.shared.state_dict())  # the shared obstacle weights
        fixed.weights["attractor"].load_state_dict(tree_with_sets.weights["attractor"].state_dict())
        a, b = tree_with_sets(q, qd, world_b.aux()), fixed(q, qd, scene_aux(world_b))
        for k in ("f", "M", "qdd", "V"):
            torch.testing.assert_close(
                getattr(a, k), getattr(b, k), rtol=1e-12, atol=1e-12, msg=f"{k} at change {step}"
            )
        for module in ("shared", "attractor"):  # gradients of f with respect to every weight parameter
            pa = list(
                (tree_with_sets.shared if module == "shared" else tree_with_sets.weights["attractor"]).parameters()
            )
            pb = list((fixed.shared if module == "shared" else fixed.weights["attractor"]).parameters())
            ga = torch.autograd.grad(a.f.sum(), pa, retain_graph=True, allow_unused=True)
            gb = torch.autograd.grad(b.f.sum(), pb, retain_graph=True, allow_unused=True)
            for x, y in zip(ga, gb):
                if y is None:
                    assert x is None or float(x.abs().max()) == 0.0
                else:
                    torch.testing.assert_close(x, y, rtol=1e-10, atol=1e-12, msg=f"d f / d {module} at change {step}")


def test_the_tree_declares_the_sets_and_their_weights_by_role(tree_with_sets):
    spec = expand_tree(declaration({"obstacles": [], "ground": None}, SETS))
    assert {"spheres1_present", "boxes2_rotation", "obstacle_center"} <= set(spec["aux"])
    assert spec["roles"]["obstacle"] == [f"cp{i}_obstacle" for i in range(1, 15)]
    assert spec["nodes"]["cp3_boxes2"]["weight"] == {
        "shared": "cp3_obstacle",
        "bind": {"obstacle_center": "boxes2_center", "obstacle_radius": "boxes2_radius"},
    }


def test_changes_the_world_cannot_make_are_clear_errors():
    w = World(SETS)
    for k in range(3):
        w.add("sphere", center=[0.1 * k, 0.0, 0.5], radius=0.05)
    cases = [
        (lambda: w.add("sphere", center=[0, 0, 0], radius=0.1), "set 'spheres' is full: all 3 members"),
        (lambda: w.add("capsule", center=[0, 0, 0], radius=0.1), "no obstacle set holds capsules"),
        (lambda: w.add("box", center=[0, 0, 0]), "adding a box needs half_extents"),
        (lambda: w.move("nothing", center=[0, 0, 0]), "no obstacle 'nothing' in the world; present: spheres1"),
        (lambda: w.move("spheres1", radius=0.2), "use resize('spheres1', ...)"),
        (lambda: w.resize("spheres1", center=[0, 0, 0]), "use move('spheres1', ...)"),
        (lambda: w.move("spheres1", center=[0, 0]), "spheres.center must be 3 finite number(s)"),
        (lambda: w.move("spheres1", axis=[0, 0, 1]), "a sphere in set 'spheres' has no field 'axis'"),
        (lambda: w.set_goal([0.0, float("nan"), 0.0]), "goal must be 3 finite number(s)"),
    ]
    for change, words in cases:
        with pytest.raises(WorldError, match=None) as err:
            change()
        assert words in str(err.value), (words, str(err.value))
    w.remove("spheres2")
    assert w.add("sphere", center=[0.0, 0.0, 0.9], radius=0.05) == "spheres2"  # the freed member is reused


@pytest.mark.slow
def test_one_compiled_controller_serves_a_world_that_changes_while_it_reaches():
    """tools/world_demo.py: the Panda's expert tree with obstacle sets, compiled once, reaches goals that move while
    obstacles appear in its way, move and vanish (8 changes in 6 s): nothing compiles after the first call, no
    control sphere touches an obstacle, V_r never rises between changes, and it ends at the last goal."""
    from tools.world_demo import run_demo

    r = run_demo(compiled=True, seconds=6.0, dt=0.002)
    assert r.changes == 8 and r.compiles_after_first_call == 0
    assert r.min_clearance > 0.0, r.trace
    assert r.vr_rises_between_changes == 0, r.trace
    assert r.final_goal_distance < 0.02, r.trace


def test_set_distances_measure_present_members_as_the_tree_does_and_absent_ones_at_infinity():
    """The clearance reported beside a world's rollouts: the registered maps of the sets' slots, checked against
    the distance to a sphere and to an axis-aligned box computed here; a removed member is infinitely far."""
    from rmpfusion.scenes.sets import set_distances

    sets = [ObstacleSet(shape="sphere", n_max=3), ObstacleSet(shape="box", n_max=2)]
    world = World(sets, goal=[0.5, 0.0, 0.4])
    ball = world.add("sphere", center=[0.5, 0.0, 0.5], radius=0.1)
    world.add("box", center=[0.0, 0.5, 0.5], half_extents=[0.1, 0.2, 0.1])
    pts = torch.tensor([[0.5, 0.0, 0.8], [0.0, 0.5, 0.8], [0.3, -0.2, 0.1]], dtype=torch.float64)
    d = set_distances(sets, world.set_aux(), pts)
    assert d.shape == (3, 5)
    sphere = (pts - torch.tensor([0.5, 0.0, 0.5], dtype=torch.float64)).norm(dim=-1) - 0.1
    outside = (
        (pts - torch.tensor([0.0, 0.5, 0.5], dtype=torch.float64)).abs()
        - torch.tensor([0.1, 0.2, 0.1], dtype=torch.float64)
    ).clamp(min=0)
    torch.testing.assert_close(d[:, 0], sphere)
    torch.testing.assert_close(d[:, 3], outside.norm(dim=-1))
    assert torch.isinf(d[:, [1, 2, 4]]).all()
    world.remove(ball)
    assert torch.isinf(set_distances(sets, world.set_aux(), pts)[:, 0]).all()
