"""Probing a signed distance: evaluation in chunks, rays to the wall, gradients,
local maxima and cross-section centres.

Every stage of the skeleton extraction reads the vessel only through these
probes (the SDF is positive inside, in the SDF's unit); they are vectorised over
points, so a stage asks once for all its points instead of once a point.
"""

from __future__ import annotations

from typing import Callable

import numpy as np


#: A signed distance: ``sdf(points (n, 3)) -> (n,)``, positive inside the vessel.
SdfFunction = Callable[[np.ndarray], np.ndarray]



#: The 26 neighbour offsets of a voxel (the order of the bit codes of :mod:`.thin`),
#: also the compass directions of :func:`maximise_sdf`.
_OFFSETS26 = np.array([(a, b, c) for a in (-1, 0, 1) for b in (-1, 0, 1) for c in (-1, 0, 1) if (a, b, c) != (0, 0, 0)])


def evaluate_sdf(sdf: SdfFunction, points: np.ndarray, chunk: int = 1 << 18) -> np.ndarray:
    """Evaluate ``sdf`` on ``points`` (n, 3) in chunks of at most ``chunk`` points.

    Chunking bounds the temporary memory of the SDF backend (closest points,
    face indices) on large grids.
    """
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    out = np.empty(len(points), dtype=np.float64)
    for start in range(0, len(points), chunk):
        block = np.ascontiguousarray(points[start : start + chunk])
        out[start : start + len(block)] = np.asarray(sdf(block), dtype=np.float64).reshape(-1)
    return out



def _arclength(points: np.ndarray) -> np.ndarray:
    """Cumulative arclength ``(n,)`` at the points ``(n, 3)`` of a polyline."""
    return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])



def distance_to_wall(
    sdf: SdfFunction,
    origins: np.ndarray,
    directions: np.ndarray,
    max_length: np.ndarray | float,
    samples: int = 8,
    bisections: int = 6,
) -> np.ndarray:
    """Distance along rays from inside points to the first wall crossing.

    Each ray is sampled at ``samples`` equal steps up to ``max_length``; the first
    sample outside (SDF <= 0) brackets the crossing, which is refined by bisection
    and a final linear interpolation of the SDF.

    Parameters
    ----------
    sdf : callable
        Signed distance, positive inside.
    origins, directions : (n, 3) arrays
        Ray starts (inside the vessel) and unit directions.
    max_length : float or (n,) array
        How far to look along each ray.
    samples, bisections : int
        Sampling and refinement effort.

    Returns
    -------
    (n,) array
        Distance to the crossing; ``inf`` where the ray stays inside up to
        ``max_length``, ``0`` where the origin is already outside.
    """
    origins = np.asarray(origins, float).reshape(-1, 3)
    directions = np.asarray(directions, float).reshape(-1, 3)
    n = len(origins)
    if n == 0:
        return np.zeros(0)
    max_length = np.broadcast_to(np.asarray(max_length, float), (n,))
    steps = np.arange(samples + 1) / samples
    t = max_length[:, None] * steps[None, :]
    d = evaluate_sdf(sdf, (origins[:, None, :] + t[..., None] * directions[:, None, :]).reshape(-1, 3))
    d = d.reshape(n, samples + 1)
    outside = d <= 0
    hit = outside.any(axis=1)
    first = np.argmax(outside, axis=1)
    result = np.full(n, np.inf)
    result[hit & (first == 0)] = 0.0
    rays = np.flatnonzero(hit & (first > 0))
    if len(rays):
        k = first[rays]
        lo, hi = t[rays, k - 1], t[rays, k]
        d_lo, d_hi = d[rays, k - 1], d[rays, k]
        o, u = origins[rays], directions[rays]
        for _ in range(bisections):
            mid = 0.5 * (lo + hi)
            d_mid = evaluate_sdf(sdf, o + mid[:, None] * u)
            inside = d_mid > 0
            lo = np.where(inside, mid, lo)
            d_lo = np.where(inside, d_mid, d_lo)
            hi = np.where(inside, hi, mid)
            d_hi = np.where(inside, d_hi, d_mid)
        frac = np.clip(d_lo / np.maximum(d_lo - d_hi, 1e-300), 0.0, 1.0)
        result[rays] = lo + frac * (hi - lo)
    return result



def sdf_gradient(sdf: SdfFunction, points: np.ndarray, step: np.ndarray | float) -> np.ndarray:
    """Unit gradient of the SDF (pointing into the vessel) by central differences."""
    points = np.asarray(points, float).reshape(-1, 3)
    step = np.broadcast_to(np.asarray(step, float), (len(points),))
    offsets = np.eye(3)[None, :, :] * step[:, None, None]
    probe = np.concatenate([points[:, None, :] + offsets, points[:, None, :] - offsets], axis=1)
    d = evaluate_sdf(sdf, probe.reshape(-1, 3)).reshape(len(points), 2, 3)
    g = d[:, 0] - d[:, 1]
    return g / np.maximum(np.linalg.norm(g, axis=1, keepdims=True), 1e-300)



def plane_basis(normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors spanning the plane orthogonal to each unit normal (n, 3)."""
    normals = np.asarray(normals, float).reshape(-1, 3)
    helper = np.where(np.abs(normals[:, [0]]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    u = np.cross(normals, helper)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    return u, np.cross(normals, u)



def maximise_sdf(sdf: SdfFunction, start: np.ndarray, reach: np.ndarray | float, step: float, iterations: int = 8):
    """Local maximum of the SDF near each start point (compass search).

    Each point tries the 26 neighbouring positions ``step`` away, moves to the
    deepest one, and halves the step when none is deeper; moves are confined to
    a ball of radius ``reach`` around the start.

    Returns
    -------
    points : (n, 3) array
    values : (n,) array
        The SDF at the returned points.
    """
    start = np.asarray(start, float).reshape(-1, 3)
    n = len(start)
    reach = np.broadcast_to(np.asarray(reach, float), (n,))
    points = start.copy()
    values = evaluate_sdf(sdf, points)
    steps = np.full(n, float(step))
    directions = _OFFSETS26 / np.linalg.norm(_OFFSETS26, axis=1, keepdims=True)
    for _ in range(iterations):
        trial = points[:, None, :] + steps[:, None, None] * directions[None, :, :]
        inside = np.linalg.norm(trial - start[:, None, :], axis=2) <= reach[:, None]
        d = evaluate_sdf(sdf, trial.reshape(-1, 3)).reshape(n, -1)
        d = np.where(inside, d, -np.inf)
        best = np.argmax(d, axis=1)
        gain = d[np.arange(n), best] > values
        points = np.where(gain[:, None], trial[np.arange(n), best], points)
        values = np.where(gain, d[np.arange(n), best], values)
        steps = np.where(gain, steps, 0.5 * steps)
    return points, values



# duplicates: a signature shaped like rays.cast_rays (arrays, then numeric options), not the same logic
def center_in_cross_sections(
    sdf: SdfFunction,
    points: np.ndarray,
    tangents: np.ndarray,
    radii: np.ndarray,
    n_chords: int = 4,
    iterations: int = 3,
    max_half_chord: float = 1.6,
) -> tuple[np.ndarray, np.ndarray]:
    """Move points to the centre of the vessel cross-section through them.

    In the plane orthogonal to the tangent, ``n_chords`` chords through the point
    are cast to the wall in both directions. For a circular (or any centrally
    symmetric) section the centre ``c`` satisfies ``(c - p) . u = (t+ - t-) / 2``
    for every chord direction ``u``; the in-plane offset is solved in the
    least-squares sense from all valid chords. Chords whose half-length exceeds
    ``max_half_chord`` x the radius escape into another vessel (near junctions)
    and are ignored; a point keeps its position along directions without valid
    chords.

    Parameters
    ----------
    sdf : callable
        Signed distance, positive inside.
    points, tangents : (n, 3) arrays
        Points near the axis and unit axis directions.
    radii : (n,) array
        Expected vessel radius at each point (sets the search length).
    n_chords, iterations : int
        Chord directions per point and centring passes.
    max_half_chord : float
        Longest accepted half-chord, in radii.

    Returns
    -------
    centres : (n, 3) array
    section_radius : (n,) array
        Mean half-length of the valid chords at the final position (``nan`` where
        no chord was valid).
    """
    points = np.array(points, float).reshape(-1, 3)
    n = len(points)
    if n == 0:
        return points, np.zeros(0)
    tangents = np.asarray(tangents, float).reshape(-1, 3)
    radii = np.asarray(radii, float).reshape(-1)
    e1, e2 = plane_basis(tangents)
    angles = np.pi * np.arange(n_chords) / n_chords
    # chord directions (n, k, 3) and their in-plane coordinates (k, 2)
    cos, sin = np.cos(angles), np.sin(angles)
    dirs = cos[None, :, None] * e1[:, None, :] + sin[None, :, None] * e2[:, None, :]
    plane = np.stack([cos, sin], axis=1)
    reference = radii.copy()
    section = np.full(n, np.nan)
    for _ in range(iterations):
        limit = max_half_chord * reference
        origins = np.repeat(points, 2 * n_chords, axis=0)
        rays = np.concatenate([dirs, -dirs], axis=1).reshape(-1, 3)
        lengths = distance_to_wall(sdf, origins, rays, np.repeat(limit, 2 * n_chords) * 1.05)
        lengths = lengths.reshape(n, 2, n_chords)
        forward, backward = lengths[:, 0], lengths[:, 1]
        valid = (forward <= limit[:, None]) & (backward <= limit[:, None]) & (forward > 0) & (backward > 0)
        offset_along = np.where(valid, 0.5 * (np.where(valid, forward, 0) - np.where(valid, backward, 0)), 0.0)
        # least squares  sum_k valid_k (x . u_k - o_k)^2 + eps |x|^2  (x in-plane, 2 unknowns):
        # directions without a valid chord give no move along them
        w = valid.astype(float)
        normal_matrix = np.einsum("nk,ki,kj->nij", w, plane, plane) + 1e-6 * np.eye(2)
        rhs = np.einsum("nk,nk,ki->ni", w, offset_along, plane)
        x = np.linalg.solve(normal_matrix, rhs[..., None])[..., 0]
        points = points + x[:, [0]] * e1 + x[:, [1]] * e2
        count = valid.sum(axis=1)
        half = np.where(valid, 0.5 * (np.where(valid, forward, 0) + np.where(valid, backward, 0)), 0.0)
        section = np.where(count > 0, half.sum(axis=1) / np.maximum(count, 1), np.nan)
        # an off-axis start underestimates the radius: widen the search with what was seen
        reference = np.fmax(reference, section)
    return points, section

