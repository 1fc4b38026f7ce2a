"""Obstacle sets as batched, masked aux (scenes/sets.py, the ``present`` mask of maps/shapes.py): a tree built once
with N_max members of a set, k of them present, equals a tree built with only those k obstacles (values and
gradients w.r.t. every learnable parameter, to 1e-12), for every shape and several masks (none and all present among
them); nothing absent, nor a control point inside an obstacle, ever produces NaN; V_r is non-increasing on a rollout
with the mask fixed."""

import pytest
import torch

from rmpfusion import build_tree
from rmpfusion.maps.shapes import ABSENT_DISTANCE
from rmpfusion.scenes.sets import SET_SHAPES, ObstacleSet, every_shape, set_dims, with_slots
from tests.conftest import assert_lyapunov_non_increasing, rk4_rollout

N_MAX = 4
MASKS = [(0, 0, 0, 0), (1, 0, 0, 0), (0, 1, 1, 0), (1, 0, 1, 1), (1, 1, 1, 1)]
CONTROL_POINTS = {
    "cp1": {"type": "identity"},
    "cp2": {
        "type": "linear",
        "matrix": [[0.8, 0.3, 0.0], [-0.2, 1.1, 0.1], [0.1, 0.0, 0.9]],
        "bias": [0.1, -0.2, 0.05],
    },
}
OUTPUTS = ("qdd", "f", "M", "G", "B", "Phi", "V", "L")


def obstacle_weight():
    return {
        "type": "mlp",
        "hidden": [8],
        "activation": "tanh",
        "positivity": "exp",
        "aux": ["obstacle_center", "obstacle_radius"],
    }


def tree_spec(s: ObstacleSet, slots: list[int], masked: bool) -> dict:
    """A 3-D point (cp1) and an affine image of it (cp2) avoiding set ``s``'s members ``slots`` with a learned barrier
    under a learned weight shared by each control point's obstacle edges; masked: through the set's masked maps."""
    aux = {"obstacle_center": 3, "obstacle_radius": 1}
    nodes = {
        "goal": {
            "parent": "q",
            "map": {"type": "offset", "origin": [0.6, -0.4, 0.3]},
            "rmp": {"type": "goal_attractor", "gain": 2.0, "eta": 2.0},
        },
        "damp": {"parent": "q", "map": {"type": "identity"}, "rmp": {"type": "damper", "w": 0.2, "eta": 1.0}},
    }
    shared = {}
    for cp, m in CONTROL_POINTS.items() if slots else ():
        nodes[cp] = {"parent": "q", "map": m}
        shared[f"{cp}_obstacle"] = obstacle_weight()
        for i in slots:
            spec = s.slot_map(i)
            if not masked:
                spec.pop("present")
            nodes[f"{cp}_{s.prefix}{i}"] = {
                "parent": cp,
                "map": spec,
                "weight": {"shared": f"{cp}_obstacle", "bind": s.weight_bind(i)},
                "rmp": {
                    "type": "collision_avoidance",
                    "r_w": {"learn": True, "init": 0.8 + 0.1 * i},
                    "alpha": 0.05,
                    "eta": 0.5,
                },
            }
    dims = set_dims([s]) if masked else {s.slot_name(i, f): k for i in slots for f, k in s.fields().items()}
    return {"root": {"name": "q", "dim": 3}, "aux": {**aux, **dims}, "shared_weights": shared, "nodes": nodes}


def random_rotation(gen, B, N):
    A = torch.randn(B, N, 3, 3, generator=gen, dtype=torch.float64)
    Q, R = torch.linalg.qr(A)
    Q = Q * torch.sign(torch.diagonal(R, dim1=-2, dim2=-1)).unsqueeze(-2)
    return Q * torch.linalg.det(Q)[..., None, None]  # det +1


def set_tensors(s: ObstacleSet, B: int, gen) -> dict[str, torch.Tensor]:
    """Random members of set ``s`` (B, N_max, k) around the origin."""
    rnd = lambda *shape: torch.rand(*shape, generator=gen, dtype=torch.float64)
    unit = lambda: torch.nn.functional.normalize(torch.randn(B, s.n_max, 3, generator=gen, dtype=torch.float64), dim=-1)
    values = {
        "center": 2 * rnd(B, s.n_max, 3) - 1,
        "radius": 0.1 + 0.2 * rnd(B, s.n_max, 1),
        "half_extents": 0.1 + 0.2 * rnd(B, s.n_max, 3),
        "rotation": random_rotation(gen, B, s.n_max).flatten(-2),
        "axis": unit(),
        "normal": unit(),
        "half_height": 0.1 + 0.3 * rnd(B, s.n_max, 1),
        "half_length": 0.1 + 0.3 * rnd(B, s.n_max, 1),
        "velocity": 0.5 * torch.randn(B, s.n_max, 3, generator=gen, dtype=torch.float64),
    }
    if s.shape == "plane":  # every point of [-1, 1]³ above the planes (points inside obstacles: tested below)
        values["center"] = -(1.8 + 0.4 * rnd(B, s.n_max, 1)) * values["normal"]
    return {f"{s.prefix}_{f}": values[f] for f in s.fields()}


def inputs(s: ObstacleSet, B: int, seed: int):
    gen = torch.Generator().manual_seed(seed)
    q = (
        2 * torch.rand(B, 3, generator=gen, dtype=torch.float64) - 1
    )  # among the obstacles, inside their barriers' support
    qd = torch.randn(B, 3, generator=gen, dtype=torch.float64)
    return q, qd, set_tensors(s, B, gen)


def slot_aux(s: ObstacleSet, raw: dict, slots: list[int]) -> dict:
    """The aux of a tree built with only ``slots``, read straight from the set tensors (no masking involved)."""
    return {s.slot_name(i, f): raw[f"{s.prefix}_{f}"][:, i - 1] for i in slots for f in s.fields()}


def set_pair(s: ObstacleSet, mask):
    """The masked tree over every slot and the tree of the present slots only, with the same parameters."""
    present = [i + 1 for i, m in enumerate(mask) if m]
    full = build_tree(tree_spec(s, list(range(1, s.n_max + 1)), masked=True))
    with torch.no_grad():  # learned numbers away from their initial values, so every parameter matters
        for p in full.parameters():
            p.add_(0.3 * torch.randn(p.shape, generator=torch.Generator().manual_seed(p.numel()), dtype=p.dtype))
    few = build_tree(tree_spec(s, present, masked=False))
    missing, _ = few.load_state_dict(full.state_dict(), strict=False)
    assert not missing
    return full, few, present


def scalar(out, gen_seed=7, outputs=OUTPUTS[1:]):
    """A random linear functional of the root's RMP (f, M, G, B, Φ, V, L), so one backward pass tests the gradients of
    all of them (q̈'s are M⁻¹'s linear algebra on them: equal as far as M's conditioning allows)."""
    g = torch.Generator().manual_seed(gen_seed)
    return sum(
        (getattr(out, k) * torch.randn(getattr(out, k).shape, generator=g, dtype=torch.float64)).sum() for k in outputs
    )


def assert_same_outputs(a, b, rows=slice(None)):
    """Every output of ``a`` (rows ``rows``) equals ``b``'s; q̈ as the solution of ``b``'s M q̈ = f to working
    precision (a point deep inside an obstacle makes M ill-conditioned, and q̈ then carries M's rounding times its
    condition number)."""
    for k in OUTPUTS[1:]:
        assert_equal(getattr(a, k)[rows], getattr(b, k), k)
    qdd = a.qdd[rows].detach()
    residual = (b.M.detach() @ qdd.unsqueeze(-1)).squeeze(-1) - b.f.detach()
    scale = b.M.detach().abs().amax(dim=(-2, -1)) * qdd.abs().amax(-1) + b.f.detach().abs().amax(-1)
    assert (residual.abs().amax(-1) <= 1e-12 * scale).all(), "qdd"


def assert_equal(a, b, what):
    """Equal to 1e-12 of the larger of 1 and the quantity's largest entry (a point deep inside an obstacle makes
    barrier terms of 1e11, whose sums in another order differ in their last bits)."""
    scale = max(1.0, float(b.detach().abs().max())) if b.numel() else 1.0
    torch.testing.assert_close(a, b, rtol=0, atol=1e-12 * scale, msg=what)


def gradients(tree, out) -> dict:
    """Parameter name -> gradient of ``scalar(out)`` (None where nothing reaches it); a shared weight's parameters
    under their name in ``shared`` (every edge using it holds them too)."""
    names = {}
    for name, p in tree.named_parameters(remove_duplicate=False):
        if id(p) not in names or names[id(p)].startswith("weights."):
            names[id(p)] = name
    params = list(tree.parameters())
    if not params:
        return {}
    return dict(zip([names[id(p)] for p in params], torch.autograd.grad(scalar(out), params, allow_unused=True)))


def moving(shape):
    return ObstacleSet(shape=shape, n_max=N_MAX, moving=shape in ("sphere", "plane"))


@pytest.mark.parametrize("shape", SET_SHAPES)
@pytest.mark.parametrize("mask", MASKS, ids=lambda m: "".join(map(str, m)))
def test_k_present_equals_the_tree_of_those_k(shape, mask):
    s = moving(shape)
    full, few, present = set_pair(s, mask)
    q, qd, raw = inputs(s, B=8, seed=10 * SET_SHAPES.index(shape) + MASKS.index(mask))
    raw[f"{s.prefix}_mask"] = torch.tensor(mask, dtype=torch.float64).expand(8, N_MAX)
    a, b = full(q, qd, with_slots([s], raw)), few(q, qd, slot_aux(s, raw, present))
    assert_same_outputs(a, b)
    ga, gb = gradients(full, a), gradients(few, b)
    for name, g in ga.items():
        if name in gb and gb[name] is not None:
            assert_equal(g, gb[name], name)
        else:  # an absent member's own parameters (its barrier's r_w): nothing reaches them
            assert g is None or bool((g == 0).all()), name
    assert any(g is not None and bool((g != 0).any()) for g in ga.values()) or not present


@pytest.mark.parametrize("shape", SET_SHAPES)
def test_per_sample_masks_equal_each_sample_alone(shape):
    """One batch whose samples have different members present: each row equals the tree of its own members."""
    s = moving(shape)
    q, qd, raw = inputs(s, B=len(MASKS), seed=11)
    raw[f"{s.prefix}_mask"] = torch.tensor(MASKS, dtype=torch.bool)
    full = build_tree(tree_spec(s, list(range(1, N_MAX + 1)), masked=True))
    a = full(q, qd, with_slots([s], raw))
    for row, mask in enumerate(MASKS):
        present = [i + 1 for i, m in enumerate(mask) if m]
        few = build_tree(tree_spec(s, present, masked=False))
        few.load_state_dict(full.state_dict(), strict=False)
        one = {k: v[row : row + 1] for k, v in slot_aux(s, raw, present).items()}
        b = few(q[row : row + 1], qd[row : row + 1], one)
        assert_same_outputs(a, b, slice(row, row + 1))


@pytest.mark.parametrize("shape", SET_SHAPES)
def test_absent_members_hold_nan_and_nothing_is_nan(shape):
    """Whatever an absent member's fields hold (NaN here) reaches no value and no gradient: not of the parameters,
    not of the state, not of the set tensors."""
    s = moving(shape)
    q, qd, raw = inputs(s, B=4, seed=3)
    mask = torch.tensor([[1, 0, 1, 0]] * 4, dtype=torch.float64)
    for k, t in raw.items():
        raw[k] = torch.where(mask.bool()[..., None], t, torch.full_like(t, float("nan"))).requires_grad_(True)
    raw[f"{s.prefix}_mask"] = mask
    q.requires_grad_(True)
    full = build_tree(tree_spec(s, list(range(1, N_MAX + 1)), masked=True))
    out = full(q, qd, with_slots([s], raw))
    for k in OUTPUTS:
        assert torch.isfinite(getattr(out, k)).all(), k
    leaves = [q, *(raw[k] for k in raw if k != f"{s.prefix}_mask"), *full.parameters()]
    grads = torch.autograd.grad(scalar(out, outputs=OUTPUTS), leaves, allow_unused=True)
    assert all(g is None or torch.isfinite(g).all() for g in grads)
    for k, g in zip([k for k in raw if k != f"{s.prefix}_mask"], grads[1:]):
        assert g is None or bool((g[:, [1, 3]] == 0).all()), k


@pytest.mark.parametrize("shape", SET_SHAPES)
def test_an_obstacle_appearing_inside_the_arm_is_never_nan(shape):
    """Every member present and centred on a control point (where a sphere's distance has no direction: that member is
    ignored for the sample) or around it (the barrier's finite continuation inside pushes out)."""
    s = ObstacleSet(shape=shape, n_max=2)
    q, qd, raw = inputs(s, B=3, seed=5)
    raw[f"{s.prefix}_center"][:, 0] = q  # on cp1 exactly
    raw[f"{s.prefix}_center"][:, 1] = q + 0.01  # cp1 just off its centre, deep inside
    raw[f"{s.prefix}_mask"] = torch.ones(3, 2, dtype=torch.float64)
    q.requires_grad_(True)
    full = build_tree(tree_spec(s, [1, 2], masked=True))
    out = full(q, qd, with_slots([s], raw), return_nodes=True)
    for k in OUTPUTS:
        assert torch.isfinite(getattr(out, k)).all(), k
    grads = torch.autograd.grad(scalar(out, outputs=OUTPUTS), [q, *full.parameters()], allow_unused=True)
    assert all(g is None or torch.isfinite(g).all() for g in grads)
    y_on, y_off = out.nodes["state"][f"cp1_{s.prefix}1"][0], out.nodes["state"][f"cp1_{s.prefix}2"][0]
    if shape in ("sphere", "capsule", "cylinder"):  # on the centre or the axis: no direction, ignored
        assert (y_on == ABSENT_DISTANCE).all()
    assert (y_off < 0).all() or shape == "plane"  # inside: measured, pushed out by the barrier
    assert (y_off < ABSENT_DISTANCE).all()


@pytest.mark.parametrize("shape", ["sphere", "box", "plane"])
def test_lyapunov_non_increasing_with_the_mask_fixed(shape):
    """Theorem 2 on an RK4 rollout of the masked tree (static members, two of four present)."""
    s = ObstacleSet(shape=shape, n_max=N_MAX)
    q, qd, raw = inputs(s, B=4, seed=21)
    if shape == "plane":  # planes below the points, so the start is outside them
        raw["planes_normal"] = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64).expand(4, N_MAX, 3).clone()
        raw["planes_center"][..., 2] = -4.0
    raw[f"{s.prefix}_mask"] = torch.tensor([[1, 0, 1, 0]] * 4, dtype=torch.float64)
    full = build_tree(tree_spec(s, list(range(1, N_MAX + 1)), masked=True))
    rec = rk4_rollout(full, q, qd, with_slots([s], raw), dt=2e-3, steps=300)
    assert_lyapunov_non_increasing(rec)


def test_every_shape_allocated_up_front_runs_with_none_present():
    """A tree holding a set of every shape a controller may meet, nothing present, is the tree without obstacles."""
    sets = every_shape(n_max=2)
    assert [s.shape for s in sets] == list(SET_SHAPES)
    q, qd, _raw = inputs(ObstacleSet(shape="sphere", n_max=2), B=3, seed=9)
    gen = torch.Generator().manual_seed(4)
    aux, nodes, shared = (
        {"obstacle_center": 3, "obstacle_radius": 1, **set_dims(sets)},
        {},
        {"cp_obstacle": obstacle_weight()},
    )
    base = tree_spec(sets[0], [], masked=False)
    nodes = {**base["nodes"], "cp": {"parent": "q", "map": {"type": "identity"}}}
    tensors = {}
    for s in sets:
        tensors.update(set_tensors(s, 3, gen))
        tensors[f"{s.prefix}_mask"] = torch.zeros(3, 2)
        for i in (1, 2):
            nodes[f"cp_{s.prefix}{i}"] = {
                "parent": "cp",
                "map": s.slot_map(i),
                "weight": {"shared": "cp_obstacle", "bind": s.weight_bind(i)},
                "rmp": {"type": "collision_avoidance", "r_w": 0.8},
            }
    tree = build_tree({"root": {"name": "q", "dim": 3}, "aux": aux, "shared_weights": shared, "nodes": nodes})
    empty = build_tree(base)
    assert_same_outputs(tree(q, qd, with_slots(sets, tensors)), empty(q, qd))


def test_a_set_tensor_of_the_wrong_shape_is_one_clear_error():
    s = ObstacleSet(shape="sphere", n_max=3)
    aux = {
        "spheres_center": torch.zeros(2, 4, 3),
        "spheres_radius": torch.ones(2, 3, 1),
        "spheres_mask": torch.ones(2, 3),
    }
    with pytest.raises(ValueError, match=r"aux 'spheres_center' must be \(B, 3, 3\) for obstacle set 'spheres'"):
        with_slots([s], aux)


@pytest.mark.slow
def test_a_compiled_tree_serves_every_mask_without_recompiling():
    """Members appear and vanish between calls of one compiled tree: once warm (two calls with one mask: a tree with
    learned leaf numbers compiles again on its second call, whatever its aux), no change of mask compiles anything,
    and each call equals the eager tree."""
    from torch._dynamo.utils import counters

    s = ObstacleSet(shape="sphere", n_max=N_MAX)
    q, qd, raw = inputs(s, B=3, seed=2)
    eager = build_tree(tree_spec(s, list(range(1, N_MAX + 1)), masked=True))
    compiled = build_tree(tree_spec(s, list(range(1, N_MAX + 1)), masked=True))
    compiled.load_state_dict(eager.state_dict())
    compiled.compile()
    torch._dynamo.reset()
    counters.clear()
    graphs = []
    for mask in [MASKS[0], *MASKS]:
        raw[f"{s.prefix}_mask"] = torch.tensor(mask, dtype=torch.float64).expand(3, N_MAX)
        aux = with_slots([s], raw)
        with torch.no_grad():
            a, b = compiled(q, qd, aux), eager(q, qd, aux)
        graphs.append(counters["stats"]["unique_graphs"])
        torch.testing.assert_close(a.qdd, b.qdd, rtol=1e-10, atol=1e-10)
    assert graphs[1] >= 1 and graphs[-1] == graphs[1], f"graphs compiled after each call: {graphs}"
