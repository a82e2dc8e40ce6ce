"""A tube with a thin strand of outside material across its lumen (issue 17, session 26,
branch h26/handle): the surface has a handle (genus 1) whose short loop goes round the
strand, as hepatic_artery's pillar (docs/junctions.md, "Hepatic's bend is a pillar through
a round trunk"). The tube runs along x, closed at both ends; the strand is a straight rod
through its middle, tilted against the axis."""

from __future__ import annotations

import numpy as np

#: The tube: radius, half length; the strand: radius and tilt (degrees from the normal
#: plane of the tube's axis), hepatic's pillar is about 3 thick across a trunk about 20 across.
TUBE_RADIUS = 10.0
TUBE_HALF_LENGTH = 30.0
STRAND_RADIUS = 1.6
STRAND_TILT = 30.0


def pillar_distance(p: np.ndarray, strand: bool = True) -> np.ndarray:
    """Negative inside the lumen: the closed tube less the strand (a rod through the
    origin, in the x-y plane, tilted ``STRAND_TILT`` from y towards x)."""
    p = np.asarray(p, float).reshape(-1, 3)
    tube = np.maximum(np.hypot(p[:, 1], p[:, 2]) - TUBE_RADIUS, np.abs(p[:, 0]) - TUBE_HALF_LENGTH)
    if not strand:
        return tube
    t = np.radians(STRAND_TILT)
    d = np.array([np.sin(t), np.cos(t), 0.0])
    off = p - np.outer(p @ d, d)
    rod = np.linalg.norm(off, axis=1) - STRAND_RADIUS
    return np.maximum(tube, -rod)


def pillar_surface(h: float = 0.5, strand: bool = True):
    """The lumen's wall: marching cubes of :func:`pillar_distance` on a grid of step ``h``;
    ``(vertices, faces)`` oriented outward."""
    from skimage.measure import marching_cubes

    lo = np.array([-TUBE_HALF_LENGTH, -TUBE_RADIUS, -TUBE_RADIUS]) - 2 * h
    hi = -lo
    axes = [np.arange(a, b + h, h) for a, b in zip(lo, hi)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1)
    values = pillar_distance(grid.reshape(-1, 3), strand).reshape(grid.shape[:3])
    verts, faces, _, _ = marching_cubes(values, 0.0, spacing=(h, h, h))
    return verts + lo, np.ascontiguousarray(faces).astype(np.int64)
