"""The structure of an optimiser stage (:mod:`vmesh.geometry.optimize`), compiled: node-to-
hexahedron incidence, the node colouring, step caps, target scales and ring growth (moved out
of :mod:`.kernels`, which re-exports them, to keep that module under the size limit)."""

from __future__ import annotations

import numba as nb
import numpy as np


@nb.njit(cache=True)
def incidence(hexes, n):
    """Node-to-hexahedron incidence as CSR: ``ptr (n+1,)`` and ``inc`` = 8 * element + local corner."""
    count = np.zeros(n + 1, np.int64)
    m = hexes.shape[0]
    for e in range(m):
        for c in range(8):
            count[hexes[e, c] + 1] += 1
    ptr = np.cumsum(count)
    fill = ptr[:-1].copy()
    inc = np.empty(8 * m, np.int64)
    for e in range(m):
        for c in range(8):
            v = hexes[e, c]
            inc[fill[v]] = 8 * e + c
            fill[v] += 1
    return ptr, inc


@nb.njit(cache=True)
def colour_nodes(hexes, ptr, inc, nodes, n):
    """Greedy colouring of ``nodes`` so that no two of one colour share a hexahedron
    (deterministic: nodes in the given order, smallest free colour)."""
    colour = np.full(n, -1, np.int64)
    active = np.zeros(n, np.bool_)
    for v in nodes:
        active[v] = True
    used = np.full(256, -1, np.int64)  # stamp per colour: used by a neighbour of the node `stamp`
    out = np.empty(len(nodes), np.int64)
    for j in range(len(nodes)):
        v = nodes[j]
        for t in range(ptr[v], ptr[v + 1]):
            e = inc[t] >> 3
            for c in range(8):
                w = hexes[e, c]
                if active[w] and colour[w] >= 0:
                    used[colour[w]] = v
        col = 0
        while col < 255 and used[col] == v:
            col += 1
        colour[v] = col
        out[j] = col
    return out


@nb.njit(cache=True)
def step_caps(X, hexes, ptr, inc, nodes, n, fraction):
    """Largest step per node: ``fraction`` of its longest incident edge."""
    cap = np.zeros(n)
    for v in nodes:
        longest = 0.0
        for t in range(ptr[v], ptr[v + 1]):
            e = inc[t] >> 3
            l = inc[t] & 7
            for a in range(3):
                w = hexes[e, l ^ (1 << a)]
                d = (X[w, 0] - X[v, 0]) ** 2 + (X[w, 1] - X[v, 1]) ** 2 + (X[w, 2] - X[v, 2]) ** 2
                longest = max(longest, d)
        cap[v] = fraction * np.sqrt(longest)
    return cap


@nb.njit(parallel=True, cache=True)
def target_scales(X, hexes, floor):
    """``1 / target length`` per hexahedron and axis ``(m, 3)``: the element's thickness
    across each axis.

    With ``m_a`` the mean of the element's four edges along axis ``a``, the thickness is
    ``|m_a . (m_b x m_c)| / |m_b x m_c|``, the height between its two faces across ``a``.
    Unlike edge lengths it ignores shear: a boundary-layer element whose wall nodes were
    shifted along the wall still asks for its first-layer height, not its slanted edge.
    Where the element's mean frame is degenerate or inverted (a fold), the mean edge
    length is used instead.
    """
    m = hexes.shape[0]
    out = np.empty((m, 3))
    for e in nb.prange(m):
        M = np.zeros((3, 3))
        for a in range(3):
            for c in range(8):
                if (c >> a) & 1 == 0:
                    u, w = hexes[e, c], hexes[e, c ^ (1 << a)]
                    for d in range(3):
                        M[a, d] += 0.25 * (X[w, d] - X[u, d])
        for a in range(3):
            b, c2 = (a + 1) % 3, (a + 2) % 3
            nx = M[b, 1] * M[c2, 2] - M[b, 2] * M[c2, 1]
            ny = M[b, 2] * M[c2, 0] - M[b, 0] * M[c2, 2]
            nz = M[b, 0] * M[c2, 1] - M[b, 1] * M[c2, 0]
            area = np.sqrt(nx * nx + ny * ny + nz * nz)
            length = np.sqrt(M[a, 0] ** 2 + M[a, 1] ** 2 + M[a, 2] ** 2)
            height = (M[a, 0] * nx + M[a, 1] * ny + M[a, 2] * nz) / max(area, 1e-300)
            t = height if height > 0.02 * length else length
            out[e, a] = 1.0 / max(t, floor)
    return out


@nb.njit(cache=True)
def grow_nodes(hexes, ptr, inc, mask):
    """Nodes of every hexahedron that has a node in ``mask`` (one ring more)."""
    out = mask.copy()
    for v in range(len(mask)):
        if mask[v]:
            for t in range(ptr[v], ptr[v + 1]):
                e = inc[t] >> 3
                for c in range(8):
                    out[hexes[e, c]] = True
    return out
