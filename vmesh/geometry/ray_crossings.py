"""Signed ray crossings of a :class:`~vmesh.geometry.bvh.TriangleBVH`: the winding number of a
closed, consistently oriented surface, exactly, without libigl (`build_sdf`'s sign check,
:meth:`vmesh.geometry.sdf.SignedDistance.ray_winding_number`; docs/sdf.md)."""

from __future__ import annotations

import numba as nb
import numpy as np

from .bvh import _box_interval, _line_triangle


def crossings(tree, origins, directions) -> np.ndarray:
    """Signed count of the crossings of the rays ``origins + t * directions`` (``t > 0``)
    with the triangles of ``tree``: +1 where a ray leaves through a triangle's front (its
    normal ``(b - a) x (c - a)`` along the ray), -1 where it enters. On a closed, consistently
    oriented surface this is the winding number of each origin (1 inside an outward surface,
    0 outside, 2 where two closed pieces overlap), exactly, for a ray through no edge or
    vertex (:meth:`vmesh.geometry.sdf.SignedDistance.ray_winding_number` takes the median of
    three rays).

    Parameters
    ----------
    tree : TriangleBVH
    origins, directions : (n, 3) array_like

    Returns
    -------
    (n,) int64
    """
    o = np.require(np.asarray(origins, dtype=np.float64).reshape(-1, 3), requirements="CW")
    d = np.require(np.asarray(directions, dtype=np.float64).reshape(-1, 3), requirements="CW")
    out = np.zeros(len(o), np.int64)
    if len(o):
        _crossings_run(o, d, tree._nodes, tree._first_leaf, tree.leaf_size, tree._a, tree._ab, tree._ac, out)
    return out


@nb.njit(cache=True, error_model="numpy")
def _crossings_run(origins, directions, nodes, first_leaf, leaf_size, A, AB, AC, out):
    """Signed crossings of the rays ``t > 0`` with the triangles (:func:`crossings`):
    every box the ray passes is opened (no nearest-first pruning: all crossings count)."""
    m = A.shape[0]
    stack = np.empty(256, np.int64)
    for i in range(origins.shape[0]):
        ox, oy, oz = origins[i, 0], origins[i, 1], origins[i, 2]
        dx, dy, dz = directions[i, 0], directions[i, 1], directions[i, 2]
        ix = 1.0 / dx if dx != 0.0 else np.inf
        iy = 1.0 / dy if dy != 0.0 else np.inf
        iz = 1.0 / dz if dz != 0.0 else np.inf
        count = 0
        stack[0] = 0
        sp = 1
        while sp > 0:
            sp -= 1
            node = stack[sp]
            t0, t1 = _box_interval(nodes, node, ox, oy, oz, ix, iy, iz)
            if t0 > t1 or t1 < 0.0:
                continue
            if node >= first_leaf:
                s0 = (node - first_leaf) * leaf_size
                for s in range(s0, min(s0 + leaf_size, m)):
                    t = _line_triangle(ox, oy, oz, dx, dy, dz, A, AB, AC, s)
                    if t == t and t > 0.0:
                        nx = AB[s, 1] * AC[s, 2] - AB[s, 2] * AC[s, 1]
                        ny = AB[s, 2] * AC[s, 0] - AB[s, 0] * AC[s, 2]
                        nz = AB[s, 0] * AC[s, 1] - AB[s, 1] * AC[s, 0]
                        count += 1 if nx * dx + ny * dy + nz * dz > 0.0 else -1
            else:
                stack[sp], stack[sp + 1] = 2 * node + 1, 2 * node + 2
                sp += 2
        out[i] = count
