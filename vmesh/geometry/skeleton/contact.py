"""Vessels that pass each other in contact without a junction between them.

Two branches far apart along the skeleton whose centerlines pass closer than the sum of
their radii (kissing vessels, or crossing ones, as in a whole-brain SWC tree) have lumens
that touch or fuse in the surface while the skeleton has no junction there: each tube's
blocks meet the other vessel's wall, and the fill may fold where no block repair or
untangling can open it (issue 17: the last inverted elements of a whole-brain tree and of
generated vessels). The block builder keeps each vessel's rays in its own territory; this
finds the places, so that a run can name them.
"""

from __future__ import annotations

import numpy as np


def vessels_in_contact(points: np.ndarray, radii: np.ndarray, edges: np.ndarray, reach: float = 1.0, detour: float = 4.0) -> np.ndarray:
    """Pairs of skeleton nodes in two vessels that pass in contact.

    Parameters
    ----------
    points : (n, 3) node positions.
    radii : (n,) node radii.
    edges : (e, 2) segments.
    reach : float
        Nodes closer than ``reach`` x the sum of their radii are in contact.
    detour : float
        ... and belong to different vessels when their way along the skeleton is longer than
        ``detour`` x that sum (inf when unconnected): neighbours along one vessel and the
        branches of one junction are within a few radii of each other along the skeleton.
        Two branches of one junction that stay fused further than that (an acute fork
        whose lumens part many radii on) are still one junction's branches, not a contact
        (:func:`_fused_from_junction`).

    Notes
    -----
    Meant for the resampled skeleton (nodes about a radius apart): each close pair's way is
    searched out to its ``detour`` reach, a few nodes on such a skeleton (BraVa's 13,729
    resampled nodes: 0.9 s) but many on a dense input centerline (the thoracic aorta's
    7,273 raw nodes: 4 s).

    Returns
    -------
    (k, 3) float array: node a, node b (a < b), gap between their walls (negative: the
    lumens overlap); one row per contact, the closest pair of each pair of nearby places.
    """
    from scipy.spatial import cKDTree

    from ..blocks.prep import SkeletonWays

    P = np.asarray(points, float)
    r = np.asarray(radii, float)
    if len(P) < 2:
        return np.zeros((0, 3))
    pairs = cKDTree(P).query_pairs(2.0 * reach * float(r.max()), output_type="ndarray")
    if not len(pairs):
        return np.zeros((0, 3))
    a, b = pairs[:, 0], pairs[:, 1]
    dist = np.linalg.norm(P[a] - P[b], axis=1)
    both = r[a] + r[b]
    close = dist < reach * both
    a, b, dist, both = a[close], b[close], dist[close], both[close]
    E = np.asarray(edges, np.int64)
    way = SkeletonWays(E, P, 0.0)(a, b, detour * both)
    far = way > detour * both
    if far.any():
        far &= ~_fused_from_junction(a, b, E, P, r)
    a, b, gap = a[far], b[far], (dist - both)[far]
    if not len(a):
        return np.zeros((0, 3))
    # one row per contact: the closest pair, then drop pairs within the contact's reach of it
    order = np.argsort(gap)
    kept = []
    for i in order.tolist():
        if all(min(np.linalg.norm(P[a[i]] - P[a[j]]), np.linalg.norm(P[a[i]] - P[b[j]])) > reach * (r[a[j]] + r[b[j]]) * 2.0 for j in kept):
            kept.append(i)
    kept = np.asarray(kept, np.int64)
    return np.c_[np.minimum(a, b)[kept], np.maximum(a, b)[kept], gap[kept]]


def _fused_from_junction(a: np.ndarray, b: np.ndarray, edges: np.ndarray, points: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """Which close node pairs ``(a, b)`` (a < b) are a junction's fused fork: joined to a
    pair of the junction's own first nodes (the junction and its neighbours) by close
    pairs on two branches of that junction, each a step along one segment on either side
    or both.

    Walking back from such a pair towards the junction, the two branches never leave
    contact: their lumens are one from the junction on (daughters a few degrees apart, or
    a junction moved to where the centerlines part while the walls have not), which the
    junction's half-sections take apart; a cut there runs into the junction's blocks.
    Vessels that touch further on, after parting, are a contact whatever their branches,
    and so are a branch curled back onto itself (both nodes on one branch) and the ends of
    branches from two junctions that meet (a loop's broken skeleton).

    Junction nodes joined by a segment shorter than the sum of their radii are one junction
    (their inscribed spheres overlap: one lumen, a branching the skeleton split into two
    nodes), so the daughters of either are that junction's branches. A first node counts
    only when its sphere reaches its junction's (one lumen from the junction to it): the
    touching tips of two short branches, each one long segment from its junction, are a
    contact."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    m, n = len(a), len(points)
    if m == 0 or len(edges) == 0:
        return np.zeros(m, bool)
    deg = np.bincount(edges.ravel(), minlength=n)
    # one id per cluster of junction nodes joined by segments within their spheres
    u0, v0 = edges[:, 0], edges[:, 1]
    near = (deg[u0] >= 3) & (deg[v0] >= 3) & (np.linalg.norm(points[u0] - points[v0], axis=1) < radii[u0] + radii[v0])
    _, cid = connected_components(coo_matrix((np.ones(int(near.sum())), (u0[near], v0[near])), shape=(n, n)), directed=False)
    # branch of each node: the pieces left with the junctions taken out (junctions: -1)
    inner = (deg[edges[:, 0]] < 3) & (deg[edges[:, 1]] < 3)
    e = edges[inner]
    _, branch = connected_components(coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n)), directed=False)
    branch[deg >= 3] = -1
    # each branch's junction ends (up to two)
    ends = np.full((n, 2), -1)
    for u, v in ((edges[:, 0], edges[:, 1]), (edges[:, 1], edges[:, 0])):
        at = (deg[u] >= 3) & (deg[v] < 3)
        for c, l in zip(cid[u[at]].tolist(), branch[v[at]].tolist()):
            ends[l, 0 if ends[l, 0] < 0 or ends[l, 0] == c else 1] = c
    la, lb = branch[a], branch[b]
    ea = np.where(la[:, None] >= 0, ends[np.maximum(la, 0)], cid[a][:, None])  # a junction is its own end
    eb = np.where(lb[:, None] >= 0, ends[np.maximum(lb, 0)], cid[b][:, None])
    shared = ((ea[:, :, None] == eb[:, None, :]) & (ea[:, :, None] >= 0)).any(axis=(1, 2))
    # two branches of one junction, or a junction and one of its branches
    two = (la != lb) & shared
    # each node with its neighbours (itself included): CSR rows
    src = np.r_[np.arange(n), edges[:, 0], edges[:, 1]]
    dst = np.r_[np.arange(n), edges[:, 1], edges[:, 0]]
    o = np.argsort(src * n + dst)
    src, dst = src[o], dst[o]
    start = np.searchsorted(src, np.arange(n + 1))

    def around(x):
        """(row, neighbour) for every neighbour of each x[row], itself included."""
        cnt = start[x + 1] - start[x]
        rows = np.repeat(np.arange(len(x)), cnt)
        offs = np.arange(len(rows)) - np.repeat(np.cumsum(cnt) - cnt, cnt)
        return rows, dst[start[x][rows] + offs]

    key = a * n + b
    order = np.argsort(key)
    skey = key[order]
    ia, na = around(a)
    ib, nb = around(b[ia])  # every (neighbour of a, neighbour of b) of each pair
    i, u, v = ia[ib], na[ib], nb
    ok = u != v
    i, u, v = i[ok], np.minimum(u[ok], v[ok]), np.maximum(u[ok], v[ok])
    pos = np.clip(np.searchsorted(skey, u * n + v), 0, m - 1)
    j = order[pos]
    hit = (skey[pos] == u * n + v) & two[i] & two[j]
    graph = coo_matrix((np.ones(int(hit.sum())), (i[hit], j[hit])), shape=(m, m))
    _, label = connected_components(graph, directed=False)
    # seeds: a junction and a node next to it, or two nodes next to one junction (each
    # node itself or a neighbour in one cluster of junction nodes), each node's sphere
    # reaching its junction's: the lumens are one from the junction to the pair. Two short
    # branches whose ends touch, each one long segment from its junction, are a contact.
    seed = np.zeros(m, bool)

    def keys(x):
        rows, c = around(x)
        ok = (deg[c] >= 3) & ((c == x[rows]) | (np.linalg.norm(points[x[rows]] - points[c], axis=1) < radii[x[rows]] + radii[c]))
        return np.unique(rows[ok] * n + cid[c[ok]])

    seed[np.intersect1d(keys(a), keys(b)) // n] = True
    seed &= two
    return np.isin(label, label[seed])
