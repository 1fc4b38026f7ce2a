"""tools/unseen_obstacle.py's tree surgery: experiment=lasa's tree with a disc's barrier leaf beside its others is the
same tree wherever the barrier is out of reach, and near the disc it turns a motion that heads into the disc away."""

from __future__ import annotations

import torch
from conftest import compose_cfg
from omegaconf import OmegaConf

from rmpfusion.assembly import build_tree
from tools.unseen_obstacle import BARRIER, normalising_scale, with_disc

AUX = {"goal": 2, "obstacle1_center": 2, "obstacle1_radius": 1}


def _trees() -> tuple[torch.nn.Module, torch.nn.Module, float]:
    spec = OmegaConf.to_container(compose_cfg(["experiment=lasa", "data.shape=Angle"])["tree"], resolve=True)
    torch.manual_seed(0)
    plain = build_tree(spec, aux_dims={"goal": 2}).double()
    torch.manual_seed(0)
    disc = build_tree(with_disc(spec, BARRIER), aux_dims=AUX).double()
    disc.load_state_dict(plain.state_dict(), strict=False)  # the same learned map: only the barrier is new
    return plain, disc, normalising_scale(spec)


def _aux(n: int, centre: tuple[float, float], radius: float) -> dict[str, torch.Tensor]:
    c = torch.tensor([centre], dtype=torch.float64).expand(n, -1).clone()
    return {
        "goal": torch.zeros(n, 2, dtype=torch.float64),
        "obstacle1_center": c,
        "obstacle1_radius": torch.full((n, 1), radius, dtype=torch.float64),
    }


def test_out_of_the_barriers_reach_the_tree_with_the_disc_is_the_trained_tree():
    plain, disc, scale = _trees()
    assert scale == 0.02
    gen = torch.Generator().manual_seed(1)
    q = 0.01 * torch.randn(32, 2, generator=gen, dtype=torch.float64)  # within 3 cm of the goal
    qd = 0.05 * torch.randn(32, 2, generator=gen, dtype=torch.float64)
    aux = _aux(32, (0.1, 0.1), 0.004)  # 14 cm away: beyond the 1 cm support
    torch.testing.assert_close(disc(q, qd, aux).qdd, plain(q, qd, {"goal": aux["goal"]}).qdd)


def _roll(tree, q: torch.Tensor, aux: dict, seconds: float, dt: float = 0.01) -> torch.Tensor:
    """Semi-implicit Euler from rest: the path (steps, 2)."""
    qd, path = torch.zeros_like(q), [q]
    with torch.no_grad():
        for _ in range(round(seconds / dt)):
            qd = qd + dt * tree(q, qd, aux).qdd
            q = q + dt * qd
            path.append(q)
    return torch.cat(path)


def test_a_motion_through_the_disc_goes_around_it_and_still_reaches_the_goal():
    """From rest 4 cm from the goal the tree's path runs along the x axis; a disc of 4 mm radius 1 mm beside that
    line is entered by the trained tree and never touched by the tree with the disc, which still ends at the goal (within 1 mm after 8 s)."""
    plain, disc, _ = _trees()
    centre, radius = torch.tensor([0.02, 0.001], dtype=torch.float64), 0.004
    aux = _aux(1, tuple(centre.tolist()), radius)
    start = torch.tensor([[0.04, 0.0]], dtype=torch.float64)
    free = _roll(plain, start, {"goal": aux["goal"]}, 8.0)
    around = _roll(disc, start, aux, 8.0)
    clearance = lambda path: float(((path - centre).norm(dim=-1) - radius).min())
    assert clearance(free) < 0, "the test needs a path through the disc"
    assert clearance(around) > 0, f"the path with the disc enters it by {-1e3 * clearance(around):.2f} mm"
    assert float(around[-1].norm()) < 1e-3, f"{1e3 * float(around[-1].norm()):.2f} mm from the goal after 8 s"
