"""Voxelising the inside of a vessel (stage 1 of the skeleton extraction).

The grid spacing follows the smallest vessel radius (:func:`estimate_min_radius`,
:func:`choose_spacing`); the SDF is evaluated hierarchically: a cell whose centre
is farther from the surface than its own half-diagonal has one sign throughout
(the SDF is 1-Lipschitz), so only cells near the wall are refined
(:func:`inside_mask`) and the work grows with the wall's area, not the box's
volume. Memory is one byte per voxel.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from .probe import SdfFunction, evaluate_sdf


def estimate_min_radius(
    sdf: SdfFunction,
    vertices: np.ndarray,
    faces: np.ndarray,
    quantile: float = 0.03,
    max_samples: int = 4000,
    iterations: int = 40,
) -> float:
    """Radius of the thinnest vessels of a surface, from inward chords.

    From the centroid of (a regular subsample of) the faces, a ray is traced into
    the vessel along the face normal (flipped where it points outwards according
    to the SDF) by sphere tracing; half the chord length is the local radius.
    The area-weighted ``quantile`` of these radii is returned: rays from cap rims
    or crotches are longer than a diameter, so they never make the estimate
    smaller than the thinnest vessel.

    Parameters
    ----------
    sdf : callable
        Signed distance, positive inside.
    vertices, faces : arrays
        The (closed) triangle surface.
    quantile : float
        Area fraction of the wall allowed to be thinner than the estimate.
    max_samples : int
        Number of faces sampled.
    iterations : int
        Sphere-tracing steps per ray.

    Returns
    -------
    float
        The radius estimate (``nan`` for an empty surface).
    """
    vertices = np.asarray(vertices, float)
    faces = np.asarray(faces, np.int64)
    if len(faces) == 0:
        return float("nan")
    step = max(1, len(faces) // max_samples)
    tri = vertices[faces[::step]]
    centre = tri.mean(axis=1)
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area = 0.5 * np.linalg.norm(normal, axis=1)
    ok = area > 0
    centre, normal, area = centre[ok], normal[ok] / (2 * area[ok, None]), area[ok]
    size = float(np.linalg.norm(vertices.max(axis=0) - vertices.min(axis=0)))
    eps = 1e-4 * size
    # point the rays inwards: the side where the SDF is positive
    flip = evaluate_sdf(sdf, centre - eps * normal) < evaluate_sdf(sdf, centre + eps * normal)
    inward = np.where(flip[:, None], normal, -normal)
    t = np.full(len(centre), eps)
    active = np.ones(len(centre), bool)
    for _ in range(iterations):
        idx = np.flatnonzero(active)
        if len(idx) == 0:
            break
        d = evaluate_sdf(sdf, centre[idx] + t[idx, None] * inward[idx])
        done = (d < 1e-2 * t[idx]) | (t[idx] > size)
        t[idx] += np.maximum(d, 0.0)
        active[idx[done]] = False
    radius = 0.5 * t
    order = np.argsort(radius)
    cumulative = np.cumsum(area[order]) / area.sum()
    return float(radius[order][np.searchsorted(cumulative, quantile)])



@dataclass(frozen=True)
class VoxelGrid:
    """A regular grid of voxel centres ``origin + spacing * (i, j, k)``."""

    origin: np.ndarray
    spacing: float
    shape: tuple

    @property
    def n_voxels(self) -> int:
        return int(np.prod(self.shape))

    def points(self, ijk: np.ndarray) -> np.ndarray:
        """World coordinates of voxel indices ``(n, 3)``."""
        return self.origin + self.spacing * np.asarray(ijk, float)



def grid_for_bounds(bounds, spacing: float, pad: int = 2, block: int = 8) -> VoxelGrid:
    """Grid covering ``bounds = (lo, hi)`` with ``pad`` voxels of margin; each
    dimension is a multiple of ``block`` (the coarsest cell of :func:`inside_mask`)."""
    lo, hi = (np.asarray(b, float) for b in bounds)
    origin = lo - pad * spacing
    counts = np.ceil((hi + pad * spacing - origin) / spacing).astype(np.int64) + 1
    counts = (counts + block - 1) // block * block
    return VoxelGrid(origin, float(spacing), tuple(int(c) for c in counts))



def choose_spacing(min_radius: float, bounds, voxels_per_radius: float, max_voxels: int) -> tuple[float, bool]:
    """Voxel size: ``min_radius / voxels_per_radius``, enlarged to stay within
    ``max_voxels`` over the bounding box. Returns (spacing, was_limited)."""
    lo, hi = (np.asarray(b, float) for b in bounds)
    extent = np.maximum(hi - lo, 1e-12)
    h = min_radius / voxels_per_radius
    limit = (np.prod(extent) / max_voxels) ** (1.0 / 3.0)
    if h < limit:
        return float(limit), True
    return float(h), False



def inside_mask(
    sdf: SdfFunction,
    grid: VoxelGrid,
    levels: int = 3,
    tolerance: float = 0.05,
    chunk: int = 1 << 18,
    progress: Callable | None = None,
) -> tuple[np.ndarray, int]:
    """Boolean mask of the voxel centres inside the surface (SDF > 0).

    Hierarchical evaluation: cells of ``2**levels`` voxels per side are tested at
    their centre; a cell whose |SDF| exceeds its half-diagonal (plus
    ``tolerance`` x spacing for an approximate SDF) lies on one side of the
    surface and is filled at once, the others are split into 8 children. Only
    cells near the wall reach voxel level, so the number of SDF evaluations grows
    with the surface area, not the volume of the bounding box.

    Returns
    -------
    mask : bool array of ``grid.shape``
    evaluations : int
        Number of SDF evaluations.
    """
    size = 1 << levels
    if any(s % size for s in grid.shape):
        raise ValueError("grid dimensions must be multiples of 2**levels")
    mask = np.zeros(grid.shape, dtype=bool)
    axes = [np.arange(0, s, size, dtype=np.int64) for s in grid.shape]
    cells = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    children = np.array([(a, b, c) for a in (0, 1) for b in (0, 1) for c in (0, 1)], dtype=np.int64)
    evaluations = 0
    level = 0
    while len(cells):
        centre = grid.origin + grid.spacing * (cells + 0.5 * (size - 1))
        d = evaluate_sdf(sdf, centre, chunk)
        evaluations += len(cells)
        if size == 1:
            inside = cells[d > 0]
            mask[inside[:, 0], inside[:, 1], inside[:, 2]] = True
            break
        reach = grid.spacing * (0.5 * math.sqrt(3.0) * (size - 1) + tolerance)
        full = cells[d > reach] // size
        if len(full):
            blocks = mask.reshape(grid.shape[0] // size, size, grid.shape[1] // size, size, grid.shape[2] // size, size)
            blocks[full[:, 0], :, full[:, 1], :, full[:, 2], :] = True
        near = cells[np.abs(d) <= reach]
        size //= 2
        cells = (near[:, None, :] + size * children[None, :, :]).reshape(-1, 3)
        level += 1
        if progress is not None:
            progress(level / (levels + 1), f"voxelising: {evaluations} distance evaluations")
    return mask, evaluations



def fill_cavities(mask: np.ndarray) -> np.ndarray:
    """Fill background regions not connected to the grid border (6-connected)."""
    from scipy import ndimage

    labels, count = ndimage.label(~mask)
    if count <= 1:
        return mask
    border = np.unique(
        np.concatenate(
            [labels[0].ravel(), labels[-1].ravel(), labels[:, 0].ravel(), labels[:, -1].ravel(), labels[:, :, 0].ravel(), labels[:, :, -1].ravel()]
        )
    )
    cavity = ~np.isin(labels, border) & (labels > 0)
    return mask | cavity

