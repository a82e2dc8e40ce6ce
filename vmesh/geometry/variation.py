"""Geometric variations of a vessel for parameter studies: scaling the radii about the
centerline.

Scaling every coordinate (``transform_surface``) changes lengths and radii together;
uncertainty and sensitivity studies need the radii varied with the centerline held
fixed. :func:`scale_radii` moves each surface vertex along its offset from the
centerline, so a tube of radius ``r`` becomes one of radius ``s r`` about the same axis,
flat end caps stay in their planes and the skeleton only has its radii scaled.
"""

from __future__ import annotations

import numpy as np

#: Candidate skeleton segments examined per vertex (nearest by segment midpoint).
_CANDIDATES = 16
#: Overshoot fade length of the soft minimum, relative to the distance from the centerline.
_OVERSHOOT_FADE = 0.05
#: Vertices processed per chunk (bounds the (chunk, k, 3) temporaries).
_CHUNK = 1 << 16


def closest_on_segments(points: np.ndarray, a: np.ndarray, b: np.ndarray, lo: np.ndarray, hi: np.ndarray):
    """Closest points of ``points[i]`` on segments ``a[i, k] → b[i, k]``.

    Parameters
    ----------
    points : (n, 3) array
    a, b : (n, k, 3) arrays of segment ends
    lo, hi : (n, k) arrays
        Range of the segment parameter ``t`` (``0, 1`` for a plain segment; a terminal
        segment may extend beyond its free end).

    Returns
    -------
    closest : (n, k, 3) array
    t : (n, k) array of segment parameters
    distance : (n, k) array
    """
    d = b - a
    length2 = np.maximum(np.einsum("nkj,nkj->nk", d, d), 1e-300)
    t = np.einsum("nkj,nkj->nk", points[:, None, :] - a, d) / length2
    t = np.clip(t, lo, hi)
    closest = a + t[..., None] * d
    return closest, t, np.linalg.norm(points[:, None, :] - closest, axis=2)


def scale_radii(vertices: np.ndarray, skeleton_points: np.ndarray, skeleton_radii: np.ndarray, edges: np.ndarray, scale: float, blend: float = 0.2, end_extension: float = 2.0) -> tuple[np.ndarray, dict]:
    """Scale a vessel surface about its centerline.

    Every vertex ``v`` moves to ``c + scale · (v - c)`` where ``c`` is its closest point
    on the skeleton polyline. Near junctions (and on the inside of bends) a vertex is
    about equally close to two segments, where the plain closest point jumps from one
    to the other; the displacement is therefore a soft minimum over the candidate
    segments, ``(scale - 1) Σ w_k P_k (v - c_k)``, with log-weights
    ``-(d_k - d_min) / (blend · d_min) - o_k / (0.05 · d_min)`` (``d_k`` the distance to
    segment ``k``, ``o_k`` how far the vertex's foot lies beyond the segment's end) and
    ``P_k`` the projection perpendicular to segment ``k``. The weights are continuous in
    ``v``, so the scaled surface has no cracks or folds; the overshoot term and the
    projection keep a segment from moving vertices along the axis of its collinear
    neighbour (which would stretch the vessel lengthwise).

    Terminal segments extend past their free end (by ``end_extension`` radii), so a
    vertex of a flat end cap perpendicular to the end segment moves within the cap
    plane and the cap stays where it was.

    Parameters
    ----------
    vertices : (n, 3) array
    skeleton_points : (m, 3) array
    skeleton_radii : (m,) array; NaN where unknown (only sizes the end extensions)
    edges : (e, 2) int array of skeleton segments (at least one)
    scale : float
        Radius factor ``s`` (> 0).
    blend : float
        Width of the blend between segments, relative to the distance from the
        centerline (> 0).
    end_extension : float
        How far terminal segments extend past their free end, in radii of that end.

    Returns
    -------
    vertices : (n, 3) array of the scaled surface
    info : dict with ``max_offset`` (largest vertex distance from the centerline before
        scaling) and ``blended`` (vertices whose centre takes more than 1 % from other
        than its nearest segment)
    """
    from scipy.spatial import cKDTree

    v = np.asarray(vertices, np.float64)
    p = np.asarray(skeleton_points, np.float64)
    e = np.asarray(edges, np.int64).reshape(-1, 2)
    if len(e) == 0:
        raise ValueError("the skeleton has no segments")
    if not blend > 0:
        raise ValueError("blend must be positive")
    r = np.asarray(skeleton_radii, np.float64)

    # terminal ends may extend outwards: t below 0 at a free start, above 1 at a free end
    degree = np.bincount(e.ravel(), minlength=len(p))
    seg_len = np.maximum(np.linalg.norm(p[e[:, 1]] - p[e[:, 0]], axis=1), 1e-300)
    known = np.isfinite(r) & (r > 0)
    r_end = np.where(known, r, np.median(r[known]) if known.any() else np.median(seg_len))
    lo = np.where(degree[e[:, 0]] == 1, -end_extension * r_end[e[:, 0]] / seg_len, 0.0)
    hi = np.where(degree[e[:, 1]] == 1, 1.0 + end_extension * r_end[e[:, 1]] / seg_len, 1.0)
    tiny = 1e-12 * max(float(np.ptp(v, axis=0).max(initial=0.0)), 1e-300)

    k = min(_CANDIDATES, len(e))
    tree = cKDTree(0.5 * (p[e[:, 0]] + p[e[:, 1]]))
    out = np.empty_like(v)
    max_offset, blended = 0.0, 0
    for s in range(0, len(v), _CHUNK):
        chunk = v[s : s + _CHUNK]
        _, cand = tree.query(chunk, k=k, workers=-1)
        cand = cand.reshape(len(chunk), k)
        a, b = p[e[cand, 0]], p[e[cand, 1]]
        d = b - a
        length2 = np.maximum(np.einsum("nkj,nkj->nk", d, d), 1e-300)
        t_free = np.einsum("nkj,nkj->nk", chunk[:, None, :] - a, d) / length2
        closest, t, dist = closest_on_segments(chunk, a, b, lo[cand], hi[cand])
        overshoot = np.abs(t_free - t) * np.sqrt(length2)
        d_min = np.maximum(dist.min(axis=1), tiny)[:, None]
        # log-weights (0 for the best candidate): continuous in the vertex position
        logw = -(dist - d_min) / (blend * d_min) - overshoot / (_OVERSHOOT_FADE * d_min)
        w = np.exp(logw - logw.max(axis=1, keepdims=True))
        w /= w.sum(axis=1, keepdims=True)
        # offsets perpendicular to each segment: exact (radial) for a foot inside the
        # segment; for a foot clamped at a node this drops the along-axis part, so a
        # collinear neighbour adds the same radial offset and nothing moves lengthwise
        offset = chunk[:, None, :] - closest
        u = d / np.sqrt(length2)[..., None]
        offset -= np.einsum("nkj,nkj->nk", offset, u)[..., None] * u
        out[s : s + _CHUNK] = chunk + (scale - 1.0) * np.einsum("nk,nkj->nj", w, offset)
        max_offset = max(max_offset, float(d_min.max(initial=0.0)))
        blended += int(np.count_nonzero(w.max(axis=1) < 0.99))
    return out, {"max_offset": max_offset, "blended": blended}
