"""Compiled kernels of the max-min pass (:mod:`vmesh.geometry.optimize.worst`).

A node's corners are the corners of its incident (linear, tensor-order) hexahedra whose
three edges (along +i, +j, +k) it is an end of: the node's own corner and the three corners
one edge away (corner ids differing in at most one bit). Scaled Jacobian of a corner:
``det[u, v, w] / (|u| |v| |w|)`` (the product floored at 1e-300), as ``quality.hex8_scaled_jacobian``.
The kernels assume an element holds each node once (``lift_worst`` stops on a mesh with a
degenerate or inverted element).
"""

from __future__ import annotations

import numba as nb
import numpy as np

from .kernels import PARALLEL_FROM, _variant


@nb.njit(cache=True, inline="always")
def _edge_at(X, hexes, e, tail, head, v, y0, y1, y2):
    """The edge from local node ``tail`` to ``head`` of hexahedron ``e``, with the node ``v``
    placed at ``(y0, y1, y2)``."""
    t, h = hexes[e, tail], hexes[e, head]
    return ((y0 if h == v else X[h, 0]) - (y0 if t == v else X[t, 0]), (y1 if h == v else X[h, 1]) - (y1 if t == v else X[t, 1]),
            (y2 if h == v else X[h, 2]) - (y2 if t == v else X[t, 2]))


@nb.njit(cache=True, inline="always")
def _corner_edges(X, hexes, e, c, v, y0, y1, y2):
    """The edges of corner ``c`` of hexahedron ``e`` along +i, +j, +k (9 scalars, row by row),
    its scaled Jacobian and its edge-length product (floored), with the node ``v`` at ``y``;
    on scalars, so the trial minima make no array per trial and corner."""
    i, j, k = c & 1, (c >> 1) & 1, (c >> 2) & 1
    a0, a1, a2 = _edge_at(X, hexes, e, 2 * j + 4 * k, 1 + 2 * j + 4 * k, v, y0, y1, y2)
    b0, b1, b2 = _edge_at(X, hexes, e, i + 4 * k, i + 2 + 4 * k, v, y0, y1, y2)
    c0, c1, c2 = _edge_at(X, hexes, e, i + 2 * j, i + 2 * j + 4, v, y0, y1, y2)
    det = a0 * (b1 * c2 - b2 * c1) + a1 * (b2 * c0 - b0 * c2) + a2 * (b0 * c1 - b1 * c0)
    ln = np.sqrt((((0.0 + a0 ** 2) + a1 ** 2) + a2 ** 2) * (((0.0 + b0 ** 2) + b1 ** 2) + b2 ** 2) * (((0.0 + c0 ** 2) + c1 ** 2) + c2 ** 2))
    ln = max(ln, 1e-300)
    return a0, a1, a2, b0, b1, b2, c0, c1, c2, det / ln, ln


@nb.njit(cache=True, inline="always")
def _corner(X, hexes, e, c, v, y):
    """:func:`_corner_edges` with the edges as a ``(3, 3)`` array (for the gradients):
    edges, scaled Jacobian and edge-length product."""
    r = _corner_edges(X, hexes, e, c, v, y[0], y[1], y[2])
    E = np.empty((3, 3))
    E[0, 0], E[0, 1], E[0, 2], E[1, 0], E[1, 1], E[1, 2], E[2, 0], E[2, 1], E[2, 2] = r[0], r[1], r[2], r[3], r[4], r[5], r[6], r[7], r[8]
    return E, r[9], r[10]


def _worst_corners(X, hexes, ptr, inc, group):
    """For each node of ``group``: the scaled Jacobians ``(c, 3)`` of its three worst corners
    (ascending; +inf where it has fewer), their gradients ``(c, 3, 3)`` with respect to the
    node, and the longest and shortest of its incident edges ``(c,)``."""
    c = len(group)
    q = np.full((c, 3), np.inf)
    G = np.zeros((c, 3, 3))
    longest = np.zeros(c)
    shortest = np.full(c, np.inf)
    for a in nb.prange(c):
        v = group[a]
        y = X[v]
        for s in range(ptr[v], ptr[v + 1]):
            e, loc = inc[s] >> 3, inc[s] & 7
            for cc in range(8):
                x = cc ^ loc
                if x & (x - 1):  # more than one bit apart: not one of the node's corners
                    continue
                E, sj, ln = _corner(X, hexes, e, cc, v, y)
                if cc == loc:
                    for b in range(3):
                        el = np.sqrt((E[b] ** 2).sum())
                        longest[a] = max(longest[a], el)
                        shortest[a] = min(shortest[a], el)
                if not sj < q[a, 2]:
                    continue
                g = np.zeros(3)
                i, j, k = cc & 1, (cc >> 1) & 1, (cc >> 2) & 1
                ends = ((2 * j + 4 * k, 1 + 2 * j + 4 * k), (i + 4 * k, i + 2 + 4 * k), (i + 2 * j, i + 2 * j + 4))
                for b in range(3):
                    sign = (1.0 if ends[b][1] == loc else 0.0) - (1.0 if ends[b][0] == loc else 0.0)
                    if sign == 0.0:
                        continue
                    p, r = E[(b + 1) % 3], E[(b + 2) % 3]
                    cross = np.array([p[1] * r[2] - p[2] * r[1], p[2] * r[0] - p[0] * r[2], p[0] * r[1] - p[1] * r[0]])
                    g += sign * (cross / ln - sj * E[b] / max((E[b] ** 2).sum(), 1e-300))
                m = 2  # insert in the ascending three
                while m > 0 and sj < q[a, m - 1]:
                    q[a, m] = q[a, m - 1]
                    G[a, m] = G[a, m - 1]
                    m -= 1
                q[a, m] = sj
                G[a, m] = g
    return q, G, longest, shortest


def _trial_minima(X, hexes, ptr, inc, group, T):
    """``(c, trials)``: with node ``group[a]`` at ``T[a, t]``, the least scaled Jacobian of its
    corners (-inf where one is NaN: a degenerate trial is no candidate)."""
    c, nt = T.shape[0], T.shape[1]
    out = np.full((c, nt), np.inf)
    for a in nb.prange(c):
        v = group[a]
        for t in range(nt):
            y0, y1, y2 = T[a, t, 0], T[a, t, 1], T[a, t, 2]
            best = np.inf
            for s in range(ptr[v], ptr[v + 1]):
                e, loc = inc[s] >> 3, inc[s] & 7
                for cc in range(8):
                    x = cc ^ loc
                    if x & (x - 1):
                        continue
                    sj = _corner_edges(X, hexes, e, cc, v, y0, y1, y2)[9]
                    if sj != sj:
                        best = -np.inf
                    elif sj < best:
                        best = sj
            out[a, t] = best
    return out


#: parallel versions for large colours, serial ones for small colours (as ``kernels``)
_worst_corners_parallel = nb.njit(parallel=True, cache=True)(_variant(_worst_corners, "worst_corners_parallel"))
_worst_corners_serial = nb.njit(cache=True)(_variant(_worst_corners, "worst_corners_serial"))
_trial_minima_parallel = nb.njit(parallel=True, cache=True)(_variant(_trial_minima, "trial_minima_parallel"))
_trial_minima_serial = nb.njit(cache=True)(_variant(_trial_minima, "trial_minima_serial"))


def worst_corners(X, hexes, ptr, inc, group):
    """:func:`_worst_corners`, in parallel for ``PARALLEL_FROM`` nodes or more."""
    return (_worst_corners_parallel if len(group) >= PARALLEL_FROM else _worst_corners_serial)(X, hexes, ptr, inc, group)


def trial_minima(X, hexes, ptr, inc, group, T):
    """:func:`_trial_minima`, in parallel for ``PARALLEL_FROM`` nodes or more."""
    return (_trial_minima_parallel if len(group) >= PARALLEL_FROM else _trial_minima_serial)(X, hexes, ptr, inc, group, T)
