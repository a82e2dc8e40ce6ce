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


@nb.njit(cache=True)
def _edge_at(X, hexes, e, tail, head, v, y0, y1, y2):
    """The edge from local node ``tail`` to ``head`` of hexahedron ``e``, with the node ``v``
    placed at ``(y0, y1, y2)``."""
    t, h = hexes[e, tail], hexes[e, head]
    return ((y0 if h == v else X[h, 0]) - (y0 if t == v else X[t, 0]), (y1 if h == v else X[h, 1]) - (y1 if t == v else X[t, 1]),
            (y2 if h == v else X[h, 2]) - (y2 if t == v else X[t, 2]))


@nb.njit(cache=True)
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


@nb.njit(cache=True)
def _length2(x0, x1, x2):
    """Squared length of an edge, summed in the order ``np.sum`` of its squares would."""
    return ((0.0 + x0 ** 2) + x1 ** 2) + x2 ** 2


@nb.njit(cache=True)
def _gradient_term(sign, p0, p1, p2, r0, r1, r2, e0, e1, e2, sj, ln):
    """``sign * (p x r / ln - sj e / |e|^2)``: the part of a corner's scaled-Jacobian gradient
    that comes through its edge ``e`` (``p``, ``r``: the corner's two other edges, in cyclic
    order), component by component on scalars."""
    m = max(_length2(e0, e1, e2), 1e-300)
    return (sign * ((p1 * r2 - p2 * r1) / ln - sj * e0 / m), sign * ((p2 * r0 - p0 * r2) / ln - sj * e1 / m),
            sign * ((p0 * r1 - p1 * r0) / ln - sj * e2 / m))


def _worst_corners(X, hexes, ptr, inc, group):
    """For each node of ``group``: the scaled Jacobians ``(c, 3)`` of its three worst corners
    (ascending; +inf where it has fewer), their gradients ``(c, 3, 3)`` with respect to the
    node, and the longest and shortest of its incident edges ``(c,)``.

    On scalars, no array per corner: an array expression in the ``prange`` body is a parfor
    (and a ufunc) of its own to compile. With that, and the helpers as plain calls (LLVM
    inlines them; ``inline="always"`` copied them into every parfor body at numba's IR
    level), the four kernels compile in 7.2 s CPU instead of 22.8 (docs/speed.md, session 19);
    the results are the same bits."""
    c = len(group)
    q = np.full((c, 3), np.inf)
    G = np.zeros((c, 3, 3))
    longest = np.zeros(c)
    shortest = np.full(c, np.inf)
    for a in nb.prange(c):
        v = group[a]
        y0, y1, y2 = X[v, 0], X[v, 1], X[v, 2]
        for s in range(ptr[v], ptr[v + 1]):
            e, loc = inc[s] >> 3, inc[s] & 7
            for cc in range(8):
                x = cc ^ loc
                if x & (x - 1):  # more than one bit apart: not one of the node's corners
                    continue
                a0, a1, a2, b0, b1, b2, c0, c1, c2, sj, ln = _corner_edges(X, hexes, e, cc, v, y0, y1, y2)
                if cc == loc:
                    for el in (np.sqrt(_length2(a0, a1, a2)), np.sqrt(_length2(b0, b1, b2)), np.sqrt(_length2(c0, c1, c2))):
                        longest[a] = max(longest[a], el)
                        shortest[a] = min(shortest[a], el)
                if not sj < q[a, 2]:
                    continue
                g0 = g1 = g2 = 0.0
                i, j, k = cc & 1, (cc >> 1) & 1, (cc >> 2) & 1
                # the node's sign along each edge: +1 at its head, -1 at its tail, 0 off it
                sa = (1.0 if 1 + 2 * j + 4 * k == loc else 0.0) - (1.0 if 2 * j + 4 * k == loc else 0.0)
                sb = (1.0 if i + 2 + 4 * k == loc else 0.0) - (1.0 if i + 4 * k == loc else 0.0)
                sc = (1.0 if i + 2 * j + 4 == loc else 0.0) - (1.0 if i + 2 * j == loc else 0.0)
                if sa != 0.0:
                    t0, t1, t2 = _gradient_term(sa, b0, b1, b2, c0, c1, c2, a0, a1, a2, sj, ln)
                    g0, g1, g2 = g0 + t0, g1 + t1, g2 + t2
                if sb != 0.0:
                    t0, t1, t2 = _gradient_term(sb, c0, c1, c2, a0, a1, a2, b0, b1, b2, sj, ln)
                    g0, g1, g2 = g0 + t0, g1 + t1, g2 + t2
                if sc != 0.0:
                    t0, t1, t2 = _gradient_term(sc, a0, a1, a2, b0, b1, b2, c0, c1, c2, sj, ln)
                    g0, g1, g2 = g0 + t0, g1 + t1, g2 + t2
                m = 2  # insert in the ascending three
                while m > 0 and sj < q[a, m - 1]:
                    q[a, m] = q[a, m - 1]
                    for d in range(3):
                        G[a, m, d] = G[a, m - 1, d]
                    m -= 1
                q[a, m] = sj
                G[a, m, 0], G[a, m, 1], G[a, m, 2] = g0, g1, g2
    return q, G, longest, shortest


@nb.njit(cache=True)
def _ratio(X, hexes, e, v, y0, y1, y2):
    """Jacobian ratio of hexahedron ``e`` (min det / max |det| over its 8 corners) with the
    node ``v`` placed at ``y``."""
    lo, hi = np.inf, 0.0
    for cc in range(8):
        a0, a1, a2, b0, b1, b2, c0, c1, c2, sj, ln = _corner_edges(X, hexes, e, cc, v, y0, y1, y2)
        det = a0 * (b1 * c2 - b2 * c1) + a1 * (b2 * c0 - b0 * c2) + a2 * (b0 * c1 - b1 * c0)
        lo, hi = min(lo, det), max(hi, abs(det))
    return lo / max(hi, 1e-300)


def _ratio_rows(X, hexes, ptr, inc, group, ratio_floor):
    """For each node of ``group``: its incident hexahedra's least Jacobian ratio less the
    guard's limit (the lesser of ``ratio_floor`` and that least ratio: so <= 0 when the least
    is below the floor), and that hexahedron's ratio gradient with respect to the node ``(c,
    3)``: ``(d_min' - r |d_max|') / |d_max|``, through the four corners the node moves (the
    other four are constant). The max-min direction takes it as one more row, so its step
    raises the ratio of a hexahedron at the guard's limit instead of being refused by it."""
    c = len(group)
    margin = np.full(c, np.inf)
    G = np.zeros((c, 3))
    for a in nb.prange(c):
        v = group[a]
        y0, y1, y2 = X[v, 0], X[v, 1], X[v, 2]
        least = np.inf
        for s in range(ptr[v], ptr[v + 1]):
            e, loc = inc[s] >> 3, inc[s] & 7
            lo, hi = np.inf, 0.0
            glo0 = glo1 = glo2 = ghi0 = ghi1 = ghi2 = 0.0
            for cc in range(8):
                a0, a1, a2, b0, b1, b2, c0, c1, c2, sj, ln = _corner_edges(X, hexes, e, cc, v, y0, y1, y2)
                det = a0 * (b1 * c2 - b2 * c1) + a1 * (b2 * c0 - b0 * c2) + a2 * (b0 * c1 - b1 * c0)
                g0 = g1 = g2 = 0.0
                x = cc ^ loc
                if not x & (x - 1):  # one of the node's corners: det moves with it
                    i, j, k = cc & 1, (cc >> 1) & 1, (cc >> 2) & 1
                    sa = (1.0 if 1 + 2 * j + 4 * k == loc else 0.0) - (1.0 if 2 * j + 4 * k == loc else 0.0)
                    sb = (1.0 if i + 2 + 4 * k == loc else 0.0) - (1.0 if i + 4 * k == loc else 0.0)
                    sc = (1.0 if i + 2 * j + 4 == loc else 0.0) - (1.0 if i + 2 * j == loc else 0.0)
                    # d det = sa (b x c) + sb (c x a) + sc (a x b)
                    g0 = sa * (b1 * c2 - b2 * c1) + sb * (c1 * a2 - c2 * a1) + sc * (a1 * b2 - a2 * b1)
                    g1 = sa * (b2 * c0 - b0 * c2) + sb * (c2 * a0 - c0 * a2) + sc * (a2 * b0 - a0 * b2)
                    g2 = sa * (b0 * c1 - b1 * c0) + sb * (c0 * a1 - c1 * a0) + sc * (a0 * b1 - a1 * b0)
                if det < lo:
                    lo, glo0, glo1, glo2 = det, g0, g1, g2
                if abs(det) > hi:
                    sg = 1.0 if det >= 0.0 else -1.0
                    hi, ghi0, ghi1, ghi2 = abs(det), sg * g0, sg * g1, sg * g2
            hi = max(hi, 1e-300)
            r = lo / hi
            if r < least:
                least = r
                G[a, 0], G[a, 1], G[a, 2] = (glo0 - r * ghi0) / hi, (glo1 - r * ghi1) / hi, (glo2 - r * ghi2) / hi
        margin[a] = least - min(ratio_floor, least)
    return margin, G


def _trial_minima(X, hexes, ptr, inc, group, T, ratio_floor):
    """``(c, trials)``: with node ``group[a]`` at ``T[a, t]``, the least scaled Jacobian of its
    corners (-inf where one is NaN: a degenerate trial is no candidate, and where an incident
    hexahedron's Jacobian ratio falls below the lesser of ``ratio_floor`` and the incident
    hexahedra's least ratio before, ``-inf`` for no such guard: the light pass's taper guard)."""
    c, nt = T.shape[0], T.shape[1]
    out = np.full((c, nt), np.inf)
    for a in nb.prange(c):
        v = group[a]
        least = ratio_floor
        if ratio_floor > -np.inf:
            for s in range(ptr[v], ptr[v + 1]):
                least = min(least, _ratio(X, hexes, inc[s] >> 3, v, X[v, 0], X[v, 1], X[v, 2]))
        for t in range(nt):
            y0, y1, y2 = T[a, t, 0], T[a, t, 1], T[a, t, 2]
            best = np.inf
            if ratio_floor > -np.inf:
                for s in range(ptr[v], ptr[v + 1]):
                    if _ratio(X, hexes, inc[s] >> 3, v, y0, y1, y2) < least:
                        best = -np.inf
                        break
                if best == -np.inf:
                    out[a, t] = best
                    continue
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
_ratio_rows_parallel = nb.njit(parallel=True, cache=True)(_variant(_ratio_rows, "ratio_rows_parallel"))
_ratio_rows_serial = nb.njit(cache=True)(_variant(_ratio_rows, "ratio_rows_serial"))
_trial_minima_parallel = nb.njit(parallel=True, cache=True)(_variant(_trial_minima, "trial_minima_parallel"))
_trial_minima_serial = nb.njit(cache=True)(_variant(_trial_minima, "trial_minima_serial"))


def worst_corners(X, hexes, ptr, inc, group):
    """:func:`_worst_corners`, in parallel for ``PARALLEL_FROM`` nodes or more."""
    return (_worst_corners_parallel if len(group) >= PARALLEL_FROM else _worst_corners_serial)(X, hexes, ptr, inc, group)


def ratio_rows(X, hexes, ptr, inc, group, ratio_floor):
    """:func:`_ratio_rows`, in parallel for ``PARALLEL_FROM`` nodes or more."""
    return (_ratio_rows_parallel if len(group) >= PARALLEL_FROM else _ratio_rows_serial)(X, hexes, ptr, inc, group, float(ratio_floor))


def trial_minima(X, hexes, ptr, inc, group, T, ratio_floor=-np.inf):
    """:func:`_trial_minima`, in parallel for ``PARALLEL_FROM`` nodes or more."""
    return (_trial_minima_parallel if len(group) >= PARALLEL_FROM else _trial_minima_serial)(X, hexes, ptr, inc, group, T, float(ratio_floor))
