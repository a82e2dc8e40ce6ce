"""Building one skeleton graph from polylines: merging coincident points and
overlapping centerlines (moved from :mod:`vmesh.geometry.skeleton_ops`, issue 20)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from .graph import arc_length, _graph_distance, simplify_edges, _true_runs


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
