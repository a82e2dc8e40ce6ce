"""Skeleton kernels: graph structure, merging of overlapping centerlines, cleaning,
resampling and tagging.

Every function is pure: it takes a :class:`~vmesh.skeleton.Skeleton` (or arrays) and
returns new arrays or a new skeleton, never modifying its input. Geometry work is
vectorised over nodes; only graph walks (one step per node, once) are Python loops.

Terminology
-----------
key node
    A node whose degree is not 2 (endpoint, junction or isolated node).
branch
    A path of nodes between two key nodes through degree-2 nodes only (both ends may be
    the same node for a loop). A cycle without any key node is one branch that starts and
    ends at its lowest-numbered node.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components, dijkstra
from scipy.spatial import cKDTree

from ..skeleton import Skeleton

#: Node tags that mark the end of a vessel; they stay on the end node when it moves.
END_TAGS = ("inlet", "outlet")

# ---------------------------------------------------------------------------
# graph structure
# ---------------------------------------------------------------------------


def edge_lengths(points: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """Euclidean length of every edge ``(e,)``."""
    edges = np.asarray(edges, np.int64).reshape(-1, 2)
    return np.linalg.norm(points[edges[:, 1]] - points[edges[:, 0]], axis=1)


def arc_length(points: np.ndarray) -> np.ndarray:
    """Cumulative arc length ``(m,)`` along an ordered polyline ``(m, 3)``, starting at 0."""
    points = np.asarray(points, float)
    if len(points) < 2:
        return np.zeros(len(points))
    return np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))]


def simplify_edges(edges: np.ndarray, edge_tags=None) -> tuple[np.ndarray, list]:
    """Drop self-loops and duplicate edges; tags of duplicates are united.

    Returns
    -------
    edges : (k, 2) int64
        Unique edges ``(min, max)`` in order of first occurrence.
    edge_tags : list of tuple of str
    """
    edges = np.asarray(edges, np.int64).reshape(-1, 2)
    tags = list(edge_tags) if edge_tags is not None and len(edge_tags) else [()] * len(edges)
    loop = edges[:, 0] == edges[:, 1]
    key = np.sort(edges, axis=1)
    key[loop] = -1
    _, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
    inverse = inverse.ravel()
    keep_groups = np.flatnonzero(~loop[first])
    order = keep_groups[np.argsort(first[keep_groups], kind="stable")]
    new_id = np.full(len(first), -1)
    new_id[order] = np.arange(len(order))
    out_tags = [() for _ in order]
    if any(tags):
        for i, g in enumerate(inverse.tolist()):
            j = new_id[g]
            if j >= 0 and tags[i]:
                out_tags[j] = _union(out_tags[j], tags[i])
    return key[first[order]].reshape(-1, 2), out_tags


def _union(a: tuple, b: tuple) -> tuple:
    return tuple(dict.fromkeys((*a, *b)))


def _adjacency_with_edge_ids(n: int, edges: np.ndarray) -> sp.csr_matrix:
    """Symmetric CSR adjacency whose data is ``edge index + 1`` (edges must be simple)."""
    a, b = edges.T
    ids = np.arange(1, len(edges) + 1)
    return sp.csr_matrix((np.r_[ids, ids], (np.r_[a, b], np.r_[b, a])), shape=(n, n))


def branch_paths(n_nodes: int, edges: np.ndarray) -> list[np.ndarray]:
    """Split a simple graph into branches (see the module docstring).

    Parameters
    ----------
    n_nodes : int
    edges : (e, 2) int array, without self-loops or duplicates.

    Returns
    -------
    list of (k,) int64 arrays
        Node sequences; every edge belongs to exactly one branch. Branches starting at a
        key node come first, in order of that node; pure cycles come last and repeat
        their first node at the end.
    """
    edges = np.asarray(edges, np.int64).reshape(-1, 2)
    if len(edges) == 0:
        return []
    deg = np.bincount(edges.ravel(), minlength=n_nodes)
    adj = _adjacency_with_edge_ids(n_nodes, edges)
    indptr = adj.indptr.tolist()
    nbr = adj.indices.tolist()
    eid = (adj.data - 1).tolist()
    degl = deg.tolist()
    used = [False] * len(edges)

    def walk(start: int, k: int) -> np.ndarray:
        path = [start]
        e, cur = eid[k], nbr[k]
        used[e] = True
        path.append(cur)
        while degl[cur] == 2 and cur != start:
            lo = indptr[cur]
            k = lo + 1 if eid[lo] == e else lo
            e = eid[k]
            if used[e]:
                break
            used[e] = True
            cur = nbr[k]
            path.append(cur)
        return np.asarray(path, np.int64)

    paths = []
    for v in np.flatnonzero(deg != 2).tolist():
        for k in range(indptr[v], indptr[v + 1]):
            if not used[eid[k]]:
                paths.append(walk(v, k))
    for e in range(len(edges)):  # what is left are cycles of degree-2 nodes
        if not used[e]:
            v = int(edges[e].min())
            k = next(k for k in range(indptr[v], indptr[v + 1]) if not used[eid[k]])
            paths.append(walk(v, k))
    return paths


def path_edge_ids(n_nodes: int, edges: np.ndarray, paths: list[np.ndarray]) -> list[np.ndarray]:
    """Edge index of every step of every path (``len(path) - 1`` per path)."""
    adj = _adjacency_with_edge_ids(n_nodes, np.asarray(edges, np.int64).reshape(-1, 2))
    out = []
    for p in paths:
        out.append(np.asarray(adj[p[:-1], p[1:]]).ravel().astype(np.int64) - 1)
    return out


def component_labels(n_nodes: int, edges: np.ndarray) -> np.ndarray:
    """Connected-component label of every node."""
    edges = np.asarray(edges, np.int64).reshape(-1, 2)
    a, b = edges.T
    adj = sp.coo_matrix((np.ones(len(a)), (a, b)), shape=(n_nodes, n_nodes))
    return connected_components(adj, directed=False)[1]


def _rebuild(skeleton: Skeleton, points, radii, edges, node_tags, edge_tags) -> Skeleton:
    edges, edge_tags = simplify_edges(edges, edge_tags)
    return Skeleton(points, radii, edges, node_tags, edge_tags, name=skeleton.name)


def contract_nodes(skeleton: Skeleton, group: np.ndarray, positions: np.ndarray | None = None) -> Skeleton:
    """Merge nodes that share a group label; label -1 deletes a node.

    Parameters
    ----------
    skeleton : Skeleton
    group : (n,) int array
        Group of every node. New nodes are numbered in order of the group labels, so
        labelling every group by its smallest member keeps the original order.
    positions : (g, 3) array, optional
        Position of every group (in label order); the mean of the members otherwise.

    Returns
    -------
    Skeleton
        Radius of a group = largest finite member radius; tags = union of the members'.
        Edges inside a group vanish, parallel edges are merged (tags united).
    """
    group = np.asarray(group, np.int64)
    alive = group >= 0
    labels, new = np.unique(group[alive], return_inverse=True)
    new_index = np.full(skeleton.n_nodes, -1, np.int64)
    new_index[alive] = new.ravel()
    g = len(labels)
    idx = np.flatnonzero(alive)
    counts = np.bincount(new_index[idx], minlength=g)
    if positions is None:
        pts = np.zeros((g, 3))
        np.add.at(pts, new_index[idx], skeleton.points[idx])
        pts /= counts[:, None]
    else:
        pts = np.asarray(positions, float).reshape(g, 3)
    rad = np.full(g, -np.inf)
    r = skeleton.radii[idx]
    np.maximum.at(rad, new_index[idx], np.where(np.isfinite(r), r, -np.inf))
    rad[~np.isfinite(rad)] = np.nan
    tags: list = [()] * g
    for i in idx.tolist():
        t = skeleton.node_tags[i]
        if t:
            j = new_index[i]
            tags[j] = _union(tags[j], t)
    e = new_index[skeleton.edges]
    keep = (e >= 0).all(axis=1)
    etags = [t for t, k in zip(skeleton.edge_tags, keep) if k]
    return _rebuild(skeleton, pts, rad, e[keep], tags, etags)


def remove_nodes(skeleton: Skeleton, remove: np.ndarray, bridge: bool = True) -> Skeleton:
    """Delete nodes; optionally bridge the gaps so that paths stay connected.

    A connected run of removed nodes with exactly two surviving neighbours is replaced by
    an edge between them (a dropped stretch of a branch). A run with more than two
    surviving neighbours (a removed junction region) is collapsed into one node instead,
    so the junction survives. Runs with fewer neighbours (a branch end) just vanish.
    """
    remove = np.asarray(remove, bool)
    n = skeleton.n_nodes
    if not remove.any():
        return skeleton.copy()
    group = np.where(remove, -1, np.arange(n))
    extra = np.zeros((0, 2), np.int64)
    if bridge:
        sub = skeleton.edges[remove[skeleton.edges].all(axis=1)]
        label = component_labels(n, sub)  # components among removed nodes (others are singletons)
        a, b = skeleton.edges.T
        cross = remove[a] != remove[b]
        gone = np.where(remove[a], a, b)[cross]
        kept = np.where(remove[a], b, a)[cross]
        pairs = np.unique(np.c_[label[gone], kept], axis=0)
        comp, n_kept = np.unique(pairs[:, 0], return_counts=True)
        two = comp[n_kept == 2]
        if len(two):
            sel = pairs[np.isin(pairs[:, 0], two)]
            extra = sel[:, 1].reshape(-1, 2)  # sorted by component: consecutive pairs
        many = comp[n_kept > 2]
        if len(many):
            in_many = remove & np.isin(label, many)
            idx = np.flatnonzero(in_many)
            # label each collapsed run by its smallest node so node order is kept
            rep = np.full(label.max() + 1, n)
            np.minimum.at(rep, label[idx], idx)
            group[idx] = rep[label[idx]]
    if len(extra):
        skeleton = skeleton.copy(
            edges=np.r_[skeleton.edges, extra], edge_tags=list(skeleton.edge_tags) + [()] * len(extra)
        )
    return contract_nodes(skeleton, group)


def _graph_distance(query: np.ndarray, points: np.ndarray, edges: np.ndarray, tree: cKDTree):
    """Distance from each query point to a polyline graph, and the nearest graph node.

    The nearest node is found with the KD-tree; the distance is the smallest distance to
    that node's incident segments (exact wherever the graph is sampled densely compared
    with the distance, which is the regime this is used in).
    """
    _, near = tree.query(query)
    n = len(points)
    deg = np.bincount(edges.ravel(), minlength=n)
    width = max(int(deg.max()) if len(deg) else 0, 1)
    nb = np.full((n, width), -1, np.int64)
    if len(edges):
        a, b = np.r_[edges[:, 0], edges[:, 1]], np.r_[edges[:, 1], edges[:, 0]]
        order = np.argsort(a, kind="stable")
        a, b = a[order], b[order]
        slot = np.arange(len(a)) - np.searchsorted(a, a)
        nb[a, slot] = b
    start = points[near][:, None, :]  # (m, 1, 3)
    other = nb[near]
    end = points[np.maximum(other, 0)]
    seg = end - start
    rel = query[:, None, :] - start
    t = np.clip((rel * seg).sum(-1) / np.maximum((seg * seg).sum(-1), 1e-300), 0.0, 1.0)
    d = np.linalg.norm(rel - t[..., None] * seg, axis=-1)
    d = np.where(other >= 0, d, np.inf)
    d = np.minimum(d.min(axis=1), np.linalg.norm(query - points[near], axis=1))
    return d, near


def _true_runs(mask: np.ndarray) -> np.ndarray:
    """``(k, 2)`` inclusive index ranges of the runs of True in a boolean array."""
    m = np.r_[False, np.asarray(mask, bool), False].astype(np.int8)
    d = np.diff(m)
    return np.c_[np.flatnonzero(d == 1), np.flatnonzero(d == -1) - 1]


# ---------------------------------------------------------------------------
# building graphs from polylines
# ---------------------------------------------------------------------------


def merge_coincident_points(points: np.ndarray, edges: np.ndarray, tolerance: float) -> tuple[np.ndarray, np.ndarray]:
    """Weld points closer than ``tolerance``; returns the map old -> representative and the
    representatives (first occurrence of every cluster)."""
    points = np.asarray(points, float)
    n = len(points)
    if n == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    pairs = cKDTree(points).query_pairs(tolerance, output_type="ndarray")
    if len(pairs) == 0:
        rep = np.arange(n)
    else:
        adj = sp.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
        label = connected_components(adj, directed=False)[1]
        first = np.full(label.max() + 1, n)
        np.minimum.at(first, label, np.arange(n))
        rep = first[label]
    return rep, np.unique(rep)


def polylines_overlap(lines: list[np.ndarray], radii: list[np.ndarray] | None = None, fraction: float = 0.05) -> bool:
    """Whether some polylines share stretches (VMTK-style centerlines from one inlet to
    every outlet) rather than only touching at their ends.

    A line overlaps another when more than ``fraction`` of its inner points (and at least
    three) lie within 5 % of the radius of a point of another line; without radii, within
    half the line's median point spacing (lines through the same trunk, sampled apart,
    are that close; lines that only meet at a junction part after a point or two).
    """
    if len(lines) < 2:
        return False
    lines = [np.asarray(l, float).reshape(-1, 3) for l in lines]
    allp = np.concatenate(lines)
    scale = float(np.ptp(allp, axis=0).max()) or 1.0
    owner = np.concatenate([np.full(len(l), i) for i, l in enumerate(lines)])
    for i, line in enumerate(lines):
        inner = line[1:-1]
        if len(inner) < 3:
            continue
        if radii is not None and np.isfinite(radii[i][1:-1]).any():
            r = np.nan_to_num(np.asarray(radii[i], float)[1:-1], nan=float(np.nanmedian(radii[i])))
            tol = np.maximum(0.05 * r, 1e-6 * scale)
        else:
            spacing = np.linalg.norm(np.diff(line, axis=0), axis=1)
            tol = np.full(len(inner), max(0.5 * float(np.median(spacing)), 1e-6 * scale))
        d, _ = cKDTree(allp[owner != i]).query(inner)
        close = int((d <= tol).sum())
        if close >= 3 and close > fraction * len(inner):
            return True
    return False


@dataclass
class MergedCenterlines:
    """Result of :func:`merge_overlapping_polylines`.

    Attributes
    ----------
    points, radii : (n, 3), (n,)
    edges : (e, 2) int64
    origin : (n, 2) int64
        ``(line, index in line)`` each node was taken from (to carry point arrays).
    source : int
        Node of the common start of the lines (the inlet), or -1 when they do not share one.
    """

    points: np.ndarray
    radii: np.ndarray
    edges: np.ndarray
    origin: np.ndarray
    source: int


def merge_overlapping_polylines(
    lines: list[np.ndarray], radii: list[np.ndarray], tolerance: float = 0.2, excursion: float = 1.0
) -> MergedCenterlines:
    """Merge centerlines that share their trunks into one tree.

    VMTK writes one polyline from the inlet to every outlet; the lines coincide along the
    common trunk and separate at each bifurcation. Lines are added longest first: the
    points of a new line closer to the tree than ``tolerance`` x radius are dropped (they
    are already there), every stretch that leaves the tree becomes a new branch attached
    to the tree node nearest to where it left (the divergence point is the junction) and,
    if it comes back, to where it re-enters.

    Parameters
    ----------
    lines : list of (m_i, 3) arrays
    radii : list of (m_i,) arrays
        Maximum inscribed sphere radius along each line; NaN where unknown (then twice the
        median point spacing stands in for the radius).
    tolerance : float
        A point belongs to the tree while its distance to it is below ``tolerance`` times
        the tree radius there.
    excursion : float
        A stretch that leaves the tree and comes back without getting farther than
        ``excursion`` x radius is noise, not a loop: it is absorbed.

    Returns
    -------
    MergedCenterlines
    """
    pairs = [(np.asarray(l, float).reshape(-1, 3), np.asarray(r, float).reshape(-1)) for l, r in zip(lines, radii)]
    lines = [l for l, _ in pairs if len(l)]
    radii = [r for l, r in pairs if len(l)]
    if not lines:
        z = np.zeros((0, 3))
        return MergedCenterlines(z, np.zeros(0), np.zeros((0, 2), np.int64), np.zeros((0, 2), np.int64), -1)
    spacing = np.concatenate([np.linalg.norm(np.diff(l, axis=0), axis=1) for l in lines])
    fallback = 2.0 * float(np.median(spacing)) if len(spacing) and np.median(spacing) > 0 else 1.0
    order = sorted(range(len(lines)), key=lambda i: -arc_length(lines[i])[-1])

    first = order[0]
    pts = [lines[first]]
    rad = [radii[first]]
    origin = [np.c_[np.full(len(lines[first]), first), np.arange(len(lines[first]))]]
    m0 = len(lines[first])
    edges = [np.c_[np.arange(m0 - 1), np.arange(1, m0)]]
    n = m0
    for li in order[1:]:
        q, rq = lines[li], radii[li]
        P, E, R = np.concatenate(pts), np.concatenate(edges), np.concatenate(rad)
        d, near = _graph_distance(q, P, E, cKDTree(P))
        scale = np.where(np.isfinite(R[near]) & (R[near] > 0), R[near], fallback)
        rel = d / scale
        m = len(q)
        for a, b in _true_runs(rel > tolerance).tolist():
            inner = a > 0 and b < m - 1
            if inner and rel[a : b + 1].max() < excursion:
                continue
            k = b - a + 1
            ids = np.arange(n, n + k)
            chain = [np.c_[ids[:-1], ids[1:]]]
            if a > 0:
                chain.append([[near[a - 1], ids[0]]])
            if b < m - 1:
                chain.append([[ids[-1], near[b + 1]]])
            pts.append(q[a : b + 1])
            rad.append(rq[a : b + 1])
            origin.append(np.c_[np.full(k, li), np.arange(a, b + 1)])
            edges.append(np.concatenate([np.asarray(c, np.int64).reshape(-1, 2) for c in chain]))
            n += k
    P, R, O = np.concatenate(pts), np.concatenate(rad), np.concatenate(origin)
    E, _ = simplify_edges(np.concatenate(edges))
    starts = np.array([l[0] for l in lines])
    source = -1
    if len(lines) > 1 and np.ptp(starts, axis=0).max() <= 1e-6 * max(float(np.ptp(P, axis=0).max()), 1e-12):
        source = int(np.argmin(np.linalg.norm(P - starts[0], axis=1)))
    elif len(lines) == 1:
        source = 0
    return MergedCenterlines(P, R, E, O.astype(np.int64), source)


# ---------------------------------------------------------------------------
# signed distance helpers
# ---------------------------------------------------------------------------


def distance_gradient(distance, points: np.ndarray, step: np.ndarray | float) -> np.ndarray:
    """Unit gradient of a distance function by central differences (one batched call).

    Parameters
    ----------
    distance : callable (k, 3) -> (k,)
    points : (m, 3)
    step : float or (m,) array
        Difference step per point.
    """
    points = np.asarray(points, float)
    m = len(points)
    h = np.broadcast_to(np.asarray(step, float), (m,))
    offsets = np.eye(3)[None, :, :] * h[:, None, None]  # (m, 3, 3)
    probes = np.concatenate([points[:, None, :] + offsets, points[:, None, :] - offsets], axis=1)
    d = np.asarray(distance(probes.reshape(-1, 3)), float).reshape(m, 6)
    g = (d[:, :3] - d[:, 3:]) / (2.0 * h[:, None])
    norm = np.linalg.norm(g, axis=1, keepdims=True)
    return np.divide(g, norm, out=np.zeros_like(g), where=norm > 0)


def ascend_distance(
    points: np.ndarray,
    target: np.ndarray,
    distance,
    gradient=None,
    iterations: int = 40,
) -> tuple[np.ndarray, np.ndarray]:
    """Move points up a signed distance (positive inside) until it reaches ``target`` or
    stops increasing (the medial ridge).

    Steps follow the gradient, start at half the missing depth and halve whenever a
    step would not increase the distance.

    Parameters
    ----------
    points : (m, 3)
    target : (m,) array
        Wanted distance (e.g. a fraction of the node radius).
    distance : callable (k, 3) -> (k,)
    gradient : callable (k, 3) -> (k, 3), optional
        Gradient of ``distance``; central differences otherwise.

    Returns
    -------
    points : (m, 3)
    distance : (m,) distance at the returned points
    """
    p = np.array(points, float).reshape(-1, 3)
    target = np.broadcast_to(np.asarray(target, float), (len(p),)).copy()
    d = np.asarray(distance(p), float)
    scale = np.maximum(np.abs(target - d), 1e-9)
    step = 0.5 * scale + np.maximum(-d, 0.0)  # at least reach the wall from outside
    active = d < target
    for _ in range(iterations):
        idx = np.flatnonzero(active)
        if len(idx) == 0:
            break
        if gradient is not None:
            g = np.asarray(gradient(p[idx]), float)
            g /= np.maximum(np.linalg.norm(g, axis=1, keepdims=True), 1e-300)
        else:
            g = distance_gradient(distance, p[idx], 1e-2 * scale[idx])
        trial = p[idx] + step[idx, None] * g
        dt = np.asarray(distance(trial), float)
        better = dt > d[idx]
        p[idx[better]] = trial[better]
        d[idx[better]] = dt[better]
        step[idx[~better]] *= 0.5
        active[idx] = (d[idx] < target[idx]) & (step[idx] > 1e-4 * scale[idx])
    return p, d


def estimate_radii(skeleton: Skeleton, distance=None, overwrite: bool = False) -> tuple[Skeleton, int]:
    """Fill missing radii: from the signed distance at each node where one is given, then
    by arc-length interpolation along each branch for whatever is still missing.

    Parameters
    ----------
    skeleton : Skeleton
    distance : callable (k, 3) -> (k,), optional
        Signed distance to the wall, positive inside (the inscribed sphere radius at a
        centerline point). Nodes where it is not positive are left for interpolation.
    overwrite : bool
        Recompute every radius from ``distance``, not only the missing ones.

    Returns
    -------
    skeleton : Skeleton
    n_filled : int
        Number of nodes whose radius changed.
    """
    radii = skeleton.radii.copy()
    todo = np.ones(len(radii), bool) if overwrite else ~(np.isfinite(radii) & (radii > 0))
    if distance is not None and todo.any():
        d = np.asarray(distance(skeleton.points[todo]), float)
        radii[todo] = np.where(d > 0, d, np.nan)
    radii = fill_missing_along_branches(skeleton.n_nodes, skeleton.edges, skeleton.points, radii)
    changed = ~np.isclose(radii, skeleton.radii, equal_nan=True)
    return skeleton.copy(radii=radii), int(changed.sum())


def fill_missing_along_branches(n_nodes: int, edges: np.ndarray, points: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Interpolate NaN node values linearly in arc length along branches; nodes of a
    branch without any value get the median of their connected component (or of all)."""
    values = np.asarray(values, float).copy()
    missing = ~np.isfinite(values)
    if not missing.any() or not (~missing).any():
        return values
    for _ in range(2):  # a second pass reaches branches whose only known values were key nodes filled in pass one
        for path in branch_paths(n_nodes, edges):
            v = values[path]
            bad = ~np.isfinite(v)
            if not bad.any() or bad.all():
                continue
            s = arc_length(points[path])
            v[bad] = np.interp(s[bad], s[~bad], v[~bad])
            values[path] = v
    still = ~np.isfinite(values)
    if still.any():
        label = component_labels(n_nodes, edges)
        for c in np.unique(label[still]):
            known = (label == c) & np.isfinite(values)
            values[(label == c) & still] = np.median(values[known]) if known.any() else np.nanmedian(values)
    return values


def pull_inside(
    skeleton: Skeleton, distance, gradient=None, tolerance: float = 0.02, mode: str = "pull"
) -> tuple[Skeleton, int, int]:
    """Bring back nodes that lie outside the domain (signed distance below
    ``-tolerance`` x radius).

    ``mode="pull"`` walks them up the signed distance towards the medial ridge (towards
    their own radius as depth) and drops those still outside; ``"drop"`` removes them
    straight away. Junctions are never dropped (they are pulled). Removed stretches of a
    branch are bridged so the graph stays connected.

    Returns
    -------
    skeleton : Skeleton
    n_pulled, n_dropped : int
    """
    r = skeleton.radii
    scale = np.where(np.isfinite(r) & (r > 0), r, np.nanmedian(r) if np.isfinite(r).any() else 1.0)
    d = np.asarray(distance(skeleton.points), float)
    outside = d < -tolerance * scale
    if not outside.any():
        return skeleton.copy(), 0, 0
    deg = skeleton.degrees
    points = skeleton.points.copy()
    pull = outside & ((mode == "pull") | (deg >= 3))
    n_pulled = 0
    if pull.any():
        idx = np.flatnonzero(pull)
        new, dn = ascend_distance(points[idx], scale[idx], distance, gradient)
        ok = dn >= 0
        points[idx[ok]] = new[ok]
        n_pulled = int(ok.sum())
        outside[idx[ok]] = False
        # a junction that cannot be brought inside still stays (its branches hang on it)
        outside[idx[~ok & (deg[idx] >= 3)]] = False
    moved = skeleton.copy(points=points)
    n_dropped = int(outside.sum())
    return (remove_nodes(moved, outside) if n_dropped else moved), n_pulled, n_dropped


# ---------------------------------------------------------------------------
# cleaning
# ---------------------------------------------------------------------------


def node_scale(skeleton: Skeleton) -> np.ndarray:
    """Per-node length scale: the radius where it is known, else the median known radius,
    else the median segment length (1 where there is none)."""
    r = skeleton.radii
    good = np.isfinite(r) & (r > 0)
    if good.any():
        fill = float(np.median(r[good]))
    else:
        lengths = edge_lengths(skeleton.points, skeleton.edges)
        fill = float(np.median(lengths)) if len(lengths) and np.median(lengths) > 0 else 1.0
    return np.where(good, r, fill)


def merge_close_junctions(skeleton: Skeleton, tolerance: float = 0.5) -> tuple[Skeleton, int]:
    """Merge junctions joined by a branch shorter than ``tolerance`` x the larger of their
    radii into one junction (at the mean of the merged junctions).

    Skeletonisation often splits one junction of four or more branches into two or three
    junctions a short distance apart, or leaves a tiny loop at a junction; both collapse
    (a loop from a junction back to itself when it stays within the junction's diameter of
    it: the tube around it fills its hole).

    Returns
    -------
    skeleton : Skeleton
    n_merged : int
        Number of junctions that disappeared.
    """
    if tolerance <= 0 or skeleton.n_edges == 0:
        return skeleton.copy(), 0
    deg = skeleton.degrees
    scale = node_scale(skeleton)
    paths = branch_paths(skeleton.n_nodes, skeleton.edges)
    merge_sets = []
    for p in paths:
        a, b = p[0], p[-1]
        if deg[a] < 3 or deg[b] < 3:
            continue
        if a == b:  # a loop narrower than the vessel encloses no wall: a hole of a voxel skeleton
            reach = np.linalg.norm(skeleton.points[p] - skeleton.points[a], axis=1).max()
            if reach < 2 * scale[a]:
                merge_sets.append(p)
            continue
        length = arc_length(skeleton.points[p])[-1]
        if length < tolerance * max(scale[a], scale[b]):
            merge_sets.append(p)
    if not merge_sets:
        return skeleton.copy(), 0
    n = skeleton.n_nodes
    rows = np.concatenate([p[:-1] for p in merge_sets])
    cols = np.concatenate([p[1:] for p in merge_sets])
    adj = sp.coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(n, n))
    _, label = connected_components(adj, directed=False)
    involved = np.zeros(n, bool)
    involved[np.concatenate(merge_sets)] = True
    first = np.full(label.max() + 1, n)
    np.minimum.at(first, label, np.arange(n))
    group = np.where(involved, first[label], np.arange(n))
    # a merged junction sits at the mean of the junctions it replaces
    groups, inverse = np.unique(group, return_inverse=True)
    weight = np.where(deg >= 3, 1.0, 1e-9)
    pos = np.zeros((len(groups), 3))
    np.add.at(pos, inverse, skeleton.points * weight[:, None])
    pos /= np.bincount(inverse, weights=weight)[:, None]
    out = contract_nodes(skeleton, group, pos)
    n_merged = int((deg >= 3).sum() - (out.degrees >= 3).sum())
    return out, max(n_merged, 0)


def _polyline_at(points: np.ndarray, arc: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Points at arc lengths ``s`` (clamped to the ends) of a polyline with arc lengths ``arc``."""
    s = np.clip(s, 0.0, arc[-1])
    k = np.clip(np.searchsorted(arc, s, side="right") - 1, 0, len(arc) - 2)
    t = ((s - arc[k]) / np.maximum(arc[k + 1] - arc[k], 1e-300))[:, None]
    return (1 - t) * points[k] + t * points[k + 1]


def _pair_angle(m: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angle (radians) at ``m`` between the directions to ``a`` and to ``b`` (row-wise)."""
    u, v = a - m, b - m
    cos = (u * v).sum(-1) / np.maximum(np.linalg.norm(u, axis=-1) * np.linalg.norm(v, axis=-1), 1e-300)
    return np.arccos(np.clip(cos, -1.0, 1.0))


def separate_parallel_branches(
    skeleton: Skeleton,
    min_angle: float = 30.0,
    part_angle: float = 60.0,
    ahead: float = 1.0,
    max_shift: float = 4.0,
    distance=None,
) -> tuple[Skeleton, int]:
    """Move junctions whose branches leave nearly parallel downstream, to where they part.

    Centerlines traced from an inlet to every outlet (VMTK, SimVascular) split as soon as
    the paths are a fraction of the radius apart, well before the carina: two daughters
    then leave the junction a few degrees apart and run side by side for a radius or two,
    and the junction's half cross-sections become slivers reaching down to the carina. At
    every junction whose two closest branches make an angle below ``min_angle``
    (directions to the points ``ahead`` x radius along them), the common stretch of those
    two joins the vessel they leave (nodes on the midpoints of the two, matched by arc
    length) and the junction moves to the first midpoint from which the two branches,
    ``ahead`` x radius further on, are ``part_angle`` apart (about where the medial axis
    of the surface branches).

    Parameters
    ----------
    skeleton : Skeleton
    min_angle : float
        Least angle (degrees) between two branches at a junction; 0 moves nothing.
    part_angle : float
        Angle (degrees, at least ``min_angle``) between the two branches seen from the
        moved junction.
    ahead : float
        Where the branch directions are measured (x radius along the branches).
    max_shift : float
        Farthest a junction moves along its branches (x its radius); a junction whose
        branches are not yet ``part_angle`` apart there is left where it is.
    distance : callable, optional
        Signed distance (positive inside): radii of the moved nodes. Without it (or where
        it is not positive), the larger of the two branch radii at each midpoint.

    Returns
    -------
    skeleton : Skeleton
    n_moved : int
        Number of junctions moved.
    """
    if min_angle <= 0 or skeleton.n_edges == 0:
        return skeleton.copy(), 0
    limit, target = np.radians(min_angle), np.radians(max(part_angle, min_angle))
    skel, moved, done = skeleton, 0, set()
    while True:
        scale = node_scale(skel)
        paths = branch_paths(skel.n_nodes, skel.edges)
        job = None
        for c in np.flatnonzero(skel.degrees >= 3).tolist():
            if c in done:
                continue
            done.add(c)  # unless a move below changes it
            out = [p if p[0] == c else p[::-1] for p in paths if (p[0] == c) != (p[-1] == c)]  # loops skipped
            if len(out) < 2:
                continue
            rc = scale[c]
            arcs = [arc_length(skel.points[p]) for p in out]
            tips = np.stack([_polyline_at(skel.points[p], a, np.array([ahead * rc]))[0] for p, a in zip(out, arcs)])
            i, j = np.triu_indices(len(out), 1)
            ang = _pair_angle(skel.points[c], tips[i], tips[j])
            for k in np.argsort(ang).tolist():
                if ang[k] >= limit:
                    break
                pi, ai, pj, aj = out[i[k]], arcs[i[k]], out[j[k]], arcs[j[k]]
                if pi[-1] == pj[-1]:  # two paths between the same nodes: a loop, not a fork
                    continue
                eps = 0.02 * rc
                top = min(max_shift * rc, ai[-1] - ahead * rc, aj[-1] - ahead * rc) - eps
                if top <= 0:
                    continue
                # candidate junctions: midpoints of the two branches, every twentieth of a radius
                s = np.arange(0.05 * rc, top + 1e-12, 0.05 * rc)
                Pi, Pj, Ri, Rj = skel.points[pi], skel.points[pj], scale[pi], scale[pj]
                mid = 0.5 * (_polyline_at(Pi, ai, s) + _polyline_at(Pj, aj, s))
                r = np.maximum(np.interp(s, ai, Ri), np.interp(s, aj, Rj))
                spread = _pair_angle(mid, _polyline_at(Pi, ai, s + ahead * r), _polyline_at(Pj, aj, s + ahead * r))
                wide = np.flatnonzero(spread >= target)
                if len(wide):
                    job = (c, pi, ai, pj, aj, s[wide[0]], mid[wide[0]], r[wide[0]], eps)
                    break
            if job is not None:
                break
        if job is None:
            break
        c, pi, ai, pj, aj, star, at, r_at, eps = job
        # branch i: pi[:ki] before the new junction (moved onto the midpoints), pi[li:] after
        # it, nodes at it dropped; branch j: pj[lj:] after it, the rest but c dropped
        ki = int(np.searchsorted(ai, star - eps, side="left"))
        li = int(np.searchsorted(ai, star + eps, side="right"))
        lj = int(np.searchsorted(aj, star + eps, side="right"))
        n = skel.n_nodes
        scale = node_scale(skel)
        pts = np.r_[skel.points, at[None]]
        rad = np.r_[skel.radii, r_at]
        inner = pi[1:ki]
        pts[inner] = 0.5 * (skel.points[inner] + _polyline_at(skel.points[pj], aj, ai[1:ki]))
        rad[inner] = np.maximum(scale[inner], np.interp(ai[1:ki], aj, scale[pj]))
        if distance is not None:
            ids = np.r_[inner, n]
            depth = np.asarray(distance(pts[ids]), float)
            rad[ids] = np.where(depth > 0, depth, rad[ids])
        tags = list(skel.node_tags) + [tuple(t for t in skel.node_tags[c] if t not in END_TAGS)]
        drop = np.zeros(n + 1, bool)
        drop[pi[ki:li]] = True
        drop[pj[1:lj]] = True
        cut = np.sort([[pi[ki - 1], pi[ki]], [pi[li - 1], pi[li]], [pj[lj - 1], pj[lj]]], axis=1)
        keep = ~(np.sort(skel.edges, axis=1)[:, None, :] == cut[None]).all(-1).any(-1)
        edges = np.r_[skel.edges[keep], [[pi[ki - 1], n], [n, pi[li]], [n, pj[lj]]]]
        etags = [t for t, k in zip(skel.edge_tags, keep) if k] + [()] * 3
        grown = Skeleton(pts, rad, edges, tags, etags, name=skel.name)
        skel = contract_nodes(grown, np.where(drop, -1, np.arange(n + 1)))
        # contract_nodes numbers the kept nodes in order; c is looked at again (it may have
        # more branches), the new junction is not
        new_index = np.cumsum(~drop) - 1
        done = {int(new_index[d]) for d in done if d != c and not drop[d]} | {int(new_index[n])}
        moved += 1
    return skel.copy() if skel is skeleton else skel, moved


def _node_at_foot(skel: Skeleton, seg: int, t: float, scale: np.ndarray) -> tuple[Skeleton, int]:
    """The node where something joins segment ``seg`` at parameter ``t``: an end node of
    the segment within a quarter of its radius (``scale``) of the foot point, else a new
    node splitting the segment there (radius interpolated, tags both ends share)."""
    a, b = (int(x) for x in skel.edges[seg])
    length = np.linalg.norm(skel.points[b] - skel.points[a])
    if t * length <= 0.25 * scale[a]:
        return skel, a
    if (1 - t) * length <= 0.25 * scale[b]:
        return skel, b
    foot = skel.points[a] + t * (skel.points[b] - skel.points[a])
    r = (1 - t) * skel.radii[a] + t * skel.radii[b]
    node = skel.n_nodes
    edges = np.r_[np.delete(skel.edges, seg, axis=0), [[a, node], [node, b]]]
    etags = [x for i, x in enumerate(skel.edge_tags) if i != seg] + [skel.edge_tags[seg]] * 2
    shared = tuple(x for x in skel.node_tags[a] if x in skel.node_tags[b])
    out = Skeleton(np.r_[skel.points, [foot]], np.r_[skel.radii, r], edges, list(skel.node_tags) + [shared], etags, skel.name)
    return out, node


def reconnect_components(skeleton: Skeleton, tolerance: float = 1.0) -> tuple[Skeleton, int]:
    """Reconnect separated pieces: an endpoint (or isolated node) within ``tolerance`` x its
    radius of another component is joined to it, at the foot point on the nearest segment
    (a new node there, unless an end node of that segment is within a quarter radius).

    Pieces are joined one at a time, closest gap first, so two pieces that could each
    join the other are joined once.

    Returns
    -------
    skeleton : Skeleton
    n_joined : int
    """
    if tolerance <= 0:
        return skeleton.copy(), 0
    skel = skeleton.copy()
    joined = 0
    while True:
        label = component_labels(skel.n_nodes, skel.edges)
        if label.max(initial=0) == 0:
            break
        deg = skel.degrees
        scale = node_scale(skel)
        a_seg, b_seg = skel.edges.T
        start, vec = skel.points[a_seg], skel.points[b_seg] - skel.points[a_seg]
        best = None  # (gap, endpoint, segment or -1, foot parameter, node or -1)
        for e in np.flatnonzero(deg <= 1).tolist():
            limit = tolerance * scale[e]
            segs = np.flatnonzero(label[a_seg] != label[e])
            if len(segs):
                rel = skel.points[e] - start[segs]
                t = np.clip((rel * vec[segs]).sum(1) / np.maximum((vec[segs] ** 2).sum(1), 1e-300), 0, 1)
                dist = np.linalg.norm(rel - t[:, None] * vec[segs], axis=1)
                k = int(np.argmin(dist))
                if dist[k] <= limit and (best is None or dist[k] < best[0]):
                    best = (dist[k], e, int(segs[k]), float(t[k]), -1)
            iso = np.flatnonzero((deg == 0) & (label != label[e]))
            if len(iso):
                dist = np.linalg.norm(skel.points[iso] - skel.points[e], axis=1)
                k = int(np.argmin(dist))
                if dist[k] <= limit and (best is None or dist[k] < best[0]):
                    best = (dist[k], e, -1, 0.0, int(iso[k]))
        if best is None:
            break
        _, e, seg, t, node = best
        if seg >= 0:
            skel, node = _node_at_foot(skel, seg, t, scale)
        skel = skel.copy(edges=np.r_[skel.edges, [[e, node]]], edge_tags=list(skel.edge_tags) + [()])
        joined += 1
    return skel, joined


def remove_spurs(
    skeleton: Skeleton, length: float = 1.0, protected: np.ndarray | None = None, shadow: float = 0.5
) -> tuple[Skeleton, int]:
    """Remove short side branches: a branch from an endpoint to a junction shorter than
    ``length`` x the junction radius is a bump on the wall, not a vessel.

    At most ``degree - 2`` spurs (shortest first) go per junction and round, so a short
    bifurcation (two short daughters) keeps one daughter; rounds repeat until nothing
    changes. ``protected`` endpoints (e.g. at caps) are never removed, except a spur of
    any length whose end lies within ``shadow`` x its radius of another branch of its
    junction: it runs inside that branch's lumen (an extracted skeleton's second path
    along one vessel, leaving the junction a few degrees from it) and adds no vessel.

    Returns
    -------
    skeleton : Skeleton
    n_removed : int
        Number of spurs removed.
    """
    from .skeleton.defects import shadowed

    if length <= 0 and shadow <= 0:
        return skeleton.copy(), 0
    skel = skeleton
    prot = np.zeros(skel.n_nodes, bool) if protected is None else np.asarray(protected, bool).copy()
    removed = 0
    while True:
        deg = skel.degrees
        scale = node_scale(skel)
        candidates = []
        paths = branch_paths(skel.n_nodes, skel.edges)
        for p in paths:
            a, b = p[0], p[-1]
            if deg[a] == 1 and deg[b] >= 3:
                end, junction, inner = a, b, p[:-1]
            elif deg[b] == 1 and deg[a] >= 3:
                end, junction, inner = b, a, p[1:]
            else:
                continue
            s = arc_length(skel.points[p])[-1]
            if (s < length * scale[junction] and not prot[end]) or (
                shadow > 0 and shadowed(skel, end, junction, p, paths, scale, shadow)
            ):
                candidates.append((s, junction, inner))
        if not candidates:
            break
        candidates.sort(key=lambda c: c[0])
        budget = {}
        drop = np.zeros(skel.n_nodes, bool)
        for s, j, inner in candidates:
            left = budget.setdefault(j, deg[j] - 2)
            if left > 0:
                drop[inner] = True
                budget[j] = left - 1
                removed += 1
        if not drop.any():
            break
        keep = ~drop
        skel = remove_nodes(skel, drop, bridge=False)
        prot = prot[keep]
    return skel.copy() if skel is skeleton else skel, removed


def trim_at_caps(
    skeleton: Skeleton, centers: np.ndarray, normals: np.ndarray, radii: np.ndarray, slack: float = 1.5
) -> tuple[Skeleton, int]:
    """Cut off what lies beyond the caps: where a segment passes through a cap (crosses
    its plane within ``slack`` x cap radius of its centre) and the part of the skeleton on
    the far side hangs on that segment alone and lies mostly beyond the plane, that part
    is removed and the outer node of the segment moves to the crossing point.

    Centerlines computed on a longer vessel than the surface (the surface was clipped
    afterwards) run out through the open ends; this makes them end there.

    Returns
    -------
    skeleton : Skeleton
    n_cut : int
        Number of pieces cut off.
    """
    centers = np.asarray(centers, float).reshape(-1, 3)
    normals = np.asarray(normals, float).reshape(-1, 3)
    normals = normals / np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-300)
    cap_r = np.asarray(radii, float).reshape(-1)
    skel = skeleton.copy()
    n_cut = 0
    for c in range(len(centers)):
        while True:
            h = (skel.points - centers[c]) @ normals[c]
            out = h > 1e-3 * cap_r[c]  # nodes on the plane (to rounding) are not beyond it
            a, b = skel.edges.T
            cross = out[a] != out[b]
            t = np.clip(h[a] / np.where(cross & (h[a] != h[b]), h[a] - h[b], 1.0), 0.0, 1.0)
            foot = skel.points[a] + t[:, None] * (skel.points[b] - skel.points[a])
            cand = np.flatnonzero(cross & (np.linalg.norm(foot - centers[c], axis=1) <= slack * cap_r[c]))
            done = True
            for e in cand.tolist():
                inner, outer = (a[e], b[e]) if not out[a[e]] else (b[e], a[e])
                rest = np.delete(skel.edges, e, axis=0)
                label = component_labels(skel.n_nodes, rest)
                beyond = np.flatnonzero(label == label[outer])
                if label[inner] == label[outer] or len(beyond) * 2 > skel.n_nodes or out[beyond].mean() < 0.5:
                    continue
                points, rad = skel.points.copy(), skel.radii.copy()
                te = t[e] if outer == b[e] else 1.0 - t[e]
                drop = label == label[outer]
                # the new end: the outer node moved onto the plane, or the inner node if it
                # is (nearly) there already
                end = inner if np.linalg.norm(foot[e] - skel.points[inner]) <= 0.05 * cap_r[c] else outer
                if end == outer:
                    rad[outer] = (1 - te) * skel.radii[inner] + te * skel.radii[outer]
                points[end] = foot[e]
                drop[end] = False
                tags = list(skel.node_tags)
                ends = tuple(x for i in np.flatnonzero(drop).tolist() for x in skel.node_tags[i] if x in END_TAGS)
                tags[end] = _union(tags[end], ends)
                skel = remove_nodes(skel.copy(points=points, radii=rad, node_tags=tags), drop, bridge=False)
                n_cut += 1
                done = False
                break
            if done:
                break
    return skel, n_cut


def match_ends_to_caps(skeleton: Skeleton, centers: np.ndarray, radii: np.ndarray, max_distance: float = 3.0) -> list[tuple[int, int]]:
    """Match caps to skeleton endpoints one to one: optimal assignment on distance / cap
    radius; pairs farther than ``max_distance`` x cap radius stay unmatched.

    Returns
    -------
    list of (endpoint node, cap index)
    """
    from scipy.optimize import linear_sum_assignment

    centers = np.asarray(centers, float).reshape(-1, 3)
    cap_r = np.asarray(radii, float).reshape(-1)
    ends = skeleton.endpoints
    if len(centers) == 0 or len(ends) == 0:
        return []
    cost = np.linalg.norm(skeleton.points[ends][:, None, :] - centers[None], axis=2) / cap_r[None]
    rows, cols = linear_sum_assignment(cost)
    ok = cost[rows, cols] <= max_distance
    return [(int(ends[r]), int(c)) for r, c in zip(rows[ok], cols[ok])]


def extend_to_caps(
    skeleton: Skeleton,
    centers: np.ndarray,
    normals: np.ndarray,
    radii: np.ndarray,
    names: list[str] | None = None,
    mode: str = "center",
    max_distance: float = 3.0,
) -> tuple[Skeleton, np.ndarray]:
    """Make the skeleton end exactly at the caps of the open ends.

    Every cap is matched to one endpoint (optimal assignment on distance / cap radius,
    pairs farther than ``max_distance`` x cap radius stay unmatched). For a matched
    endpoint, nodes beyond the cap plane are trimmed, then the end is brought to the cap
    centre (``mode="center"``) or to where the end direction meets the cap plane
    (``mode="plane"``; the centre when that point is more than half a cap radius
    off-centre): the part of the correction parallel to the cap bends the last two cap
    radii of the branch (weight falling linearly from the end), the part along the cap
    normal extends the branch in a straight line. New nodes keep the skeleton's median
    node spacing, radii blend linearly to the cap radius; the end node is tagged with the
    cap's name (``inlet``/``outlet`` tags move to it).

    Parameters
    ----------
    skeleton : Skeleton
    centers, normals : (c, 3)
        Cap centres and unit normals pointing out of the vessel.
    radii : (c,)
    names : list of str, optional
        Tag added to the end node of each cap.

    Returns
    -------
    skeleton : Skeleton
    matched : (c,) int64
        Node index of the end node of each cap in the returned skeleton, -1 if unmatched.
    """
    centers = np.asarray(centers, float).reshape(-1, 3)
    normals = np.asarray(normals, float).reshape(-1, 3)
    normals = normals / np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-300)
    cap_r = np.asarray(radii, float).reshape(-1)
    n_caps = len(centers)
    ends = skeleton.endpoints
    matched = np.full(n_caps, -1, np.int64)
    if n_caps == 0 or len(ends) == 0:
        return skeleton.copy(), matched
    pairs = match_ends_to_caps(skeleton, centers, cap_r, max_distance)

    pts, rad = list(skeleton.points), list(skeleton.radii)
    ntags = list(skeleton.node_tags)
    edges, etags = [tuple(e) for e in skeleton.edges.tolist()], list(skeleton.edge_tags)
    adj = skeleton.adjacency()
    deg = skeleton.degrees
    scale = node_scale(skeleton)
    lengths = edge_lengths(skeleton.points, skeleton.edges)
    spacing = float(np.median(lengths)) if len(lengths) else 1.0
    end_tags = set(END_TAGS) | set(names or ())
    drop = np.zeros(skeleton.n_nodes, bool)
    end_of_cap = {}
    for end, c in pairs:
        # the branch from the endpoint inwards, up to and including the next key node
        chain, prev, cur = [end], -1, end
        while cur == end or deg[cur] == 2:
            nb = [int(v) for v in adj.indices[adj.indptr[cur] : adj.indptr[cur + 1]] if v != prev]
            if not nb:
                break
            prev, cur = cur, nb[0]
            chain.append(cur)
        chain = np.asarray(chain)
        height = (skeleton.points[chain] - centers[c]) @ normals[c]
        beyond = height > 1e-3 * cap_r[c]  # on the plane to rounding is not beyond
        # trim the run of end nodes past the cap plane, never the branch's other end
        k = min(int(np.argmin(beyond)) if not beyond.all() else len(chain) - 1, len(chain) - 1)
        keep_end = int(chain[k])
        drop[chain[:k]] = True
        rest = chain[k:]
        p_end = skeleton.points[keep_end]
        s = arc_length(skeleton.points[rest])
        back = rest[min(int(np.searchsorted(s, scale[keep_end])), len(rest) - 1)]
        direction = p_end - skeleton.points[back]
        nd = np.linalg.norm(direction)
        target = centers[c]
        if mode == "plane" and nd > 0:
            direction = direction / nd
            cosang = direction @ normals[c]
            if cosang > 0.2:
                hit = p_end + ((centers[c] - p_end) @ normals[c]) / cosang * direction
                if np.linalg.norm(hit - centers[c]) <= 0.5 * cap_r[c]:
                    target = hit
        # the sideways part of the correction bends the last stretch of the branch (no kink,
        # the branch's other end stays put); the part along the normal extends it
        shift = target - p_end
        lateral = shift - (shift @ normals[c]) * normals[c]
        if len(rest) > 1:
            reach = min(2.0 * cap_r[c], s[-1])
            weight = np.clip(1.0 - s / max(reach, 1e-300), 0.0, 1.0)
            weight[-1] = 0.0
            for node, w_ in zip(rest.tolist(), weight.tolist()):
                if w_ > 0:
                    pts[node] = skeleton.points[node] + w_ * lateral
        else:
            pts[keep_end] = p_end + lateral
        p_end = np.asarray(pts[keep_end])
        # end labels (inlet/outlet/cap name), also of trimmed nodes, move to the new end node
        old = ntags[keep_end]
        trimmed = tuple(t for i in chain[:k].tolist() for t in ntags[i] if t in end_tags)
        moved = _union(tuple(t for t in old if t in end_tags), trimmed)
        base = tuple(t for t in old if t not in end_tags)
        end_label = _union(moved, (names[c],) if names else ())
        gap = np.linalg.norm(target - p_end)
        if gap <= 0.5 * spacing:  # too short for a segment of its own: move the end
            pts[keep_end] = target
            ntags[keep_end] = _union(old, end_label)
            end_of_cap[c] = keep_end
            continue
        steps = max(1, int(np.ceil(gap / spacing)))
        f = np.arange(1, steps + 1) / steps
        r0 = skeleton.radii[keep_end]
        new_r = (1 - f) * r0 + f * cap_r[c] if np.isfinite(r0) else np.full(steps, cap_r[c])
        ids = list(range(len(pts), len(pts) + steps))
        pts.extend(p_end + f[:, None] * (target - p_end))
        rad.extend(new_r)
        ntags[keep_end] = base
        ntags.extend([base] * (steps - 1) + [_union(base, end_label)])
        chain_ids = [keep_end] + ids
        edges.extend(zip(chain_ids[:-1], chain_ids[1:]))
        etags.extend([()] * steps)
        end_of_cap[c] = ids[-1]
    out = Skeleton(np.asarray(pts), np.asarray(rad), np.asarray(edges, np.int64).reshape(-1, 2), ntags, etags, skeleton.name)
    full_drop = np.r_[drop, np.zeros(out.n_nodes - skeleton.n_nodes, bool)]
    new_index = np.cumsum(~full_drop) - 1
    for c, node in end_of_cap.items():
        matched[c] = new_index[node]
    if full_drop.any():
        out = remove_nodes(out, full_drop, bridge=False)
    return out, matched


def graft_branches(
    skeleton: Skeleton,
    source: Skeleton,
    centers: np.ndarray,
    radii: np.ndarray,
    names: list[str] | None = None,
    reach: float = 1.0,
    join: float = 0.5,
) -> tuple[Skeleton, list[dict]]:
    """Graft branches of ``source`` onto ``skeleton`` so that it reaches the given caps.

    A centerline that misses a vessel (a VMTK centerline without a line down one open
    end) leaves that vessel without blocks: the wall over its mouth is meshed by the
    blocks of its neighbours and badly. ``source`` is another skeleton of the same vessel
    (extracted from its signed distance) that does reach the cap. For each cap the
    grafted branch is the shortest path in ``source`` from its endpoint nearest the cap
    centre (at most ``reach`` x cap radius away) to the first node within ``join`` x
    radius of ``skeleton`` (distance to its segments; radius the larger of the two
    skeletons' there). That last node is replaced by the foot point on ``skeleton`` (an
    existing node within a quarter radius, else a new node splitting the segment), which
    becomes the junction. Caps are grafted in order, so a later branch may join an
    earlier one.

    Grafted nodes keep the positions and radii of ``source`` and get the tags both end
    nodes of the joined segment carry (end tags excepted); the end node also gets the
    cap's name and ``inlet`` (a cap named ``inlet*`` when no endpoint is tagged ``inlet``
    yet) or ``outlet``.

    Parameters
    ----------
    skeleton, source : Skeleton
    centers : (c, 3)
        Centres of the caps to reach.
    radii : (c,)
        Cap radii.
    names : list of str, optional
        Cap names, for the tags and the report.

    Returns
    -------
    skeleton : Skeleton
    grafts : list of dict
        One per cap: ``cap``, ``nodes`` (added), ``length`` of the branch, ``joined_at``
        (position of the junction), ``gap`` (distance / radius from the last source node
        to ``skeleton``); ``nodes == 0`` and a ``reason`` where nothing was grafted.
    """
    centers = np.asarray(centers, float).reshape(-1, 3)
    cap_r = np.asarray(radii, float).reshape(-1)
    names = list(names) if names is not None else [f"cap_{c}" for c in range(len(centers))]
    end_tags = set(END_TAGS) | set(names)
    src_ends = source.endpoints
    skel = skeleton.copy()
    grafts = []
    if not len(src_ends) or skel.n_edges == 0:
        return skel, [{"cap": n, "nodes": 0, "reason": "no skeleton to graft from or onto"} for n in names]
    w = edge_lengths(source.points, source.edges)
    a, b = source.edges.T
    src_adj = sp.coo_matrix((np.r_[w, w], (np.r_[a, b], np.r_[b, a])), shape=(source.n_nodes,) * 2).tocsr()
    src_r = node_scale(source)
    for c in range(len(centers)):
        gap_to_cap = np.linalg.norm(source.points[src_ends] - centers[c], axis=1)
        if gap_to_cap.min() > reach * cap_r[c]:
            grafts.append({"cap": names[c], "nodes": 0, "reason": "the source skeleton has no end at the cap"})
            continue
        start = int(src_ends[np.argmin(gap_to_cap)])
        scale = node_scale(skel)
        dist, near = _graph_distance(source.points, skel.points, skel.edges, cKDTree(skel.points))
        close = dist <= join * np.maximum(src_r, scale[near])
        along, pred = dijkstra(src_adj, indices=start, return_predecessors=True)
        cand = np.flatnonzero(close & np.isfinite(along))
        if not len(cand):
            grafts.append({"cap": names[c], "nodes": 0, "reason": "the source skeleton does not come near the skeleton"})
            continue
        entry = int(cand[np.argmin(along[cand])])
        path = [entry]
        while path[-1] != start:
            path.append(int(pred[path[-1]]))
        new = np.asarray(path[:0:-1], np.int64)  # from the cap end inwards, without the entry node
        if not len(new):
            grafts.append({"cap": names[c], "nodes": 0, "reason": "the skeleton passes through the cap centre"})
            continue
        # the junction: the foot of the entry node on the nearest segment of the skeleton
        q = source.points[entry]
        p0, vec = skel.points[skel.edges[:, 0]], skel.points[skel.edges[:, 1]] - skel.points[skel.edges[:, 0]]
        t = np.clip(((q - p0) * vec).sum(1) / np.maximum((vec * vec).sum(1), 1e-300), 0.0, 1.0)
        seg = int(np.argmin(np.linalg.norm(q - p0 - t[:, None] * vec, axis=1)))
        e0, e1 = skel.edges[seg]
        base = tuple(x for x in skel.node_tags[e0] if x in skel.node_tags[e1] and x not in end_tags)
        skel, node = _node_at_foot(skel, seg, float(t[seg]), scale)
        has_inlet = any("inlet" in skel.node_tags[i] for i in skel.endpoints.tolist())
        kind = "inlet" if names[c].startswith("inlet") and not has_inlet else "outlet"
        n0 = skel.n_nodes
        chain = np.r_[n0 + np.arange(len(new)), node]
        tags = list(skel.node_tags) + [base] * len(new)
        tags[n0] = _union(base, (kind, names[c]))
        skel = Skeleton(
            np.r_[skel.points, source.points[new]],
            np.r_[skel.radii, source.radii[new]],
            np.r_[skel.edges, np.c_[chain[:-1], chain[1:]]],
            tags,
            list(skel.edge_tags) + [()] * len(new),
            skel.name,
        )
        grafts.append(
            {
                "cap": names[c],
                "nodes": int(len(new)),
                "length": float(arc_length(skel.points[chain])[-1]),
                "joined_at": skel.points[node].tolist(),
                "gap": float(dist[entry] / src_r[entry]),
            }
        )
    return skel, grafts


# ---------------------------------------------------------------------------
# resampling
# ---------------------------------------------------------------------------


def _smooth_along(s: np.ndarray, values: np.ndarray, sigma: float, step: float) -> np.ndarray:
    """Gaussian smoothing of ``values(s)`` with standard deviation ``sigma`` (length units),
    on a uniform grid of ``step``; returned at the original ``s``."""
    if sigma <= 0 or len(s) < 3 or s[-1] <= 0:
        return values.copy()
    from scipy.ndimage import gaussian_filter1d  # imported here: scipy.ndimage is slow to import

    n = int(min(max(np.ceil(s[-1] / step), 2), 20000)) + 1
    grid = np.linspace(0.0, s[-1], n)
    v = gaussian_filter1d(np.interp(grid, s, values), sigma / (grid[1] - grid[0]), mode="nearest")
    return np.interp(s, grid, v)


def radius_features(s: np.ndarray, radius: np.ndarray, threshold: float) -> np.ndarray:
    """Arc-length positions where the radius changes fast along a branch.

    Where ``|dr/ds|`` of the radius (smoothed over a quarter radius) exceeds ``threshold``
    (e.g. 0.25: the radius changes by a quarter of the distance travelled), the start and
    end of that stretch are features, and so is the radius extremum between a falling and
    a rising stretch (the throat of a coarctation, the widest point of a sac). Stretches
    that touch an end of the branch are ignored: there the radius of a junction sphere
    or a cap blends into the vessel's.

    Parameters
    ----------
    s : (m,) increasing arc lengths
    radius : (m,)
    threshold : float

    Returns
    -------
    positions : (k,) sorted arc lengths strictly inside ``(0, s[-1])``
    extremum : (k,) bool
        True for radius extrema (they matter more than the stretch ends).
    """
    if len(s) < 3 or s[-1] <= 0:
        return np.zeros(0), np.zeros(0, bool)
    from scipy.ndimage import gaussian_filter1d

    r_med = float(np.median(radius))
    step = min(0.1 * r_med, s[-1] / 50)
    n = int(min(max(np.ceil(s[-1] / step), 3), 20000)) + 1
    grid = np.linspace(0.0, s[-1], n)
    r = gaussian_filter1d(np.interp(grid, s, radius), 0.25 * r_med / (grid[1] - grid[0]), mode="nearest")
    slope = np.gradient(r, grid)
    fast = np.abs(slope) > threshold
    runs = _true_runs(fast)
    # a change touching a branch end is the junction sphere shrinking to the daughter radius
    # (or a cap), not a feature of the vessel
    runs = runs[(runs[:, 0] > 0) & (runs[:, 1] < n - 1)]
    feats, kind = [], []
    for a, b in runs.tolist():
        feats += [grid[a], grid[b]]
        kind += [False, False]
    for (a0, b0), (a1, b1) in zip(runs[:-1].tolist(), runs[1:].tolist()):
        s0, s1 = np.sign(slope[b0]), np.sign(slope[a1])
        if s0 != s1:
            seg = r[b0 : a1 + 1]
            k = np.argmin(seg) if s0 < 0 else np.argmax(seg)
            feats.append(grid[b0 + k])
            kind.append(True)
    feats, kind = np.asarray(feats, float), np.asarray(kind, bool)
    order = np.lexsort((~kind, feats))
    feats, kind = feats[order], kind[order]
    keep = (feats > 0) & (feats < s[-1])
    keep[1:] &= feats[1:] != feats[:-1]
    return feats[keep], kind[keep]


def resample_skeleton(
    skeleton: Skeleton,
    spacing: float = 1.25,
    radius_change: float | None = None,
    smooth_radii: float = 0.0,
    min_segments: int = 1,
) -> Skeleton:
    """Resample every branch as a curve with node spacing ``spacing`` x local radius.

    Junctions and endpoints are kept as they are. Along a branch, positions and radii are
    interpolated linearly in arc length; the node density is ``1 / (spacing x r(s))``
    with ``r`` smoothed over half a radius (so noisy radii do not make the spacing
    jitter) and the nodes split the integrated density into equal parts. With
    ``radius_change`` set, points where the radius changes fast (see
    :func:`radius_features`) become extra fixed nodes, so the throat of a coarctation and
    the neck of an aneurysm get a node (and a cross-section) of their own.

    Parameters
    ----------
    skeleton : Skeleton
        Radii must be known (see :func:`estimate_radii`).
    spacing : float
        Node spacing in local radii.
    radius_change : float, optional
        Threshold of ``|dr/ds|`` for extra nodes; ``None`` for none.
    smooth_radii : float
        Standard deviation (in local radii) of a Gaussian smoothing of the radii of the
        new inner nodes; 0 keeps the interpolated radii.
    min_segments : int
        Least number of segments per branch (loops get at least 3, parallel branches
        between the same two nodes at least 2, so the graph stays simple).

    Returns
    -------
    Skeleton
        Node tags come from the nearest original node along the branch, segment tags from
        the original segment at the middle of the new one.
    """
    if not np.isfinite(skeleton.radii).all() or (skeleton.radii <= 0).any():
        raise ValueError("every node needs a positive radius before resampling (estimate_radii fills them)")
    n = skeleton.n_nodes
    deg = skeleton.degrees
    paths = branch_paths(n, skeleton.edges)
    path_edges = path_edge_ids(n, skeleton.edges, paths)
    key = deg != 2
    for p in paths:
        if p[0] == p[-1] and not key[p[0]]:
            key[p[0]] = True  # a pure cycle keeps its first node
    key_ids = np.flatnonzero(key)
    new_of_key = np.full(n, -1, np.int64)
    new_of_key[key_ids] = np.arange(len(key_ids))
    pts = [skeleton.points[key_ids]]
    rad = [skeleton.radii[key_ids]]
    ntags = [skeleton.node_tags[i] for i in key_ids.tolist()]
    edges, etags = [], []
    count = len(key_ids)
    has_edge_tags = any(skeleton.edge_tags)
    seen_pairs: set = set()
    for p, pe in zip(paths, path_edges):
        P, R = skeleton.points[p], skeleton.radii[p]
        s = arc_length(P)
        L = s[-1]
        r_med = float(np.median(R))
        r_sm = _smooth_along(s, R, 0.5 * r_med, 0.1 * r_med)
        fixed, extremum = radius_features(s, R, radius_change) if radius_change else (np.zeros(0), np.zeros(0, bool))
        density = 1.0 / (spacing * np.maximum(r_sm, 1e-12))
        tau = np.r_[0.0, np.cumsum(0.5 * (density[1:] + density[:-1]) * np.diff(s))]
        # features closer than half a spacing to each other or to an end are not worth a
        # node; extrema are placed first
        if len(fixed):
            tf = np.interp(fixed, s, tau)
            taken = [0.0, tau[-1]]
            keep = []
            for i in np.r_[np.flatnonzero(extremum), np.flatnonzero(~extremum)].tolist():
                if np.min(np.abs(np.asarray(taken) - tf[i])) >= 0.5:
                    taken.append(tf[i])
                    keep.append(fixed[i])
            fixed = np.sort(np.asarray(keep))
        bounds = np.r_[0.0, fixed, L]
        tb = np.interp(bounds, s, tau)
        counts = np.maximum(np.rint(np.diff(tb)).astype(int), 1)
        pair = (min(p[0], p[-1]), max(p[0], p[-1]))
        least = 3 if p[0] == p[-1] else (2 if pair in seen_pairs else 1)
        least = max(least, min_segments)
        seen_pairs.add(pair)
        while counts.sum() < least:
            counts[np.argmax(np.diff(tb) / counts)] += 1
        new_s = [np.array([0.0])]
        for k in range(len(counts)):
            t = np.linspace(tb[k], tb[k + 1], counts[k] + 1)[1:]
            new_s.append(np.interp(t, tau, s))
        new_s = np.concatenate(new_s)
        new_s[-1] = L
        inner_s = new_s[1:-1]
        m = len(inner_s)
        inner_p = np.stack([np.interp(inner_s, s, P[:, j]) for j in range(3)], axis=1)
        radius_source = _smooth_along(s, R, smooth_radii * r_med, 0.1 * r_med) if smooth_radii > 0 else R
        inner_r = np.interp(inner_s, s, radius_source)
        nearest = np.clip(np.searchsorted(s, inner_s), 1, len(s) - 1)
        nearest -= (inner_s - s[nearest - 1]) < (s[nearest] - inner_s)
        pts.append(inner_p)
        rad.append(inner_r)
        ntags.extend(skeleton.node_tags[p[i]] for i in nearest.tolist())
        ids = np.r_[new_of_key[p[0]], np.arange(count, count + m), new_of_key[p[-1]]]
        count += m
        edges.append(np.c_[ids[:-1], ids[1:]])
        if has_edge_tags:
            mid = 0.5 * (new_s[1:] + new_s[:-1])
            seg = np.clip(np.searchsorted(s, mid) - 1, 0, len(pe) - 1)
            etags.extend(skeleton.edge_tags[pe[i]] for i in seg.tolist())
        else:
            etags.extend([()] * (len(ids) - 1))
    E = np.concatenate(edges) if edges else np.zeros((0, 2), np.int64)
    return Skeleton(np.concatenate(pts), np.concatenate(rad), E, ntags, etags, skeleton.name)


# ---------------------------------------------------------------------------
# tags
# ---------------------------------------------------------------------------


@dataclass
class BranchTree:
    """Branches numbered outwards from a root.

    Attributes
    ----------
    paths : list of (k,) int64 arrays
        Branches, each oriented away from the root, numbered in breadth-first order
        (branch 0 starts at the root).
    parent : (b,) int64
        Branch through which each branch was reached; -1 for the first branch of each
        connected component.
    edge_branch : (e,) int64
        Branch of every edge.
    root : int
        Root node of the first component.
    """

    paths: list
    parent: np.ndarray
    edge_branch: np.ndarray
    root: int


def choose_root(skeleton: Skeleton, nodes: np.ndarray | None = None) -> int:
    """The inlet: an endpoint tagged ``inlet`` if there is one, else the endpoint with the
    largest radius, else the node with the largest radius (among ``nodes`` if given)."""
    cand = np.arange(skeleton.n_nodes) if nodes is None else np.asarray(nodes)
    ends = cand[skeleton.degrees[cand] == 1]
    tagged = [i for i in ends.tolist() if "inlet" in skeleton.node_tags[i]]
    if tagged:
        return tagged[0]
    pool = ends if len(ends) else cand
    r = np.nan_to_num(skeleton.radii[pool], nan=-np.inf)
    return int(pool[np.argmax(r)])


def branch_tree(skeleton: Skeleton, root: int | None = None) -> BranchTree:
    """Number the branches breadth-first from ``root`` (default :func:`choose_root`)."""
    n = skeleton.n_nodes
    paths = branch_paths(n, skeleton.edges)
    path_e = path_edge_ids(n, skeleton.edges, paths)
    at = {}
    for k, p in enumerate(paths):
        at.setdefault(int(p[0]), []).append(k)
        if p[-1] != p[0]:
            at.setdefault(int(p[-1]), []).append(k)
    label = component_labels(n, skeleton.edges)
    order, parent, oriented = [], [], []
    done = np.zeros(len(paths), bool)
    first_root = None
    roots = [] if root is None else [int(root)]
    pending = set(np.unique(label[skeleton.edges.ravel()]).tolist()) if skeleton.n_edges else set()
    while pending:
        if roots:
            r = roots.pop()
        else:
            comp = min(pending)
            r = choose_root(skeleton, np.flatnonzero(label == comp))
        pending.discard(int(label[r]))
        if first_root is None:
            first_root = r
        queue = [(r, -1)]
        while queue:
            v, via = queue.pop(0)
            for k in at.get(v, []):
                if done[k]:
                    continue
                done[k] = True
                p = paths[k] if paths[k][0] == v else paths[k][::-1]
                order.append(k)
                parent.append(via)
                oriented.append(p)
                queue.append((int(p[-1]), len(order) - 1))
    edge_branch = np.full(skeleton.n_edges, -1, np.int64)
    new_id = {k: i for i, k in enumerate(order)}
    for k, pe in enumerate(path_e):
        edge_branch[pe] = new_id[k]
    return BranchTree(oriented, np.asarray(parent, np.int64), edge_branch, -1 if first_root is None else first_root)


def tag_nodes(node_tags: list, mask: np.ndarray, tag: str) -> list:
    """A copy of ``node_tags`` with ``tag`` added where ``mask`` is True."""
    out = list(node_tags)
    for i in np.flatnonzero(mask).tolist():
        if tag not in out[i]:
            out[i] = out[i] + (tag,)
    return out


def nodes_in_sphere(points: np.ndarray, center, radius: float) -> np.ndarray:
    """Mask of the points within ``radius`` of ``center``."""
    return np.linalg.norm(np.asarray(points, float) - np.asarray(center, float), axis=1) <= radius


def sac_nodes(skeleton: Skeleton, ratio: float = 1.5, tree: BranchTree | None = None) -> np.ndarray:
    """Mask of nodes whose radius exceeds ``ratio`` x the median radius of the parent
    branch (of their own branch for root branches): an aneurysm sac grows out of a vessel
    much wider than the vessel it sits on. Junctions are never flagged."""
    tree = tree or branch_tree(skeleton)
    r = skeleton.radii
    med = np.array([np.nanmedian(r[p]) if np.isfinite(r[p]).any() else np.nan for p in tree.paths])
    ref = np.where(tree.parent >= 0, med[np.maximum(tree.parent, 0)], med)
    deg = skeleton.degrees
    mask = np.zeros(skeleton.n_nodes, bool)
    for k, p in enumerate(tree.paths):
        inner = p[deg[p] < 3]
        mask[inner] |= r[inner] > ratio * ref[k]
    return mask


def derive_edge_tags(skeleton: Skeleton, rule: str = "both", only_missing: bool = True) -> list:
    """Segment tags from node tags: the tags both end nodes carry (``"both"``) or either
    carries (``"either"``). With ``only_missing`` a segment that has tags keeps them."""
    a, b = skeleton.edges.T
    out = []
    for k, (i, j) in enumerate(zip(a.tolist(), b.tolist())):
        if only_missing and skeleton.edge_tags[k]:
            out.append(skeleton.edge_tags[k])
            continue
        ti, tj = skeleton.node_tags[i], skeleton.node_tags[j]
        out.append(tuple(t for t in ti if t in tj) if rule == "both" else _union(ti, tj))
    return out
