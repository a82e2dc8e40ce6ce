"""Skeleton graph structure: edge lengths, key-node branches and their edge ids,
connected components, and contracting or removing nodes (moved from
:mod:`vmesh.geometry.skeleton_ops`, issue 20).

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

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from ...skeleton import Skeleton


#: Node tags that mark the end of a vessel; they stay on the end node when it moves.
END_TAGS = ("inlet", "outlet")


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



def vector_angle(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Angle between vectors, row-wise (broadcast over leading axes).

    Parameters
    ----------
    u, v : (..., 3) float
        The vectors (any length but zero).

    Returns
    -------
    ndarray
        The angles in radians, in ``[0, pi]``.
    """
    cos = (u * v).sum(-1) / np.maximum(np.linalg.norm(u, axis=-1) * np.linalg.norm(v, axis=-1), 1e-300)
    return np.arccos(np.clip(cos, -1.0, 1.0))


def polyline_at(points: np.ndarray, arc: np.ndarray, s: np.ndarray, values: np.ndarray | None = None):
    """Points at arc lengths ``s`` (clamped to the ends) of a polyline with node arc lengths
    ``arc``; with per-node ``values``, also those values interpolated linearly there.

    Returns
    -------
    points : (n, 3) ndarray, or ``(points, values)`` when ``values`` is given.
    """
    s = np.clip(s, arc[0], arc[-1])
    k = np.clip(np.searchsorted(arc, s, side="right") - 1, 0, len(arc) - 2)
    t = ((s - arc[k]) / np.maximum(arc[k + 1] - arc[k], 1e-300))[:, None]
    pos = points[k] * (1 - t) + points[k + 1] * t
    if values is None:
        return pos
    w = t.reshape((-1,) + (1,) * (values.ndim - 1))
    return pos, values[k] * (1 - w) + values[k + 1] * w


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


def branches_at(paths: list[np.ndarray], c: int) -> list[np.ndarray]:
    """The branches of ``paths`` (from :func:`branch_paths`) at node ``c``, each oriented
    from ``c``; loops (both ends at ``c``) are skipped.

    Parameters
    ----------
    paths : list of ndarray
        Node paths of the branches.
    c : int
        Node index.

    Returns
    -------
    list of ndarray
        The paths that start or end at ``c`` (not both), reversed where they end at it.
    """
    return [q if int(q[0]) == c else q[::-1] for q in paths if (int(q[0]) == c) != (int(q[-1]) == c)]


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
