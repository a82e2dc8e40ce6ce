"""A flattened vessel whose skeleton wanders over its wide side (issue 17, session 25,
branch h25/realbuild): an open tube of elliptic cross-section (the wide side ``wide``, the
thin side ``thin`` half-axes) along x, and a skeleton that runs on its axis, then zigzags
across the wide side by ``offsets`` at nodes ``gaps`` apart (as a thinned voxel skeleton
wanders over a flattened lumen's medial sheet), then runs on the axis again."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from data_synthetic.vessel_generator import Vessel, write_vessel
from junction_cases import JunctionCase
from vmesh.skeleton import Skeleton

#: The zigzag of the regression vessel: node offsets across the wide side and the gaps
#: between the nodes (hepatic_artery's extracted nodes 886-890 are 3.3-5.6 apart).
OFFSETS = (5.0, -5.0, 5.0, -5.0)
GAPS = (3.4, 3.3, 5.6, 3.9, 4.0)


@dataclass
class FlatTube(JunctionCase):
    """An elliptic tube along x from ``x_ends[0]`` to ``x_ends[1]``. Its field
    ``thin * (1 - rho)``, ``rho`` the elliptic radius, is 1-Lipschitz (so a lower bound of
    the distance, as ray marching needs) and zero on the wall."""

    wide: float = 10.0
    thin: float = 4.5
    x_ends: tuple = (-10.0, 60.0)

    def distance(self, p: np.ndarray) -> np.ndarray:
        p = np.asarray(p, float).reshape(-1, 3)
        rho = np.sqrt((p[:, 1] / self.wide) ** 2 + (p[:, 2] / self.thin) ** 2)
        return np.minimum(self.thin * (1.0 - rho), np.minimum(p[:, 0] - self.x_ends[0], self.x_ends[1] - p[:, 0]))


def wandering_skeleton(offsets=OFFSETS, gaps=GAPS, straight: int = 3, step: float = 3.3) -> np.ndarray:
    """Node positions: ``straight`` segments ``step`` long on the axis, the zigzag, and
    ``straight`` more (the zigzag's first node ``offsets[0]`` off the axis)."""
    x = np.r_[0.0, np.cumsum([step] * straight + list(gaps) + [step] * straight)]
    y = np.zeros(len(x))
    y[straight + 1 : straight + 1 + len(offsets)] = offsets
    return np.c_[x, y, np.zeros(len(x))]


def flat_tube_case(wide: float = 10.0, thin: float = 4.5, radius: float = 3.0, **kw) -> tuple:
    """The analytic vessel and its wandering skeleton (radius ``radius`` at every node: the
    thin side's), the tube reaching ``wide`` past both end nodes."""
    P = wandering_skeleton(**kw)
    n = len(P)
    sk = Skeleton(P, np.full(n, radius), np.c_[np.arange(n - 1), np.arange(1, n)])
    case = FlatTube("flat_wandering", np.zeros((1, 3)), np.zeros((1, 3)), np.array([thin]), sk, wide=wide, thin=thin,
                    x_ends=(float(P[0, 0]) - wide, float(P[-1, 0]) + wide))
    return case, sk


def flat_tube_vessel(folder, wide: float = 10.0, thin: float = 4.5, spacing: float = 0.5, units: str = "mm", **kw) -> dict:
    """The same tube as an open triangle surface (rings ``spacing`` apart, open at the end
    nodes' planes) with the wandering skeleton, written into ``folder``; returns its
    manifest."""
    P = wandering_skeleton(**kw)
    x = np.linspace(P[0, 0], P[-1, 0], int(np.ceil((P[-1, 0] - P[0, 0]) / spacing)) + 1)
    around = int(np.ceil(np.pi * (wide + thin) / spacing))
    t = 2 * np.pi * np.arange(around) / around
    V = np.stack([np.repeat(x, around), np.tile(wide * np.cos(t), len(x)), np.tile(thin * np.sin(t), len(x))], axis=1)
    i, j = np.meshgrid(np.arange(len(x) - 1), np.arange(around), indexing="ij")
    a, b = i * around + j, i * around + (j + 1) % around
    c, d = a + around, b + around
    faces = np.concatenate([np.stack([a, c, b], -1).reshape(-1, 3), np.stack([b, c, d], -1).reshape(-1, 3)])
    n = len(P)
    tags = [[] for _ in range(n)]
    tags[0], tags[-1] = ["inlet"], ["outlet"]
    radius = np.array([max(thin * (1.0 - np.hypot(p[1] / wide, p[2] / thin)), 0.1 * thin) for p in P])
    manifest = {"name": "flat_wandering", "units": units, "surface_format": "ply"}
    return write_vessel(Vessel(V, faces, P, radius, tags, np.c_[np.arange(n - 1), np.arange(1, n)], manifest), Path(folder))
