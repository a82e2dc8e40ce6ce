"""Compiled kernels of the transfinite mesher (numba, parallel over lattices or lines):
Coons patches, transfinite interpolation, boundary-layer re-spacing along lattice lines,
row-wise interpolation and the element connectivity. See :mod:`vmesh.geometry.transfinite`."""

from __future__ import annotations

import numba as nb
import numpy as np

from . import bvh  # noqa: F401  (chooses numba's threading layer before the first parallel kernel)


def _interp_rows(x: np.ndarray, xp: np.ndarray, fp: np.ndarray) -> np.ndarray:
    """Row-wise ``np.interp``: x (m, j), xp (m, k) ascending per row, fp (m, k) or (m, k, d)."""
    x = np.ascontiguousarray(x, float)
    xp = np.ascontiguousarray(xp, float)
    f3 = np.ascontiguousarray(fp, float)
    if f3.ndim == 2:
        f3 = f3[:, :, None]
    out = _interp_rows_kernel(x, xp, f3)
    return out[:, :, 0] if np.ndim(fp) == 2 else out



# ---------------------------------------------------------------------------
# transfinite interpolation kernels
# ---------------------------------------------------------------------------
def coons_patch(P: np.ndarray) -> np.ndarray:
    """Fill the interior of lattices (m, Ns+1, Nt+1, 3) from their boundary (Coons patch).

    Blending parameters follow the arc-length spacing of opposite edges, so graded
    edge distributions carry into the face.
    """
    P = np.array(P, float, order="C", copy=True)
    _coons_kernel(P)
    return P


def transfinite_volume(P: np.ndarray) -> np.ndarray:
    """Fill lattices (m, I+1, J+1, K+1, 3) from their six faces (transfinite interpolation).

    Blending parameters along each axis follow the mean spacing of the block's four
    parallel edges.
    """
    P = np.array(P, float, order="C", copy=True)
    _tfi_kernel(P)
    return P


# ---------------------------------------------------------------------------
# compiled kernels (parallel over lattices or lines)
# ---------------------------------------------------------------------------
@nb.njit(cache=True, error_model="numpy")
def _ratio(first, length, n):
    """Geometric ratio of one edge (see :func:`geometric_ratio`): Newton steps on the convex
    ``s(q) = 1 + q + ... + q**(n-1)`` from above the root converge monotonically; the sum
    form has no cancellation near q = 1, unlike ``(q**n - 1) / (q - 1)``."""
    target = length / max(first, 1e-300)
    if not target > n:
        return 1.0
    q = 2.0
    for _ in range(60):  # a bracket top: s(q) >= target
        s = 1.0
        for _i in range(n - 1):
            s = s * q + 1.0
        if s >= target:
            break
        q *= 2.0
    for _ in range(200):
        s, ds = 1.0, 0.0
        for _i in range(n - 1):
            ds = ds * q + s
            s = s * q + 1.0
        step = (s - target) / ds
        if not step > 1e-16 * q:
            break
        q -= step
    return q


@nb.njit(parallel=True, cache=True, error_model="numpy")
def _ratio_kernel(first, length, n):
    out = np.empty(len(first))
    for e in nb.prange(len(first)):
        out[e] = _ratio(first[e], length[e], n)
    return out


@nb.njit(cache=True, error_model="numpy")
def _interp_line(x, xp, fp, out):
    """``out[i] = interp(x[i], xp, fp)`` for one ascending row (fp: (k, d)), the arithmetic of
    the former vectorised row-wise interpolation: interval by normalised position, clipped
    weights, flat extension outside the row."""
    k = len(xp)
    lo = xp[0]
    span = max(xp[k - 1] - lo, 1e-300)
    j = 0
    for i in range(len(x)):
        xn = min(max((x[i] - lo) / span, 0.0), 1.0)
        # last node at or before x (x is usually ascending: walk from the previous one)
        while j > 0 and (xp[j] - lo) / span > xn:
            j -= 1
        while j + 1 < k and (xp[j + 1] - lo) / span <= xn:
            j += 1
        c = min(j, k - 2)
        x0, x1 = xp[c], xp[c + 1]
        w = 0.0
        if x1 > x0:
            w = min(max((x[i] - x0) / max(x1 - x0, 1e-300), 0.0), 1.0)
        for d in range(fp.shape[1]):
            out[i, d] = fp[c, d] + w * (fp[c + 1, d] - fp[c, d])


@nb.njit(parallel=True, cache=True, error_model="numpy")
def _interp_rows_kernel(x, xp, fp):
    m = x.shape[0]
    out = np.empty((m, x.shape[1], fp.shape[2]))
    for r in nb.prange(m):
        _interp_line(x[r], xp[r], fp[r], out[r])
    return out


@nb.njit(cache=True, error_model="numpy")
def _arc_lengths(P, out):
    """Arc length from the first node at every node of one polyline (n, 3) into out (n,)."""
    out[0] = 0.0
    for i in range(1, P.shape[0]):
        dx, dy, dz = P[i, 0] - P[i - 1, 0], P[i, 1] - P[i - 1, 1], P[i, 2] - P[i - 1, 2]
        out[i] = out[i - 1] + np.sqrt(dx * dx + dy * dy + dz * dz)


@nb.njit(cache=True, error_model="numpy")
def _arc_params(P, out):
    """Normalised arc-length parameters of one polyline (n, 3) into out (n,)."""
    _arc_lengths(P, out)
    total = max(out[P.shape[0] - 1], 1e-300)
    for i in range(P.shape[0]):
        out[i] = out[i] / total


@nb.njit(parallel=True, cache=True, error_model="numpy")
def _coons_kernel(P):
    """Coons patch of lattices (m, Ns+1, Nt+1, 3) in place (interior only)."""
    m, ns1, nt1 = P.shape[0], P.shape[1], P.shape[2]
    Ns, Nt = ns1 - 1, nt1 - 1
    for f in nb.prange(m):
        Q = P[f]
        sb, st = np.empty(ns1), np.empty(ns1)
        vl, vr = np.empty(nt1), np.empty(nt1)
        _arc_params(Q[:, 0], sb)
        _arc_params(Q[:, Nt], st)
        _arc_params(Q[0, :], vl)
        _arc_params(Q[Ns, :], vr)
        for i in range(1, Ns):
            s_mean = 0.5 * (sb[i] + st[i])
            for j in range(1, Nt):
                t_mean = 0.5 * (vl[j] + vr[j])
                u = (1 - t_mean) * sb[i] + t_mean * st[i]
                v = (1 - s_mean) * vl[j] + s_mean * vr[j]
                for d in range(3):
                    Q[i, j, d] = (
                        (1 - v) * Q[i, 0, d] + v * Q[i, Nt, d] + (1 - u) * Q[0, j, d] + u * Q[Ns, j, d]
                        - ((1 - u) * (1 - v) * Q[0, 0, d] + u * (1 - v) * Q[Ns, 0, d] + (1 - u) * v * Q[0, Nt, d] + u * v * Q[Ns, Nt, d])
                    )


@nb.njit(cache=True, error_model="numpy")
def _mean_edge_params(e0, e1, e2, e3, tmp, out):
    """Mean of the normalised arc-length parameters of four parallel edges."""
    _arc_params(e0, out)
    _arc_params(e1, tmp)
    for i in range(len(out)):
        out[i] = out[i] + tmp[i]
    _arc_params(e2, tmp)
    for i in range(len(out)):
        out[i] = out[i] + tmp[i]
    _arc_params(e3, tmp)
    for i in range(len(out)):
        out[i] = (out[i] + tmp[i]) / 4


@nb.njit(cache=True, error_model="numpy")
def _tfi_one(Q):
    """Transfinite interpolation of one lattice (I+1, J+1, K+1, 3) in place (interior only):
    the Boolean sum of the three directional projectors W1 (along i), W2 (adds j), W3 (adds k)."""
    I, J, K = Q.shape[0] - 1, Q.shape[1] - 1, Q.shape[2] - 1
    u, v, w = np.empty(I + 1), np.empty(J + 1), np.empty(K + 1)
    _mean_edge_params(Q[:, 0, 0], Q[:, 0, K], Q[:, J, 0], Q[:, J, K], np.empty(I + 1), u)
    _mean_edge_params(Q[0, :, 0], Q[0, :, K], Q[I, :, 0], Q[I, :, K], np.empty(J + 1), v)
    _mean_edge_params(Q[0, 0, :], Q[0, J, :], Q[I, 0, :], Q[I, J, :], np.empty(K + 1), w)
    # W2 on the faces k = 0 and k = K (needed by W3), W1 on j = 0 and j = J (needed by W2)
    # (i, d, j): the rows _w2_row fills are C-contiguous, as ``row`` is, and k = 0 is passed
    # as a run-time integer: one specialisation of _w2_row, not three
    W2lo = np.empty((I + 1, 3, J + 1))
    W2hi = np.empty((I + 1, 3, J + 1))
    k0 = np.int64(0)
    for i in range(1, I):
        for d in range(3):
            _w2_row(Q, u, v, i, k0, d, W2lo[i, d])
            _w2_row(Q, u, v, i, K, d, W2hi[i, d])
    row = np.empty(J + 1)
    for i in range(1, I):
        for kk in range(1, K):
            for d in range(3):
                _w2_row(Q, u, v, i, kk, d, row)
                for j in range(1, J):
                    Q[i, j, kk, d] = row[j] + ((1 - w[kk]) * (Q[i, j, 0, d] - W2lo[i, d, j]) + w[kk] * (Q[i, j, K, d] - W2hi[i, d, j]))


@nb.njit(cache=True, error_model="numpy")
def _w2_row(Q, u, v, i, kk, d, out):
    """``out[j]`` = W2 (the projectors along i and j) at lattice ``(i, j, kk)``, coordinate d,
    for the interior j."""
    I, J = Q.shape[0] - 1, Q.shape[1] - 1
    a0 = (1 - u[i]) * Q[0, 0, kk, d] + u[i] * Q[I, 0, kk, d]
    aJ = (1 - u[i]) * Q[0, J, kk, d] + u[i] * Q[I, J, kk, d]
    for j in range(1, J):
        W1 = (1 - u[i]) * Q[0, j, kk, d] + u[i] * Q[I, j, kk, d]
        out[j] = W1 + ((1 - v[j]) * (Q[i, 0, kk, d] - a0) + v[j] * (Q[i, J, kk, d] - aJ))


@nb.njit(parallel=True, cache=True, error_model="numpy")
def _tfi_kernel(P):
    """Transfinite interpolation of lattices (m, I+1, J+1, K+1, 3) in place."""
    for b in nb.prange(P.shape[0]):
        _tfi_one(P[b])


@nb.njit(parallel=True, cache=True, error_model="numpy")
def _regrade_kernel(P, lattices, inner_before, inner_after, wall_first, h1, n, ref):
    """:func:`_regrade_one` on the lattices ``P[lattices]`` (P: (m, A, k, C, 3))."""
    for q in nb.prange(len(lattices)):
        b = lattices[q]
        _regrade_one(P[b], inner_before, inner_after, wall_first[b], h1[b], n, ref)


@nb.njit(cache=True, error_model="numpy")
def _regrade_one(Q, inner_before, inner_after, wall_first, h1, n, ref):
    """Re-space the lines ``Q[a, :, c]`` (Q: (A, k, C, 3)) of one lattice whose indices a and
    c are interior: geometric element boundaries with first element ``h1`` from the wall
    end, high-order nodes at ``ref`` inside each element, placed by arc length."""
    A, k, C = Q.shape[0], Q.shape[1], Q.shape[2]
    p = len(ref)
    line = np.empty((k, 3))
    s = np.empty(k)
    t = np.empty(n + 1)
    target = np.empty(k)
    new = np.empty((k, 3))
    for a in range(A):
        if not inner_before[a]:
            continue
        for c in range(C):
            if not inner_after[c]:
                continue
            for i in range(k):  # wall end first
                src = i if wall_first else k - 1 - i
                for d in range(3):
                    line[i, d] = Q[a, src, c, d]
            _arc_lengths(line, s)
            length = s[k - 1]
            ratio = _ratio(h1, length, n)
            t[0] = 0.0
            for e in range(n):
                t[e + 1] = t[e] + ratio ** float(e)
            total = t[n]
            for e in range(n + 1):
                t[e] = t[e] / total
            for e in range(n):
                for r in range(p):
                    target[e * p + r] = (t[e] + (t[e + 1] - t[e]) * ref[r]) * length
            target[n * p] = t[n] * length
            _interp_line(target, s, line, new)
            for i in range(k):
                dst = i if wall_first else k - 1 - i
                for d in range(3):
                    Q[a, dst, c, d] = new[i, d]


@nb.njit(parallel=True, cache=True, error_model="numpy")
def _fill_blocks_kernel(X, L, layer, wall_first, h1, n3, ref, before0, after0, before1, after1, before2, after2):
    """Fill the block lattices ``L`` (m, I+1, J+1, K+1) of node ids in the node array X in place:
    gather each lattice, transfinite interpolation, re-spacing of the boundary-layer lines
    along the axes flagged in ``layer`` (m, 3), scatter of the interior nodes."""
    m, I1, J1, K1 = L.shape
    for b in nb.prange(m):
        Q = np.empty((I1, J1, K1, 3))
        for i in range(I1):
            for j in range(J1):
                for k in range(K1):
                    for d in range(3):
                        Q[i, j, k, d] = X[L[b, i, j, k], d]
        _tfi_one(Q)
        if layer[b, 0]:
            _regrade_one(Q.reshape((1, I1, J1 * K1, 3)), before0, after0, wall_first[b, 0], h1[b, 0], n3[0], ref)
        if layer[b, 1]:
            _regrade_one(Q.reshape((I1, J1, K1, 3)), before1, after1, wall_first[b, 1], h1[b, 1], n3[1], ref)
        if layer[b, 2]:
            _regrade_one(Q.reshape((I1 * J1, K1, 1, 3)), before2, after2, wall_first[b, 2], h1[b, 2], n3[2], ref)
        for i in range(1, I1 - 1):
            for j in range(1, J1 - 1):
                for k in range(1, K1 - 1):
                    for d in range(3):
                        X[L[b, i, j, k], d] = Q[i, j, k, d]


@nb.njit(parallel=True, cache=True, error_model="numpy")
def _cells_kernel(L, p, out):
    """Element node ids of block lattices L (m, I+1, J+1, K+1) into out (m nk nj ni, (p+1)^3):
    elements ordered (block, ek, ej, ei), nodes in tensor order (i fastest)."""
    m = L.shape[0]
    ni, nj, nk = (L.shape[1] - 1) // p, (L.shape[2] - 1) // p, (L.shape[3] - 1) // p
    for b in nb.prange(m):
        for ek in range(nk):
            for ej in range(nj):
                for ei in range(ni):
                    e = ((b * nk + ek) * nj + ej) * ni + ei
                    c = 0
                    for kk in range(p + 1):
                        for jj in range(p + 1):
                            for ii in range(p + 1):
                                out[e, c] = L[b, ei * p + ii, ej * p + jj, ek * p + kk]
                                c += 1
