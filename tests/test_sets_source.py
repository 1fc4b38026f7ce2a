"""A tree that makes its obstacle sets' slot entries itself (``RMPTree.read_aux_through`` with a ``SetsSource``): the
caller passes each set's tensors and mask, and the tree equals the same tree given every slot entry, in values and
gradients; its inputs are checked; compiled, it serves every mask without compiling again."""

from __future__ import annotations

import pytest
import torch
from test_obstacle_sets import MASKS, N_MAX, OUTPUTS, gradients, inputs, moving, scalar, tree_spec

from rmpfusion import build_tree
from rmpfusion.scenes import SET_SHAPES, ObstacleSet, SetsSource, with_slots


def _pair(s: ObstacleSet):
    """The tree of ``s``'s every slot twice, with the same parameters: given the slot entries, and making them."""
    slots = list(range(1, s.n_max + 1))
    given = build_tree(tree_spec(s, slots, masked=True))
    with torch.no_grad():  # learned numbers away from their initial values, so every parameter matters
        for p in given.parameters():
            p.add_(0.3 * torch.randn(p.shape, generator=torch.Generator().manual_seed(p.numel()), dtype=p.dtype))
    making = build_tree(tree_spec(s, slots, masked=True))
    making.load_state_dict(given.state_dict())
    return given, making.read_aux_through(SetsSource([s], n_points=2))


@pytest.mark.parametrize("shape", SET_SHAPES)
def test_a_tree_given_the_set_tensors_equals_the_tree_given_every_slot(shape):
    s = moving(shape)
    given, making = _pair(s)
    q, qd, raw = inputs(s, B=4, seed=3)
    raw[f"{s.prefix}_mask"] = torch.tensor([MASKS[k % len(MASKS)] for k in range(4)], dtype=torch.float64)
    a, b = making(q, qd, raw), given(q, qd, with_slots([s], raw))
    for k in OUTPUTS:
        torch.testing.assert_close(getattr(a, k), getattr(b, k), rtol=0, atol=0, msg=k)
    ga, gb = gradients(making, a), gradients(given, b)
    assert ga.keys() == gb.keys() and ga
    for name in ga:
        if gb[name] is None:
            assert ga[name] is None, name
        else:
            torch.testing.assert_close(ga[name], gb[name], rtol=0, atol=0, msg=name)
    assert scalar(a).isfinite()


def test_the_set_tensors_a_tree_makes_its_entries_from_are_checked():
    s = ObstacleSet(shape="sphere", n_max=N_MAX)
    _, making = _pair(s)
    q, qd, raw = inputs(s, B=2, seed=1)
    raw["spheres_mask"] = torch.ones(2, N_MAX, dtype=torch.float64)
    with pytest.raises(KeyError, match=r"aux 'spheres_radius' of shape \(B, 4, 1\) is required"):
        making(q, qd, {k: v for k, v in raw.items() if k != "spheres_radius"})
    with pytest.raises(ValueError, match=r"aux 'spheres_center' must be \(2 or 1, 4, 3\); got \(2, 5, 3\)"):
        making(q, qd, {**raw, "spheres_center": torch.zeros(2, 5, 3, dtype=torch.float64)})
    one_row = {k: v[:1] for k, v in raw.items()}  # one row for every state: broadcast
    torch.testing.assert_close(
        making(q, qd, one_row).qdd, making(q, qd, {k: v[:1].expand_as(v) for k, v in raw.items()}).qdd
    )


def test_a_nearest_source_needs_the_control_points():
    with pytest.raises(ValueError, match="pass centres="):
        SetsSource([ObstacleSet(shape="sphere", n_max=8, nearest=2)], n_points=3)


@pytest.mark.slow
def test_a_compiled_tree_making_its_entries_serves_every_mask_without_recompiling():
    """The compiled tree takes the set's tensors (3 inputs, not one per member): once warm, no change of mask
    compiles anything, and each call equals the eager tree given every slot entry."""
    from torch._dynamo.utils import counters

    s = ObstacleSet(shape="sphere", n_max=N_MAX)
    given, making = _pair(s)
    making.compile()
    q, qd, raw = inputs(s, B=3, seed=2)
    torch._dynamo.reset()
    counters.clear()
    graphs = []
    for mask in [MASKS[0], *MASKS]:
        raw[f"{s.prefix}_mask"] = torch.tensor(mask, dtype=torch.float64).expand(3, N_MAX)
        with torch.no_grad():
            a, b = making(q, qd, raw), given(q, qd, with_slots([s], raw))
        graphs.append(counters["stats"]["unique_graphs"])
        torch.testing.assert_close(a.qdd, b.qdd, rtol=1e-10, atol=1e-10)
    assert graphs[1] >= 1 and graphs[-1] == graphs[1], f"graphs compiled after each call: {graphs}"
