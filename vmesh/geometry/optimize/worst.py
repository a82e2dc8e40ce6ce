"""A max-min pass for the worst elements of a valid linear hexahedral mesh.

The light pass (:mod:`vmesh.geometry.optimize`, ``kernels.SMOOTH``) moves a node only when
the minimum *and the sum* of its incident elements' scaled Jacobians do not drop, and its
climb follows the gradient of one corner, the worst. Where two or more corners around a
node are about equally bad and pull in different directions (the balanced elements an
untangler leaves at a junction crotch), the one-corner step lowers another corner and is
refused; a step that lifts the worst corner at some cost to the sum is refused too. Here
each node takes the steepest ascent of the minimum over *all* its nearly-worst corners
(Freitag and Ollivier-Gooch's max-min smoothing: the direction is the least-norm point of
the convex hull of their gradients), judged by the minimum alone. The corners and their gradients are compiled
(:mod:`vmesh.geometry.optimize.kernels_worst`).

Constraints are the light pass's (:func:`vmesh.geometry.optimize._node_kinds`): wall nodes
step in their tangent plane and are projected onto the wall, first-layer nodes keep their
height above the wall, cap nodes stay in their plane, rim and other boundary nodes are fixed.
"""

from __future__ import annotations

import itertools

import numpy as np

from . import _offset
from . import kernels as K
from . import kernels_worst as KW

#: corners within this much of a node's worst corner count as its worst (the active set of
#: the max-min direction; a scaled-Jacobian difference, not a quality target)
ACTIVE = 0.01
#: trial steps: the first is this fraction of the node's longest incident edge (as the light
#: pass's step caps, ``kernels.step_caps``; the shortest is the first-layer height for wall and
#: first-layer nodes, which would then barely move sideways), then halved until TRIALS halvings
#: of that fraction of the node's shortest edge are tried too
STEP, TRIALS = 0.25, 8
#: at most this many halvings more, down from the longest edge's step past the shortest's
MORE = 8


#: with the taper guard on: a node whose incident hexahedra's least Jacobian ratio is within
#: this of the guard's limit keeps that hexahedron's ratio from falling in its max-min
#: direction (:func:`_least_norm`'s ``cone``; a ratio difference, like ACTIVE)
RATIO_ACTIVE = 0.01


def _faces(rows):
    """Faces of the hull of ``rows`` gradients in 3-D that its least-norm point can lie in:
    every set of one to three of them."""
    return [f for k in (1, 2, 3) for f in itertools.combinations(range(rows), k)]


def _least_norm(G, ok, cone=False):
    """Least-norm points ``(c, 3)`` of the convex hulls of the rows of ``G (c, rows, 3)`` that
    ``ok (c, rows)`` marks (the first always): over the faces, the affine least-norm point that
    lies in its face and that every marked row sees ahead (``g . p >= |p|^2``).

    ``cone``: the last row is a constraint, not an objective: it enters with any weight
    ``>= 0`` (the hull of the others plus its ray) and need only be seen ``g . p >= 0``, so
    the direction ``p`` raises the others at the best common rate without lowering it (the
    dual of ``max min_i g_i . p`` over ``|p| <= 1`` and ``g_last . p >= 0``)."""
    c, rows = G.shape[0], G.shape[1]
    best = np.zeros((c, 3))
    bn = np.full(c, np.inf)
    last = rows - 1 if cone else -1
    for face in _faces(rows):
        if face[0] == last:
            continue  # the constraint's ray alone holds the origin
        A = G[:, face]  # (c, r, 3)
        if len(face) == 1:
            lam = np.ones((c, 1))
        else:
            D = A[:, 1:] - A[:, :1]
            if face[-1] == last:
                D[:, -1] = A[:, -1]  # a ray from the hull, not an edge of it
            M = np.einsum("cid,cjd->cij", D, D)
            rhs = -np.einsum("cid,cd->ci", D, A[:, 0])
            det = np.linalg.det(M)
            good = np.abs(det) > 1e-30 * np.maximum(np.einsum("cii->c", M) ** len(face[1:]), 1e-300)
            mu = np.zeros((c, len(face) - 1))
            if good.any():
                mu[good] = np.linalg.solve(M[good], rhs[good][..., None])[..., 0]
            hull = mu[:, :-1] if face[-1] == last else mu
            lam = np.concatenate([1 - hull.sum(1, keepdims=True), mu], 1)  # the ray's weight last
            lam[~good] = -1.0
        p = np.einsum("cr,crd->cd", lam, A)
        pn = (p * p).sum(1)
        ahead = np.einsum("crd,cd->cr", G, p)
        seen = ahead >= pn[:, None] * (1 - 1e-9) - 1e-15
        if cone:
            seen[:, last] = ahead[:, last] >= -1e-9 * pn - 1e-15
        valid = (lam >= -1e-12).all(1) & ok[:, list(face)].all(1) & (seen | ~ok).all(1) & (pn < bn)
        best[valid], bn[valid] = p[valid], pn[valid]
    return best, bn


def lift_worst(X, hexes, below, kind, normal, height, project=None, wall_normals=None, sweeps=10, X0=None, ratio_floor=-np.inf):
    """Raise the worst elements of a valid linear mesh in place: every node of an element
    below ``below`` takes max-min steps (see the module), Gauss-Seidel over a colouring of
    the nodes (a colour's nodes share no hexahedron and move together), for at most
    ``sweeps`` sweeps or until no node moves. The mesh's minimum scaled Jacobian never
    drops; other elements may give way (the caller's light pass restores the mean). Returns
    ``(nodes moved, sweeps run)``.

    ``kind``, ``normal``, ``height``: :func:`vmesh.geometry.optimize._node_kinds`. Missing
    (NaN) heights of the nodes that may move are measured up front on ``X0`` (default ``X``)
    and written into the caller's ``height`` array. ``hexes`` must be linear (8 columns).
    ``ratio_floor``: a step may not lower any incident element's Jacobian ratio below the
    lesser of this and the least ratio of the node's incident elements before the step (the light pass's taper guard; ``-inf``: none)."""
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
            if not len(group):
                continue
            ok = _step(X, hexes, ptr, inc, group, kind, normal, height, project, nrm, ratio_floor)  # a colour's nodes are independent
            dirty[group[~ok]] = False
            if ok.any():
                up = group[ok]
                moved[up] = True
                changed += len(up)
                cnt = ptr[up + 1] - ptr[up]
                t = np.repeat(ptr[up] - np.cumsum(cnt) + cnt, cnt) + np.arange(cnt.sum())
                dirty[np.unique(hexes[inc[t] >> 3])] = True
        if not changed:
            break
    return int(moved.sum()), sweep


def _direction(G, ok, cone=False):
    """Unit max-min directions ``(c, 3)`` over the rows of ``G`` that ``ok`` marks
    (:func:`_least_norm`) and where one exists."""
    d, dn = _least_norm(G, ok, cone)
    go = np.isfinite(dn) & (dn > 1e-24) & np.isfinite(d).all(1)
    return d / np.maximum(np.sqrt(np.where(go, dn, 1.0)), 1e-300)[:, None], go


def _step(X, hexes, ptr, inc, group, kind, normal, height, project, wall_nrm, ratio_floor=-np.inf):
    """One max-min step of each node of ``group`` (one colour); returns which moved (their
    incident minimum rose). ``wall_nrm (n, 3)``: the wall nodes' normals."""
    c = len(group)
    q0, G, edge, short = KW.worst_corners(X, hexes, ptr, inc, group)
    ok = q0 <= q0[:, :1] + ACTIVE
    k = kind[group]
    nrm = np.zeros((c, 3))
    plane = k == K.PLANE
    nrm[plane] = normal[group[plane]]
    onwall = (k == K.WALL) | (k == K.OFFSET)
    nrm[onwall] = wall_nrm[group[onwall]]
    nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-300)
    G = G - np.einsum("crd,cd->cr", G, nrm)[..., None] * nrm[:, None]
    if ratio_floor > -np.inf:
        # the guard refuses any trial that lowers a ratio at its limit: the direction keeps
        # that ratio from falling (a constraint of the max-min direction, not one more
        # objective: one that must climb it too lifts the scaled Jacobian less)
        margin, RG = KW.ratio_rows(X, hexes, ptr, inc, group, ratio_floor)
        RG = RG - np.einsum("cd,cd->c", RG, nrm)[:, None] * nrm
        d, go = _direction(np.concatenate([G, RG[:, None]], 1), np.concatenate([ok, (margin <= RATIO_ACTIVE)[:, None]], 1), cone=True)
    else:
        d, go = _direction(G, ok)
    if not go.any():
        return go
    # halvings from the longest edge's step down past TRIALS halvings of the shortest's, so a
    # wall or first-layer node (shortest edge: the first-layer height) still tries short steps
    extra = np.clip(np.ceil(np.log2(np.maximum(edge, 1e-300) / np.maximum(short, 1e-300))), 0, MORE).astype(np.int64)
    halvings = np.minimum(np.arange(TRIALS + int(extra.max()))[None], TRIALS - 1 + extra[:, None])  # (c, trials)
    trials = halvings.shape[1]
    T = X[group][:, None] + (STEP * edge[:, None] * 0.5**halvings)[..., None] * d[:, None]  # (c, trials, 3)
    w = np.flatnonzero(k == K.WALL)
    if len(w):
        T[w] = np.asarray(project(T[w].reshape(-1, 3)), float).reshape(len(w), trials, 3)
    o = np.flatnonzero(k == K.OFFSET)
    if len(o):
        T[o] = _offset(project, T[o].reshape(-1, 3), np.repeat(height[group[o]], trials)).reshape(len(o), trials, 3)
    qt = KW.trial_minima(X, hexes, ptr, inc, group, np.ascontiguousarray(T), ratio_floor)
    qt[~go] = -np.inf
    b = np.argmax(qt, axis=1)
    rose = qt[np.arange(c), b] > q0[:, 0] + 1e-9
    X[group[rose]] = T[np.flatnonzero(rose), b[rose]]
    return rose
