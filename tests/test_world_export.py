"""A tree holding obstacle sets exported once (learn/export.py::export_with_sets) serves any obstacles present: the
loaded program, called with the set tensors and masks a World holds, equals the eager tree for every mask, and a
saved file does the same with rmpfusion's code out of the loop."""

from __future__ import annotations

import torch
from conftest import ROOT

from rmpfusion import build_tree
from rmpfusion.learn.export import export_with_sets
from rmpfusion.scenes import ObstacleSet, World
from tests.test_obstacle_sets import tree_spec


def test_one_export_serves_every_mask(tmp_path):
    s = ObstacleSet(shape="sphere", n_max=3)
    torch.manual_seed(0)
    tree = build_tree(tree_spec(s, [1, 2, 3], masked=True)).double()
    world = World([s], batch=1)  # a controller's one state
    gen = torch.Generator().manual_seed(1)
    q = 2 * torch.rand(1, 3, generator=gen, dtype=torch.float64) - 1
    qd = torch.randn(1, 3, generator=gen, dtype=torch.float64)
    world.add("sphere", center=[0.3, 0.2, -0.1], radius=0.2)
    inputs = {k: v for k, v in world.set_aux().items() if k != "goal"}  # this tree's goal is a constant
    exported = export_with_sets(tree, [s], q, qd, inputs)
    path = tmp_path / "policy.pt2"
    torch.export.save(exported, path)
    loaded = torch.export.load(path).module()
    for change in (
        lambda: None,
        lambda: world.add("sphere", center=[-0.4, 0.1, 0.2], radius=0.15),
        lambda: world.remove("spheres1"),
        lambda: world.remove("spheres2"),
        lambda: [world.add("sphere", center=[0.1 * k, -0.3, 0.0], radius=0.1) for k in range(3)],
    ):
        change()
        aux = world.set_aux()
        args = [aux[n] for n in inputs]
        with torch.no_grad():
            expected = tree(q, qd, world.aux()).qdd
            torch.testing.assert_close(exported.module()(q, qd, *args), expected, rtol=1e-12, atol=1e-12)
            torch.testing.assert_close(loaded(q, qd, *args), expected, rtol=1e-12, atol=1e-12)
    assert len(world.present()) == 3


def _panda_spec(scene: dict) -> dict:
    import yaml

    from rmpfusion.assembly.generated import expand_tree

    decl = yaml.safe_load((ROOT / "conf/tree/arm_reach.yaml").read_text())
    decl.pop("defaults", None)
    decl.update(robot=yaml.safe_load((ROOT / "conf/robot/panda.yaml").read_text()), scene=scene)
    return expand_tree(decl)


def test_a_trees_fixed_obstacles_give_way_to_sets_with_the_same_weights():
    """``with_obstacle_sets``: the Panda's Fig. 1b tree of one fixed sphere, its obstacle edges replaced by a sphere
    set and a box set, takes the original's weights by name (the shared weights keep their names) and, with
    the same sphere as the set's only member present, equals the original (f, M, q̈, V to 1e-12); the fixed obstacle's
    aux is no longer read."""
    from rmpfusion.envs.manipulator_tree import copy_weights, with_obstacle_sets
    from rmpfusion.scenes import with_slots

    sphere = {"type": "sphere", "center": [0.5, 0.1, 0.45], "radius": 0.07}
    spec = _panda_spec({"obstacles": [sphere]})
    sets = [ObstacleSet(shape="sphere", n_max=3), ObstacleSet(shape="box", n_max=2)]
    torch.manual_seed(0)
    fixed = build_tree(spec).double()
    with torch.no_grad():
        for p in fixed.parameters():  # trained: away from the initialisation
            p.add_(0.2 * torch.randn_like(p))
    moved = build_tree(with_obstacle_sets(spec, sets)).double()
    copied = copy_weights(fixed, moved)  # by name: the shared obstacle weights and the attractor's
    assert {f"cp{i}_obstacle" for i in range(1, 15)} | {"attractor"} <= set(copied)
    count = lambda t: sum(p.numel() for p in t.parameters())
    assert count(moved) == count(fixed)  # the sets' edges add no parameter: they share the weights
    assert not any(k.startswith("obstacle1_") for k in moved.aux_dims)
    world = World(sets, goal=[0.45, -0.2, 0.4])
    world.add("sphere", center=sphere["center"], radius=sphere["radius"])
    q = torch.tensor([[0.3, -0.4, 0.1, -2.0, 0.2, 1.9, 0.7]], dtype=torch.float64)
    qd = torch.full_like(q, 0.2)
    aux_fixed = {
        "goal": torch.tensor([[0.45, -0.2, 0.4]], dtype=torch.float64),
        "obstacle1_center": torch.tensor([sphere["center"]], dtype=torch.float64),
        "obstacle1_radius": torch.tensor([[sphere["radius"]]], dtype=torch.float64),
    }
    with torch.no_grad():
        a, b = fixed(q, qd, aux_fixed), moved(q, qd, with_slots(sets, world.set_aux()))
    for x, y in ((a.f, b.f), (a.M, b.M), (a.qdd, b.qdd), (a.V, b.V)):
        torch.testing.assert_close(y, x, rtol=1e-12, atol=1e-12)
    world.add("box", center=[0.55, -0.1, 0.4], half_extents=[0.05, 0.05, 0.1])
    with torch.no_grad():
        assert (moved(q, qd, world.aux()).qdd - a.qdd).abs().max() > 1e-6  # a second obstacle counts
