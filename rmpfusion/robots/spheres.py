"""Control spheres fitted to a robot's collision geometry, and how well spheres cover it.

Per link: k-means on points sampled on the link's collision surface gives k centres; each radius reaches the
farthest sample of its cluster plus a margin. What is reported is measured on a second, independent sample, so a
fit cannot score itself on the points it was fitted to: **coverage** is the fraction of those surface points inside
some sphere of their link (spheres of other links are not counted, so a link is judged on its own spheres), and
**overshoot** is, per sphere, the largest distance from a point of its surface to the link's surface: how far the
sphere reaches out where there is no robot.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from .geometry import surface_samples


@dataclass
class LinkFit:
    """One link's spheres and their quality on independent samples."""

    link: str
    centers: np.ndarray  # (k, 3) in the link frame
    radii: np.ndarray  # (k,)
    points: np.ndarray  # (n, 3) independent surface samples
    covered: np.ndarray  # (n,) bool
    overshoot: np.ndarray  # (k,) m

    @property
    def coverage(self) -> float:
        return float(self.covered.mean()) if len(self.covered) else 1.0


def kmeans(points: np.ndarray, k: int, seed: int, iterations: int = 50) -> np.ndarray:
    """(k, 3) centres: k-means++ seeding then Lloyd's iterations (torch, reproducible by ``seed``)."""
    x = torch.as_tensor(points, dtype=torch.float64)
    g = torch.Generator().manual_seed(seed)
    centres = x[torch.randint(len(x), (1,), generator=g)]
    while len(centres) < k:
        d2 = torch.cdist(x, centres).min(1).values ** 2
        centres = torch.cat([centres, x[torch.multinomial(d2 / d2.sum(), 1, generator=g)]])
    for _ in range(iterations):
        label = torch.cdist(x, centres).argmin(1)
        new = torch.stack([x[label == j].mean(0) if bool((label == j).any()) else centres[j] for j in range(k)])
        if torch.allclose(new, centres, atol=1e-9):
            break
        centres = new
    return centres.numpy()


def covered_by(points: np.ndarray, centers: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """(n,) whether each point lies inside (or on) some sphere."""
    d = torch.cdist(torch.as_tensor(points), torch.as_tensor(centers)).numpy()
    return np.any(d <= radii[None, :] + 1e-12, axis=1)


def overshoot(centers: np.ndarray, radii: np.ndarray, surface: np.ndarray, per_sphere: int = 400) -> np.ndarray:
    """(k,) per sphere: the largest distance from a point of its surface to the nearest surface sample."""
    g = torch.Generator().manual_seed(0)
    dirs = torch.randn(per_sphere, 3, generator=g, dtype=torch.float64)
    dirs = dirs / dirs.norm(dim=1, keepdim=True)
    s = torch.as_tensor(surface)
    out = []
    for c, r in zip(centers, radii):
        pts = torch.as_tensor(c) + float(r) * dirs
        out.append(float(torch.cdist(pts, s).min(1).values.max()))
    return np.array(out)


def fit_link(
    link: str, mesh, k: int, margin: float = 0.002, n_fit: int = 4000, n_check: int = 4000, seed: int = 0
) -> LinkFit:
    """``k`` spheres covering one link's collision surface, measured on an independent sample."""
    fit_pts = surface_samples(mesh, n_fit, seed)
    centres = kmeans(fit_pts, k, seed)
    label = torch.cdist(torch.as_tensor(fit_pts), torch.as_tensor(centres)).argmin(1).numpy()
    radii = np.array(
        [np.linalg.norm(fit_pts[label == j] - centres[j], axis=1).max(initial=0.0) + margin for j in range(k)]
    )
    return measure(link, mesh, centres, radii, n_check, seed + 1)


def measure(link: str, mesh, centers, radii, n_check: int = 4000, seed: int = 1) -> LinkFit:
    """Coverage and overshoot of given spheres on one link, on ``n_check`` fresh surface samples."""
    centers, radii = np.asarray(centers, dtype=np.float64).reshape(-1, 3), np.asarray(radii, dtype=np.float64)
    pts = surface_samples(mesh, n_check, seed)
    return LinkFit(
        link,
        centers,
        radii,
        pts,
        covered_by(pts, centers, radii) if len(radii) else np.zeros(len(pts), dtype=bool),
        overshoot(centers, radii, pts) if len(radii) else np.zeros(0),
    )


def summary(fits: list[LinkFit]) -> dict[str, float]:
    """Coverage over every checked point (each link weighted by its samples), and overshoot over every sphere."""
    covered = np.concatenate([f.covered for f in fits]) if fits else np.zeros(0)
    over = np.concatenate([f.overshoot for f in fits]) if fits else np.zeros(0)
    return {
        "coverage": float(covered.mean()) if len(covered) else float("nan"),
        "overshoot_mean": float(over.mean()) if len(over) else float("nan"),
        "overshoot_max": float(over.max()) if len(over) else float("nan"),
        "spheres": int(sum(len(f.radii) for f in fits)),
    }
