"""A tree holding obstacle sets exported once (learn/export.py::export_with_sets) serves any obstacles present: the
loaded program, called with the set tensors and masks a World holds, equals the eager tree for every mask, and a
saved file does the same with rmpfusion's code out of the loop."""

from __future__ import annotations

import torch

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
