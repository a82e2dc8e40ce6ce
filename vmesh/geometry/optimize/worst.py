"""A max-min pass for the worst elements of a valid linear hexahedral mesh.

The light pass (:mod:`vmesh.geometry.optimize`, ``kernels.SMOOTH``) moves a node only when
the minimum *and the sum* of its incident elements' scaled Jacobians do not drop, and its
climb follows the gradient of one corner, the worst. Where two or more corners around a
node are about equally bad and pull in different directions (the balanced elements an
untangler leaves at a junction crotch), the one-corner step lowers another corner and is
refused; a step that lifts the worst corner at some cost to the sum is refused too. Here
each node takes the steepest ascent of the minimum over *all* its nearly-worst corners
(Freitag and Ollivier-Gooch's max-min smoothing: the direction is the least-norm point of
the convex hull of their gradients), judged by the minimum alone.

Constraints are the light pass's (:func:`vmesh.geometry.optimize._node_kinds`): wall nodes
step in their tangent plane and are projected onto the wall, first-layer nodes keep their
height above the wall, cap nodes stay in their plane, rim and other boundary nodes are fixed.
"""

from __future__ import annotations

import numpy as np

from . import _offset
from . import kernels as K

# corner c = i + 2 j + 4 k: its edges along +i, +j, +k, as (tail, head) local node ids
_C = np.arange(8)
_I, _J, _KK = _C & 1, (_C >> 1) & 1, (_C >> 2) & 1
_EDGES = np.stack(
    [
        np.stack([2 * _J + 4 * _KK, 1 + 2 * _J + 4 * _KK], 1),
        np.stack([_I + 4 * _KK, _I + 2 + 4 * _KK], 1),
        np.stack([_I + 2 * _J, _I + 2 * _J + 4], 1),
    ],
    1,
)  # (8 corners, 3 edges, tail/head)

#: corners within this much of a node's worst corner count as its worst (the active set of
#: the max-min direction; a scaled-Jacobian difference, not a quality target)
ACTIVE = 0.01
#: trial steps: the first is this fraction of the node's longest incident edge (as the light
#: pass's step caps, ``kernels.step_caps``; the shortest is the first-layer height for wall and
#: first-layer nodes, which then barely move sideways), then halved
STEP, TRIALS = 0.25, 8


def _corner_sj(P):
    """Scaled Jacobians ``(..., 8)``, the edges ``(..., 8, 3, 3)`` and the products of the
    edge lengths ``(..., 8)`` (floored) of hexahedra ``P (..., 8, 3)``."""
    E = P[..., _EDGES[:, :, 1], :] - P[..., _EDGES[:, :, 0], :]
    u, v, w = E[..., 0, :], E[..., 1, :], E[..., 2, :]
    det = np.einsum("...i,...i->...", u, np.cross(v, w))
    ln = np.maximum(np.sqrt((u * u).sum(-1) * (v * v).sum(-1) * (w * w).sum(-1)), 1e-300)
    return det / ln, E, ln


def _gradients(P, local):
    """Scaled Jacobians ``(..., 8)`` of the hexahedra ``P (..., 8, 3)``, their gradients
    ``(..., 8, 3)`` with respect to the node at local ids ``local (...)``, and which corners
    that node belongs to ``(..., 8)``."""
    sj, E, ln = _corner_sj(P)
    u, v, w = E[..., 0, :], E[..., 1, :], E[..., 2, :]
    ln = ln[..., None]
    d_e = np.stack([np.cross(v, w), np.cross(w, u), np.cross(u, v)], -2) / ln[..., None]
    d_e -= sj[..., None, None] * E / np.maximum((E * E).sum(-1, keepdims=True), 1e-300)
    lid = local[..., None, None]
    sign = (_EDGES[:, :, 1] == lid).astype(float) - (_EDGES[:, :, 0] == lid)  # (..., 8, 3)
    return sj, np.einsum("...ce,...ced->...cd", sign, d_e), sign.any(axis=-1)


#: faces of the hull of three gradients (the least-norm point of a 3-D hull lies in one)
_FACES = [(0,), (1,), (2,), (0, 1), (0, 2), (1, 2), (0, 1, 2)]


def _least_norm(G, ok):
    """Least-norm points ``(c, 3)`` of the convex hulls of the rows of ``G (c, 3, 3)`` that
    ``ok (c, 3)`` marks (the first always): over the faces, the affine least-norm point that
    lies in its face and that every marked row sees ahead (``g . p >= |p|^2``)."""
    c = len(G)
    best = np.zeros((c, 3))
    bn = np.full(c, np.inf)
    for face in _FACES:
        A = G[:, face]  # (c, r, 3)
        if len(face) == 1:
            lam = np.ones((c, 1))
        else:
            D = A[:, 1:] - A[:, :1]
            M = np.einsum("cid,cjd->cij", D, D)
            rhs = -np.einsum("cid,cd->ci", D, A[:, 0])
            det = np.linalg.det(M)
            good = np.abs(det) > 1e-30 * np.maximum(np.einsum("cii->c", M) ** len(face[1:]), 1e-300)
            mu = np.zeros((c, len(face) - 1))
            if good.any():
                mu[good] = np.linalg.solve(M[good], rhs[good][..., None])[..., 0]
            lam = np.concatenate([1 - mu.sum(1, keepdims=True), mu], 1)
            lam[~good] = -1.0
        p = np.einsum("cr,crd->cd", lam, A)
        pn = (p * p).sum(1)
        seen = np.einsum("crd,cd->cr", G, p) >= pn[:, None] * (1 - 1e-9) - 1e-15
        valid = (lam >= -1e-12).all(1) & ok[:, list(face)].all(1) & (seen | ~ok).all(1) & (pn < bn)
        best[valid], bn[valid] = p[valid], pn[valid]
    return best, bn


#: most nodes of a colour stepped at once: the trial arrays are (nodes, TRIALS, V, 8, 3) with
#: V the largest valence among them, so one irregular node pads every row
CHUNK = 2048


def lift_worst(X, hexes, below, kind, normal, height, project=None, wall_normals=None, sweeps=10, X0=None):
    """Raise the worst elements of a valid linear mesh in place: every node of an element
    below ``below`` takes max-min steps (see the module), Gauss-Seidel over a colouring of
    the nodes (a colour's nodes share no hexahedron and move together), for at most
    ``sweeps`` sweeps or until no node moves. The mesh's minimum scaled Jacobian never
    drops; other elements may give way (the caller's light pass restores the mean). Returns
    ``(nodes moved, sweeps run)``.

    ``kind``, ``normal``, ``height``: :func:`vmesh.geometry.optimize._node_kinds`. Missing
    (NaN) heights of the nodes that may move are measured up front on ``X0`` (default ``X``)
    and written into the caller's ``height`` array. ``hexes`` must be linear (8 columns)."""
    from ..quality import hex8_scaled_jacobian

    hexes = np.asarray(hexes)
    if hexes.ndim != 2 or hexes.shape[1] != 8:
        raise ValueError(f"lift_worst needs linear hexahedra (8 nodes per cell), got cells of shape {hexes.shape}")
    q = hex8_scaled_jacobian(X, hexes)
    low = q < below
    if not low.any() or q.min() <= 0:  # an inverted element is the untanglers' to fix
        return 0, 0
    n = len(X)
    ptr, inc = K.incidence(hexes, n)
    nodes = np.unique(hexes[low])
    nodes = nodes[kind[nodes] != K.FIXED]
    if project is None or wall_normals is None:
        nodes = nodes[(kind[nodes] != K.WALL) & (kind[nodes] != K.OFFSET)]
    if not len(nodes):
        return 0, 0
    X0 = X if X0 is None else X0
    todo = nodes[np.isnan(height[nodes])]
    if len(todo):
        height[todo] = np.linalg.norm(X0[todo] - np.asarray(project(X0[todo]), float), axis=1)
    colour = K.colour_nodes(hexes, ptr, inc, nodes, n)
    colours = [nodes[colour == c] for c in range(colour.max() + 1)]
    onwall = nodes[(kind[nodes] == K.WALL) | (kind[nodes] == K.OFFSET)]
    nrm = np.zeros((n, 3))
    moved = np.zeros(n, bool)
    dirty = np.ones(n, bool)
    sweep = 0
    for sweep in range(1, sweeps + 1):
        # a node moves only in its own colour's step, so its wall normal at the sweep's start
        # is the one at its step
        if len(onwall):
            nrm[onwall] = np.asarray(wall_normals(X[onwall]), float)
        changed = 0
        for group in colours:
            group = group[dirty[group]]
            for s in range(0, len(group), CHUNK):  # a colour's nodes are independent
                part = group[s : s + CHUNK]
                ok = _step(X, hexes, ptr, inc, part, kind, normal, height, project, nrm)
                dirty[part[~ok]] = False
                if ok.any():
                    up = part[ok]
                    moved[up] = True
                    changed += len(up)
                    cnt = ptr[up + 1] - ptr[up]
                    t = np.repeat(ptr[up] - np.cumsum(cnt) + cnt, cnt) + np.arange(cnt.sum())
                    dirty[np.unique(hexes[inc[t] >> 3])] = True
        if not changed:
            break
    return int(moved.sum()), sweep


def _step(X, hexes, ptr, inc, group, kind, normal, height, project, wall_nrm):
    """One max-min step of each node of ``group`` (one colour); returns which moved (their
    incident minimum rose). ``wall_nrm (n, 3)``: the wall nodes' normals."""
    c = len(group)
    val = ptr[group + 1] - ptr[group]
    V = int(val.max())
    slot = np.minimum(np.arange(V)[None], val[:, None] - 1)  # padding repeats the last element
    t = inc[ptr[group][:, None] + slot]
    real = np.arange(V)[None] < val[:, None]
    H, local = hexes[t >> 3], t & 7  # (c, V, 8), (c, V)
    P = X[H]
    sj, g, mine = _gradients(P, local)
    mine &= real[..., None]
    flat = np.where(mine, sj, np.inf).reshape(c, -1)
    worst = np.argsort(flat, axis=1)[:, :3]
    q0 = np.take_along_axis(flat, worst, 1)
    ok = q0 <= q0[:, :1] + ACTIVE
    G = np.take_along_axis(g.reshape(c, -1, 3), worst[..., None], 1)  # (c, 3, 3)
    k = kind[group]
    nrm = np.zeros((c, 3))
    plane = k == K.PLANE
    nrm[plane] = normal[group[plane]]
    onwall = (k == K.WALL) | (k == K.OFFSET)
    nrm[onwall] = wall_nrm[group[onwall]]
    nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-300)
    G = G - np.einsum("crd,cd->cr", G, nrm)[..., None] * nrm[:, None]
    d, dn = _least_norm(G, ok)
    go = np.isfinite(dn) & (dn > 1e-24) & np.isfinite(d).all(1)
    if not go.any():
        return go
    d = d / np.maximum(np.sqrt(dn), 1e-300)[:, None]
    ci, vi = np.arange(c)[:, None], np.arange(V)[None, :]
    ends = P[ci[..., None], vi[..., None], _EDGES[local, :, 1]] - P[ci[..., None], vi[..., None], _EDGES[local, :, 0]]  # the node's corner's edges
    edge = np.where(real[..., None], np.linalg.norm(ends, axis=-1), 0.0).max(axis=(1, 2))
    T = X[group][:, None] + (STEP * edge[:, None] * 0.5 ** np.arange(TRIALS))[..., None] * d[:, None]  # (c, TRIALS, 3)
    w = np.flatnonzero(k == K.WALL)
    if len(w):
        T[w] = np.asarray(project(T[w].reshape(-1, 3)), float).reshape(len(w), TRIALS, 3)
    o = np.flatnonzero(k == K.OFFSET)
    if len(o):
        T[o] = _offset(project, T[o].reshape(-1, 3), np.repeat(height[group[o]], TRIALS)).reshape(len(o), TRIALS, 3)
    Pt = np.repeat(P[:, None], TRIALS, axis=1)  # (c, TRIALS, V, 8, 3)
    Pt[ci, :, vi, local] = T[:, None]  # (indexed as (c, V, TRIALS, 3): the advanced indices first)
    sjt = _corner_sj(Pt)[0]  # (c, TRIALS, V, 8)
    qt = np.where(mine[:, None], sjt, np.inf).min(axis=(2, 3))
    qt = np.where(np.isnan(qt), -np.inf, qt)  # a degenerate trial is no candidate
    qt[~go] = -np.inf
    b = np.argmax(qt, axis=1)
    rose = qt[np.arange(c), b] > q0[:, 0] + 1e-9
    X[group[rose]] = T[np.flatnonzero(rose), b[rose]]
    return rose
