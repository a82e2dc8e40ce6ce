"""Resampling a skeleton along its branches, spaced by radius, with radius features
kept (moved from :mod:`vmesh.geometry.skeleton_ops`, issue 20)."""

from __future__ import annotations

import numpy as np

from ...skeleton import Skeleton
from .graph import arc_length, branch_paths, path_edge_ids, _true_runs


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


def _branch_stations(s: np.ndarray, R: np.ndarray, r_med: float, spacing: float, radius_change: float, least: int) -> np.ndarray:
    """Arc lengths of the nodes of one resampled branch, ends included (see
    :func:`resample_skeleton`): ``spacing`` x the smoothed radius apart, at least ``least``
    segments, the radius features of :func:`radius_features` kept."""
    L = s[-1]
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
    while counts.sum() < least:
        counts[np.argmax(np.diff(tb) / counts)] += 1
    new_s = [np.array([0.0])]
    for k in range(len(counts)):
        t = np.linspace(tb[k], tb[k + 1], counts[k] + 1)[1:]
        new_s.append(np.interp(t, tau, s))
    new_s = np.concatenate(new_s)
    new_s[-1] = L
    return new_s


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
        r_med = float(np.median(R))
        pair = (min(p[0], p[-1]), max(p[0], p[-1]))
        least = 3 if p[0] == p[-1] else (2 if pair in seen_pairs else 1)
        least = max(least, min_segments)
        seen_pairs.add(pair)
        new_s = _branch_stations(s, R, r_med, spacing, radius_change, least)
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
