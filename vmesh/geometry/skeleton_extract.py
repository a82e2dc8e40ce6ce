"""Extract a centerline skeleton from a signed distance function.

Pipeline (all distances in the SDF's unit, the signed distance positive inside):

1. **Voxelise** the inside of the vessel on a grid whose spacing follows the
   smallest vessel radius (:func:`estimate_min_radius`), evaluating the SDF
   hierarchically: a cell whose centre is farther from the surface than its own
   half-diagonal has one sign throughout (the SDF is 1-Lipschitz), so only cells
   near the wall are refined (:func:`inside_mask`). Memory is one byte per voxel.
2. **Thin** the mask to a one-voxel-wide curve skeleton: distance-ordered
   homotopic thinning (topology preserving: tubes become curves along the ridge
   of the distance, a ring keeps its cycle).
3. **Trace** the voxel skeleton into a graph (:func:`trace_branches`): 26-connected
   voxels, clusters of junction voxels collapsed into one node, chains of
   degree-2 voxels into ordered branches.
4. **Clean** the graph (:class:`BranchGraph`): drop specks, prune spurs that are
   short relative to the radius of the vessel they sprout from, merge junctions
   closer than about a radius (a 5-furcation becomes one degree-5 node), collapse
   tiny cycles made by voxel noise (true cycles are long compared to the radius).
5. **Place the ends**: an end is moved to the centre of the cap it belongs to when
   caps are known, otherwise the branch is extended along its end tangent to the
   surface: to the last full cross-section behind a flat end face
   (:func:`flat_end_sections`), or into a rounded end (an aneurysm dome) down to a
   depth where the inscribed radius is ``end_depth`` x the end radius.
6. **Smooth, resample and centre** every branch: nodes spaced by a multiple of the
   local radius, kept clear of junctions (where the medial axis of a crotch is not
   the vessel axis), moved within their cross-section plane to the centre of the
   section (:func:`center_in_cross_sections`), radius = distance to the wall.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components, dijkstra

from ..skeleton import Skeleton

#: A signed distance: ``sdf(points (n, 3)) -> (n,)``, positive inside the vessel.
SdfFunction = Callable[[np.ndarray], np.ndarray]

#: The 13 "forward" offsets of the 26-neighbourhood (the other 13 are their negatives).
_HALF_NEIGHBOURHOOD = np.array(
    [(a, b, c) for a in (-1, 0, 1) for b in (-1, 0, 1) for c in (-1, 0, 1) if (a, b, c) > (0, 0, 0)],
    dtype=np.int64,
)


def _neighbourhood_tables():
    """Bit tables of the 3x3x3 neighbourhood (26 positions, the centre excluded).

    Returns the offsets (26, 3), the 26-adjacency and the 6-adjacency (within the
    18-neighbourhood) of every position as bit masks, and the masks of the
    18-neighbourhood and of the 6 face neighbours.
    """
    offsets = np.array([(a, b, c) for a in (-1, 0, 1) for b in (-1, 0, 1) for c in (-1, 0, 1) if (a, b, c) != (0, 0, 0)])
    bits = np.left_shift(np.uint32(1), np.arange(26, dtype=np.uint32))
    diff = offsets[:, None, :] - offsets[None, :, :]
    cheb = np.abs(diff).max(axis=2)
    manh = np.abs(diff).sum(axis=2)
    l1 = np.abs(offsets).sum(axis=1)
    in18 = l1 <= 2
    adj26 = np.array([np.bitwise_or.reduce(bits[(cheb[p] == 1)]) for p in range(26)], dtype=np.uint32)
    adj6 = np.array(
        [np.bitwise_or.reduce(bits[(manh[p] == 1) & in18]) if in18[p] else 0 for p in range(26)], dtype=np.uint32
    )
    n18 = np.bitwise_or.reduce(bits[in18])
    faces = np.bitwise_or.reduce(bits[l1 == 1])
    return offsets, adj26, adj6, np.uint32(n18), np.uint32(faces)


_OFFSETS26, _ADJ26, _ADJ6, _N18, _FACES = _neighbourhood_tables()


# ---------------------------------------------------------------------------
# SDF helpers
# ---------------------------------------------------------------------------


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


# ---------------------------------------------------------------------------
# Radius estimate and voxel grid
# ---------------------------------------------------------------------------


def estimate_min_radius(
    sdf: SdfFunction,
    vertices: np.ndarray,
    faces: np.ndarray,
    quantile: float = 0.03,
    max_samples: int = 4000,
    iterations: int = 40,
) -> float:
    """Radius of the thinnest vessels of a surface, from inward chords.

    From the centroid of (a regular subsample of) the faces, a ray is traced into
    the vessel along the face normal (flipped where it points outwards according
    to the SDF) by sphere tracing; half the chord length is the local radius.
    The area-weighted ``quantile`` of these radii is returned: rays from cap rims
    or crotches are longer than a diameter, so they never make the estimate
    smaller than the thinnest vessel.

    Parameters
    ----------
    sdf : callable
        Signed distance, positive inside.
    vertices, faces : arrays
        The (closed) triangle surface.
    quantile : float
        Area fraction of the wall allowed to be thinner than the estimate.
    max_samples : int
        Number of faces sampled.
    iterations : int
        Sphere-tracing steps per ray.

    Returns
    -------
    float
        The radius estimate (``nan`` for an empty surface).
    """
    vertices = np.asarray(vertices, float)
    faces = np.asarray(faces, np.int64)
    if len(faces) == 0:
        return float("nan")
    step = max(1, len(faces) // max_samples)
    tri = vertices[faces[::step]]
    centre = tri.mean(axis=1)
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area = 0.5 * np.linalg.norm(normal, axis=1)
    ok = area > 0
    centre, normal, area = centre[ok], normal[ok] / (2 * area[ok, None]), area[ok]
    size = float(np.linalg.norm(vertices.max(axis=0) - vertices.min(axis=0)))
    eps = 1e-4 * size
    # point the rays inwards: the side where the SDF is positive
    flip = evaluate_sdf(sdf, centre - eps * normal) < evaluate_sdf(sdf, centre + eps * normal)
    inward = np.where(flip[:, None], normal, -normal)
    t = np.full(len(centre), eps)
    active = np.ones(len(centre), bool)
    for _ in range(iterations):
        idx = np.flatnonzero(active)
        if len(idx) == 0:
            break
        d = evaluate_sdf(sdf, centre[idx] + t[idx, None] * inward[idx])
        done = (d < 1e-2 * t[idx]) | (t[idx] > size)
        t[idx] += np.maximum(d, 0.0)
        active[idx[done]] = False
    radius = 0.5 * t
    order = np.argsort(radius)
    cumulative = np.cumsum(area[order]) / area.sum()
    return float(radius[order][np.searchsorted(cumulative, quantile)])


@dataclass(frozen=True)
class VoxelGrid:
    """A regular grid of voxel centres ``origin + spacing * (i, j, k)``."""

    origin: np.ndarray
    spacing: float
    shape: tuple

    @property
    def n_voxels(self) -> int:
        return int(np.prod(self.shape))

    def points(self, ijk: np.ndarray) -> np.ndarray:
        """World coordinates of voxel indices ``(n, 3)``."""
        return self.origin + self.spacing * np.asarray(ijk, float)


def grid_for_bounds(bounds, spacing: float, pad: int = 2, block: int = 8) -> VoxelGrid:
    """Grid covering ``bounds = (lo, hi)`` with ``pad`` voxels of margin; each
    dimension is a multiple of ``block`` (the coarsest cell of :func:`inside_mask`)."""
    lo, hi = (np.asarray(b, float) for b in bounds)
    origin = lo - pad * spacing
    counts = np.ceil((hi + pad * spacing - origin) / spacing).astype(np.int64) + 1
    counts = (counts + block - 1) // block * block
    return VoxelGrid(origin, float(spacing), tuple(int(c) for c in counts))


def inside_mask(
    sdf: SdfFunction,
    grid: VoxelGrid,
    levels: int = 3,
    tolerance: float = 0.05,
    chunk: int = 1 << 18,
    progress: Callable | None = None,
) -> tuple[np.ndarray, int]:
    """Boolean mask of the voxel centres inside the surface (SDF > 0).

    Hierarchical evaluation: cells of ``2**levels`` voxels per side are tested at
    their centre; a cell whose |SDF| exceeds its half-diagonal (plus
    ``tolerance`` x spacing for an approximate SDF) lies on one side of the
    surface and is filled at once, the others are split into 8 children. Only
    cells near the wall reach voxel level, so the number of SDF evaluations grows
    with the surface area, not the volume of the bounding box.

    Returns
    -------
    mask : bool array of ``grid.shape``
    evaluations : int
        Number of SDF evaluations.
    """
    size = 1 << levels
    if any(s % size for s in grid.shape):
        raise ValueError("grid dimensions must be multiples of 2**levels")
    mask = np.zeros(grid.shape, dtype=bool)
    axes = [np.arange(0, s, size, dtype=np.int64) for s in grid.shape]
    cells = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    children = np.array([(a, b, c) for a in (0, 1) for b in (0, 1) for c in (0, 1)], dtype=np.int64)
    evaluations = 0
    level = 0
    while len(cells):
        centre = grid.origin + grid.spacing * (cells + 0.5 * (size - 1))
        d = evaluate_sdf(sdf, centre, chunk)
        evaluations += len(cells)
        if size == 1:
            inside = cells[d > 0]
            mask[inside[:, 0], inside[:, 1], inside[:, 2]] = True
            break
        reach = grid.spacing * (0.5 * math.sqrt(3.0) * (size - 1) + tolerance)
        full = cells[d > reach] // size
        if len(full):
            blocks = mask.reshape(grid.shape[0] // size, size, grid.shape[1] // size, size, grid.shape[2] // size, size)
            blocks[full[:, 0], :, full[:, 1], :, full[:, 2], :] = True
        near = cells[np.abs(d) <= reach]
        size //= 2
        cells = (near[:, None, :] + size * children[None, :, :]).reshape(-1, 3)
        level += 1
        if progress is not None:
            progress(level / (levels + 1), f"voxelising: {evaluations} distance evaluations")
    return mask, evaluations


def fill_cavities(mask: np.ndarray) -> np.ndarray:
    """Fill background regions not connected to the grid border (6-connected)."""
    from scipy import ndimage

    labels, count = ndimage.label(~mask)
    if count <= 1:
        return mask
    border = np.unique(
        np.concatenate(
            [labels[0].ravel(), labels[-1].ravel(), labels[:, 0].ravel(), labels[:, -1].ravel(), labels[:, :, 0].ravel(), labels[:, :, -1].ravel()]
        )
    )
    cavity = ~np.isin(labels, border) & (labels > 0)
    return mask | cavity




def _flood(seed: np.ndarray, allowed: np.ndarray, adjacency: np.ndarray) -> np.ndarray:
    """Bits reachable from ``seed`` within ``allowed`` (vectorised over configurations)."""
    reached = seed & allowed
    for _ in range(26):
        grown = reached.copy()
        for p in range(26):
            grown |= ((reached >> np.uint32(p)) & np.uint32(1)) * adjacency[p]
        grown &= allowed
        if np.array_equal(grown, reached):
            break
        reached = grown
    return reached


def _lowest_bit(x: np.ndarray) -> np.ndarray:
    return x & (~x + np.uint32(1))


def simple_points(codes: np.ndarray) -> np.ndarray:
    """Whether the centre of each 26-neighbourhood configuration is a simple point.

    ``codes`` holds one bit per neighbour (the order of :data:`_OFFSETS26`). A
    point is simple (removable without changing the topology) when its
    foreground neighbours form exactly one 26-component and the background in its
    18-neighbourhood has exactly one 6-component 6-adjacent to it
    (Bertrand & Malandain 1994).
    """
    codes = np.asarray(codes, dtype=np.uint32)
    one_object = (codes != 0) & (_flood(_lowest_bit(codes), codes, _ADJ26) == codes)
    background = ~codes & _N18
    face_background = background & _FACES
    reached = _flood(_lowest_bit(face_background), background, _ADJ6)
    one_hole = (face_background != 0) & ((face_background & ~reached) == 0)
    return one_object & one_hole


def thin_to_curves(mask: np.ndarray, distance: np.ndarray, step: float, keep_end_above: float) -> np.ndarray:
    """Distance-ordered homotopic thinning of a voxel mask to one-voxel-wide curves.

    Voxels are peeled in order of increasing distance to the wall (levels
    ``step`` apart), so what remains runs along the ridge of the distance field.
    A voxel is removed when it is simple and not the end of a curve; to stay
    topology-preserving while working in parallel, each pass removes voxels of
    one of the 8 parity classes ``(i, j, k) mod 2`` only, which are never
    neighbours of each other (removing them together is the same as removing
    them one by one). Curve ends closer to the wall than ``keep_end_above``
    (one-voxel hairs of a rough mask) are not protected.

    Parameters
    ----------
    mask : 3-D bool array
        The object, with at least one voxel of background on every side.
    distance : float array, shape ``(mask.sum(),)``
        Distance to the wall of each object voxel, in ``np.flatnonzero(mask)`` order.
    step : float
        Distance between peeling levels.
    keep_end_above : float
        Curve ends at least this far from the wall are kept.

    Returns
    -------
    bool array like ``mask``
        The curve skeleton: same connected components and cycles as ``mask``.
    """
    shape = mask.shape
    alive = np.ascontiguousarray(mask, dtype=np.uint8).ravel().copy()
    strides = np.array([shape[1] * shape[2], shape[2], 1], dtype=np.int64)
    neighbour_offset = _OFFSETS26 @ strides
    face_offset = np.array([s * d for s in strides for d in (-1, 1)], dtype=np.int64)
    voxels = np.flatnonzero(alive)
    distance = np.asarray(distance, float)
    order = np.argsort(distance, kind="stable")
    voxels, distance = voxels[order], distance[order]
    ijk = np.stack(np.unravel_index(voxels, shape), axis=1)
    parity = (ijk[:, 0] % 2) * 4 + (ijk[:, 1] % 2) * 2 + (ijk[:, 2] % 2)
    bits = np.left_shift(np.uint32(1), np.arange(26, dtype=np.uint32))
    level = distance[0] if len(distance) else 0.0
    top = distance[-1] if len(distance) else 0.0
    pool = np.zeros(0, np.int64)  # indices into ``voxels`` that are alive and reached
    reached = 0
    while True:
        level += step
        upto = int(np.searchsorted(distance, level, side="right"))
        pool = np.concatenate([pool, np.arange(reached, upto)])
        reached = upto
        while True:
            removed = 0
            for cls in range(8):
                cand = pool[parity[pool] == cls]
                if len(cand) == 0:
                    continue
                lin = voxels[cand]
                # only border voxels can be simple
                border = (alive[lin[:, None] + face_offset[None, :]] == 0).any(axis=1)
                cand, lin = cand[border], lin[border]
                if len(cand) == 0:
                    continue
                nb = alive[lin[:, None] + neighbour_offset[None, :]].astype(bool)
                codes = np.bitwise_or.reduce(np.where(nb, bits[None, :], np.uint32(0)), axis=1)
                count = nb.sum(axis=1)
                curve_end = (count == 1) & (distance[cand] >= keep_end_above)
                remove = simple_points(codes) & ~curve_end & (count > 0)
                alive[lin[remove]] = 0
                removed += int(remove.sum())
            pool = pool[alive[voxels[pool]] == 1]
            if removed == 0:
                break
        if reached >= len(voxels) and level > top:
            break
    return alive.reshape(shape).astype(bool)


def voxel_skeleton(mask: np.ndarray, sdf: SdfFunction, grid: "VoxelGrid") -> np.ndarray:
    """Indices ``(k, 3)`` of the curve skeleton of ``mask``.

    The mask is cropped to its bounding box (plus a one-voxel margin), cavities
    are filled (they would leave closed medial surfaces), the SDF is evaluated
    at the inside voxels and the mask is thinned in distance order
    (:func:`thin_to_curves`).

    skimage's Lee thinning is not used: it deletes whole straight branches whose
    section thins to two voxels (scikit-image issue #3757), which happens for
    vessels aligned with the grid.
    """
    occupied = [np.flatnonzero(mask.any(axis=axes)) for axes in ((1, 2), (0, 2), (0, 1))]
    if any(len(o) == 0 for o in occupied):
        return np.zeros((0, 3), np.int64)
    lo = np.array([o[0] for o in occupied])
    hi = np.array([o[-1] for o in occupied]) + 1
    crop = np.zeros(tuple(hi - lo + 2), dtype=bool)
    crop[1:-1, 1:-1, 1:-1] = mask[lo[0] : hi[0], lo[1] : hi[1], lo[2] : hi[2]]
    crop = fill_cavities(crop)
    inside = np.argwhere(crop) + lo - 1  # C order = np.flatnonzero order
    distance = evaluate_sdf(sdf, grid.points(inside))
    thin = thin_to_curves(crop, distance, step=0.5 * grid.spacing, keep_end_above=grid.spacing)
    return np.argwhere(thin).astype(np.int64) + lo - 1


# ---------------------------------------------------------------------------
# Voxel skeleton -> branch graph
# ---------------------------------------------------------------------------


def voxel_adjacency(ijk: np.ndarray) -> sp.csr_matrix:
    """Symmetric 26-neighbourhood adjacency of voxels ``(k, 3)`` (integer indices)."""
    ijk = np.asarray(ijk, np.int64)
    k = len(ijk)
    if k == 0:
        return sp.csr_matrix((0, 0))
    base = ijk.min(axis=0) - 1
    dims = ijk.max(axis=0) - base + 2
    key = np.ravel_multi_index((ijk - base).T, dims)
    order = np.argsort(key)
    sorted_key = key[order]
    rows, cols = [], []
    for off in _HALF_NEIGHBOURHOOD:
        nb = np.ravel_multi_index((ijk - base + off).T, dims)
        pos = np.searchsorted(sorted_key, nb)
        pos = np.minimum(pos, k - 1)
        found = sorted_key[pos] == nb
        rows.append(np.flatnonzero(found))
        cols.append(order[pos[found]])
    r, c = np.concatenate(rows), np.concatenate(cols)
    data = np.ones(2 * len(r), dtype=np.int8)
    return sp.csr_matrix((data, (np.r_[r, c], np.r_[c, r])), shape=(k, k))


@dataclass
class TracedSkeleton:
    """Voxel skeleton split into nodes and branches.

    Attributes
    ----------
    node_voxels : list of int arrays
        Voxels of each node (a junction cluster, an end voxel, or a voxel cut out
        of an isolated cycle).
    branch_ends : (b, 2) int array
        Node at the start and at the end of each branch.
    branch_voxels : list of int arrays
        Interior voxels of each branch, ordered from its start node to its end node
        (may be empty when two nodes touch).
    """

    node_voxels: list
    branch_ends: np.ndarray
    branch_voxels: list


def trace_branches(adjacency: sp.csr_matrix) -> TracedSkeleton:
    """Split a voxel skeleton graph into nodes and ordered branches.

    Voxels with other than two neighbours are node voxels; 26-connected clusters of
    junction voxels (three or more neighbours) form one node (staircase steps and
    thick crossings make such clusters). The remaining chains of two-neighbour
    voxels are the branches. An isolated cycle without any node voxel is cut at
    one voxel. Chains are ordered by a single breadth-first search from a virtual
    source linked to one end of every chain, so no per-voxel Python loop is needed.
    """
    adjacency = sp.csr_matrix(adjacency)
    k = adjacency.shape[0]
    degree = np.diff(adjacency.indptr)
    is_node = degree != 2
    # an isolated cycle has no node voxel: cut it at its first voxel
    n_comp, comp = connected_components(adjacency, directed=False)
    has_node = np.zeros(n_comp, bool)
    has_node[comp[is_node]] = True
    for c in np.flatnonzero(~has_node):
        is_node[np.flatnonzero(comp == c)[0]] = True
    # nodes: clusters of junction voxels; every other node voxel alone
    node_of = np.full(k, -1, np.int64)
    junction = is_node & (degree >= 3)
    jidx = np.flatnonzero(junction)
    n_j, jlab = connected_components(adjacency[jidx][:, jidx], directed=False)
    node_of[jidx] = jlab
    others = np.flatnonzero(is_node & ~junction)
    node_of[others] = n_j + np.arange(len(others))
    n_nodes = n_j + len(others)
    node_voxels = _group(node_of, n_nodes)

    chain = np.flatnonzero(~is_node)
    coo = sp.triu(adjacency, k=1).tocoo()
    a, b = coo.row, coo.col
    # direct node-node contacts between different nodes become empty branches
    both = is_node[a] & is_node[b] & (node_of[a] != node_of[b])
    direct = np.unique(np.sort(np.stack([node_of[a[both]], node_of[b[both]]], axis=1), axis=1), axis=0)
    ends_list = [direct.reshape(-1, 2)]
    voxels_list: list = [np.zeros(0, np.int64)] * len(ends_list[0])
    if len(chain):
        sub = adjacency[chain][:, chain]
        n_chains, chain_of = connected_components(sub, directed=False)
        chain_degree = np.diff(sub.indptr)
        # first end of every chain: its lowest-index voxel with fewer than two chain neighbours
        end_voxel = np.flatnonzero(chain_degree < 2)
        first = np.full(n_chains, -1, np.int64)
        order_end = end_voxel[np.lexsort((end_voxel, chain_of[end_voxel]))]
        starts = np.unique(chain_of[order_end], return_index=True)[1]
        first[chain_of[order_end[starts]]] = order_end[starts]
        # BFS depth from a virtual source attached to every first voxel
        m = len(chain)
        src = sp.csr_matrix((np.ones(n_chains), (np.zeros(n_chains, np.int64), first)), shape=(1, m))
        graph = sp.bmat([[sub, src.T], [src, None]], format="csr")
        depth = dijkstra(graph, directed=False, indices=m, unweighted=True)[:m]
        order = np.lexsort((depth, chain_of))
        bounds = np.searchsorted(chain_of[order], np.arange(n_chains + 1))
        # node neighbours of chain voxels (end voxels only have them)
        node_nb = adjacency[chain].tocoo()
        mask_nb = is_node[node_nb.col]
        rows, nodes_touch = node_nb.row[mask_nb], node_of[node_nb.col[mask_nb]]
        srt = np.lexsort((nodes_touch, rows))
        rows, nodes_touch = rows[srt], nodes_touch[srt]
        row_start = np.searchsorted(rows, np.arange(m + 1))
        for c in range(n_chains):
            seq = order[bounds[c] : bounds[c + 1]]
            f, l = seq[0], seq[-1]
            at_f = nodes_touch[row_start[f] : row_start[f + 1]]
            at_l = nodes_touch[row_start[l] : row_start[l + 1]]
            if f == l:
                if len(at_f) < 2:
                    continue
                u, v = at_f[0], at_f[1]
            else:
                if len(at_f) == 0 or len(at_l) == 0:
                    continue
                u, v = at_f[0], at_l[0]
            ends_list.append(np.array([[u, v]]))
            voxels_list.append(chain[seq])
    branch_ends = np.concatenate(ends_list).astype(np.int64).reshape(-1, 2)
    return TracedSkeleton(node_voxels, branch_ends, voxels_list)


def _group(labels: np.ndarray, n: int) -> list:
    """Indices of ``labels == i`` for i < n (labels < 0 ignored)."""
    idx = np.flatnonzero(labels >= 0)
    order = idx[np.argsort(labels[idx], kind="stable")]
    cuts = np.searchsorted(labels[order], np.arange(n + 1))
    return [order[cuts[i] : cuts[i + 1]] for i in range(n)]


# ---------------------------------------------------------------------------
# Branch graph cleaning
# ---------------------------------------------------------------------------


class BranchGraph:
    """A skeleton under cleaning: nodes with a position and radius, branches with a
    medial polyline (interior points and their radii, ordered from the branch's
    ``start`` node).

    A ``networkx.MultiGraph`` holds the topology (branches may be parallel or
    loops); its size is the number of branches, not of voxels.
    """

    def __init__(self):
        import networkx as nx

        self.graph = nx.MultiGraph()
        self._next_node = 0

    # -- construction --------------------------------------------------------
    def add_node(self, position, radius, **attributes) -> int:
        node = self._next_node
        self._next_node += 1
        self.graph.add_node(node, pos=np.asarray(position, float), r=float(radius), **attributes)
        return node

    def add_branch(self, u: int, v: int, points=None, radii=None) -> int:
        points = np.zeros((0, 3)) if points is None else np.asarray(points, float).reshape(-1, 3)
        radii = np.zeros(0) if radii is None else np.asarray(radii, float).reshape(-1)
        return self.graph.add_edge(u, v, start=u, pts=points, rad=radii)

    # -- queries --------------------------------------------------------------
    def pos(self, node: int) -> np.ndarray:
        return self.graph.nodes[node]["pos"]

    def radius(self, node: int) -> float:
        return self.graph.nodes[node]["r"]

    def degree(self, node: int) -> int:
        return self.graph.degree(node)

    def branches(self):
        """``(u, v, key)`` of every branch."""
        return list(self.graph.edges(keys=True))

    def polyline(self, u: int, v: int, key: int, start: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Points (with both end nodes) and radii of a branch, oriented from ``start``."""
        data = self.graph.edges[u, v, key]
        a = data["start"]
        b = v if a == u else u
        pts = np.concatenate([self.pos(a)[None], data["pts"], self.pos(b)[None]])
        rad = np.concatenate([[self.radius(a)], data["rad"], [self.radius(b)]])
        if start is not None and start != a:
            return pts[::-1].copy(), rad[::-1].copy()
        return pts, rad

    def length(self, u: int, v: int, key: int) -> float:
        pts, _ = self.polyline(u, v, key)
        return float(np.linalg.norm(np.diff(pts, axis=0), axis=1).sum())

    def other(self, u: int, v: int, node: int) -> int:
        return v if node == u else u

    # -- edits ----------------------------------------------------------------
    def contract(self, keep: int, drop: int) -> None:
        """Merge node ``drop`` into ``keep``; its branches are re-attached to ``keep``
        (a branch between the two becomes a loop at ``keep``)."""
        g = self.graph
        for u, v, key, data in list(g.edges(drop, keys=True, data=True)):
            far = self.other(u, v, drop)
            target = keep if far == drop else far
            start = keep if data["start"] == drop else data["start"]
            g.add_edge(keep, target, start=start, pts=data["pts"], rad=data["rad"])
        g.remove_node(drop)

    def dissolve(self, node: int) -> bool:
        """Join the two branches of a degree-2 node (not a loop) into one."""
        g = self.graph
        incident = list(g.edges(node, keys=True))
        if g.degree(node) != 2 or len(incident) != 2:  # a lone loop also has degree 2
            return False
        (a, b, k1), (c, d, k2) = incident
        x, y = self.other(a, b, node), self.other(c, d, node)
        if x == node or y == node:
            return False
        p1, r1 = self.polyline(a, b, k1, start=x)
        p2, r2 = self.polyline(c, d, k2, start=node)
        g.remove_edge(a, b, k1)
        g.remove_edge(c, d, k2)
        g.remove_node(node)
        g.add_edge(x, y, start=x, pts=np.concatenate([p1[1:], p2[1:-1]]), rad=np.concatenate([r1[1:], r2[1:-1]]))
        return True

    def dissolve_all(self) -> None:
        for node in [n for n in self.graph.nodes if self.graph.degree(n) == 2]:
            if node in self.graph:
                self.dissolve(node)

    def split(self, u: int, v: int, key: int, index: int) -> int:
        """Insert a node at interior point ``index`` of a branch; returns the new node."""
        data = self.graph.edges[u, v, key]
        a = data["start"]
        b = self.other(u, v, a)
        pts, rad = data["pts"], data["rad"]
        node = self.add_node(pts[index], rad[index])
        self.graph.remove_edge(u, v, key)
        self.add_branch(a, node, pts[:index], rad[:index])
        self.add_branch(node, b, pts[index + 1 :], rad[index + 1 :])
        return node

    # -- cleaning -------------------------------------------------------------
    def drop_small_components(self, ratio: float) -> int:
        """Remove components whose total branch length is below ``ratio`` x their
        largest radius (specks of the voxel mask); the largest component stays."""
        import networkx as nx

        comps = [list(c) for c in nx.connected_components(self.graph)]
        if len(comps) <= 1:
            return 0
        sizes = []
        for c in comps:
            sub = self.graph.subgraph(c)
            total = sum(self.length(u, v, k) for u, v, k in sub.edges(keys=True))
            rmax = max(self.radius(n) for n in c)
            sizes.append((total, rmax))
        largest = int(np.argmax([s[0] for s in sizes]))
        removed = 0
        for i, (c, (total, rmax)) in enumerate(zip(comps, sizes)):
            if i != largest and total < ratio * rmax:
                self.graph.remove_nodes_from(c)
                removed += 1
        return removed

    def prune_spurs(self, ratio: float) -> int:
        """Remove terminal branches that barely stick out of the vessel they leave.

        A terminal branch from junction ``j`` to tip ``t`` is a spur when
        ``(|t - j| + r_t) / r_j < ratio``: the tip's inscribed ball hardly leaves
        the junction's ball (surface noise, the rim of a flat end). Up to
        ``1.5 x ratio`` it is also a spur unless it ends in a bulb (its radius
        grows again after a neck, as into an aneurysm sac): a branch whose radius
        only shrinks towards a tip that close leaks into a wide saddle (between
        two branches leaving a wide vessel) or a bulge. A real side branch reaches
        well beyond. The least salient spurs go first; a junction keeps at least
        one branch.
        """
        removed = 0
        while True:
            candidates = []
            for u, v, k in self.branches():
                du, dv = self.degree(u), self.degree(v)
                if u == v or min(du, dv) != 1 or max(du, dv) < 3:
                    continue
                tip, base = (u, v) if du == 1 else (v, u)
                reach = float(np.linalg.norm(self.pos(tip) - self.pos(base))) + self.radius(tip)
                score = reach / max(self.radius(base), 1e-12)
                if score >= 1.5 * ratio or (score >= ratio and self.ends_in_bulb(u, v, k, base)):
                    continue
                candidates.append((score, u, v, k, tip, base))
            if not candidates:
                return removed
            candidates.sort(key=lambda c: c[0])
            touched = set()
            for _, u, v, k, tip, base in candidates:
                if base in touched or not self.graph.has_edge(u, v, k) or self.degree(base) < 3:
                    continue
                self.graph.remove_edge(u, v, k)
                self.graph.remove_node(tip)
                touched.add(base)
                removed += 1
            for node in touched:
                if node in self.graph and self.degree(node) == 2:
                    self.dissolve(node)

    def ends_in_bulb(self, u: int, v: int, key: int, base: int, rise: float = 1.15) -> bool:
        """Whether the radius along a branch grows again by ``rise`` after a neck."""
        _, rad = self.polyline(u, v, key, start=base)
        inner = rad[1:]
        if len(inner) < 2:
            return False
        ahead = np.maximum.accumulate(inner[::-1])[::-1]  # largest radius from here to the tip
        return bool(np.max(ahead / np.maximum(inner, 1e-12)) >= rise)

    def axis_line(self, node: int, u: int, v: int, key: int, near: float, far: float):
        """Line (point, unit direction) fitted to a branch between arclengths
        ``near`` and ``far`` from ``node``; ``None`` when the branch is too short."""
        pts, _ = self.polyline(u, v, key, start=node)
        s = _arclength(pts)
        sel = pts[(s >= near) & (s <= far)]
        if len(sel) < 3:
            return None
        centre = sel.mean(axis=0)
        direction = np.linalg.svd(sel - centre, full_matrices=False)[2][0]
        return centre, direction

    def junction_centre(self, node: int, exclude=None) -> np.ndarray:
        """Where the axes of a junction's branches meet (least squares).

        Each branch's axis is fitted beyond the crotch (1.5 to 3.5 junction radii
        away), where the medial axis follows the vessel; the point closest to all
        these lines is the junction centre. The node position is returned when
        fewer than two branches are long enough or the lines meet far away.
        """
        r = self.radius(node)
        x0 = self.pos(node)
        lines = []
        for u, v, k in self.graph.edges(node, keys=True):
            if u == v or (exclude is not None and (u, v, k) in (exclude, (exclude[1], exclude[0], exclude[2]))):
                continue
            line = self.axis_line(node, u, v, k, 1.5 * r, 3.5 * r)
            if line is not None:
                lines.append(line)
        if len(lines) < 2:
            return x0
        a = 1e-3 * len(lines) * np.eye(3)
        b = a @ x0
        for c, d in lines:
            m = np.eye(3) - np.outer(d, d)
            a = a + m
            b = b + m @ c
        x = np.linalg.solve(a, b)
        return x if np.linalg.norm(x - x0) <= 1.5 * r else x0

    def merge_junctions(self, ratio: float) -> int:
        """Merge junctions whose centres are closer than ``ratio`` x the larger radius.

        Thinning splits one furcation into several junctions joined by short
        branches, spread over the crotch; two separate bifurcations a few radii
        apart look alike. The junction centres (where the branch axes meet,
        :meth:`junction_centre`) tell them apart: they coincide for one
        furcation and stay apart for two. The merged node keeps the larger
        inscribed ball.
        """
        merged = 0
        while True:
            best = None
            for u, v, k in self.branches():
                if u == v or self.degree(u) < 3 or self.degree(v) < 3:
                    continue
                rmax = max(self.radius(u), self.radius(v))
                if self.length(u, v, k) > 3.0 * rmax:
                    continue
                gap = float(np.linalg.norm(self.junction_centre(u, (u, v, k)) - self.junction_centre(v, (u, v, k))))
                if gap < ratio * rmax and (best is None or gap / rmax < best[0]):
                    best = (gap / rmax, u, v, k)
            if best is None:
                return merged
            _, u, v, k = best
            keep, drop = (u, v) if self.radius(u) >= self.radius(v) else (v, u)
            self.graph.remove_edge(u, v, k)
            self.contract(keep, drop)
            merged += 1
            self.dissolve_all()

    def center_junctions(self, sdf: SdfFunction, spacing: float, max_shift: float = 0.75, search: float = 0.35) -> int:
        """Place every junction where its branch axes meet, on the ridge of the SDF.

        The start is :meth:`junction_centre` when it is less than ``max_shift``
        junction radii from the node and nearly as deep; from there the SDF is
        maximised within ``search`` junction radii (:func:`maximise_sdf`), which
        puts the node on the vessel axes with sub-voxel accuracy while the axis
        lines fix its place along a vessel that runs straight through. Returns
        the number of junctions.
        """
        nodes = [n for n in self.graph.nodes if self.degree(n) >= 3]
        if not nodes:
            return 0
        old = np.array([self.pos(n) for n in nodes])
        radius = np.array([self.radius(n) for n in nodes])
        centres = np.array([self.junction_centre(n) for n in nodes])
        depth = evaluate_sdf(sdf, centres)
        shift = np.linalg.norm(centres - old, axis=1)
        use = (depth >= 0.8 * radius) & (shift <= max_shift * radius)
        start = np.where(use[:, None], centres, old)
        best, value = maximise_sdf(sdf, start, search * radius, 0.5 * spacing)
        for n, p, d in zip(nodes, best, value):
            self.graph.nodes[n]["pos"] = p
            self.graph.nodes[n]["r"] = float(d)
        return len(nodes)

    def n_cycles(self) -> int:
        import networkx as nx

        g = self.graph
        return g.number_of_edges() - g.number_of_nodes() + nx.number_connected_components(g)

    def bottleneck(self, u: int, v: int, key: int) -> float:
        """Smallest radius along a branch (its narrowest passage)."""
        _, rad = self.polyline(u, v, key)
        return float(rad[1:-1].min()) if len(rad) > 2 else float(rad.min())

    def break_extra_cycles(self, keep: int) -> int:
        """Cut cycles until ``keep`` independent ones are left (the genus of the surface).

        Where two vessels run closer than a voxel (the saddle of a narrow crotch,
        two touching vessels) the voxel mask bridges them and thinning turns the
        bridge into a cycle the vessel does not have. Of the branches on cycles,
        the one with the narrowest passage (smallest radius along it) is such a
        bridge and is removed, one at a time.
        """
        import networkx as nx

        removed = 0
        while self.n_cycles() > keep:
            g = self.graph
            simple = nx.Graph(g)
            bridges = {frozenset(e) for e in nx.bridges(simple)} if simple.number_of_edges() else set()
            parallel = {frozenset((u, v)) for u, v in g.edges() if g.number_of_edges(u, v) > 1}
            on_cycle = [
                (self.bottleneck(u, v, k), u, v, k)
                for u, v, k in g.edges(keys=True)
                if u == v or frozenset((u, v)) in parallel or frozenset((u, v)) not in bridges
            ]
            if not on_cycle:
                break
            _, u, v, k = min(on_cycle)
            g.remove_edge(u, v, k)
            removed += 1
            for node in (u, v):
                if node in g and g.degree(node) == 0:
                    g.remove_node(node)
            self.dissolve_all()
        return removed

    def collapse_small_cycles(self, ratio: float) -> int:
        """Collapse cycles shorter than ``ratio`` x their largest radius into one node.

        Cycles are the fundamental cycles of a minimum spanning tree (by branch
        length): every branch outside the tree closes one; voxel noise makes short
        ones around junctions, a true vascular ring is many radii long.
        """
        import networkx as nx

        collapsed = 0
        while True:
            g = self.graph
            weighted = nx.MultiGraph()
            weighted.add_nodes_from(g.nodes)
            for u, v, k in g.edges(keys=True):
                weighted.add_edge(u, v, key=k, length=self.length(u, v, k))
            tree = nx.minimum_spanning_tree(weighted, weight="length")
            in_tree = {(min(u, v), max(u, v), k) for u, v, k in tree.edges(keys=True)}
            found = None
            for u, v, k, data in weighted.edges(keys=True, data=True):
                if (min(u, v), max(u, v), k) in in_tree:
                    continue
                path = nx.shortest_path(tree, u, v, weight="length")
                cycle_length = data["length"] + nx.path_weight(tree, path, weight="length") if len(path) > 1 else data["length"]
                rmax = max(self.radius(n) for n in path)
                if cycle_length < ratio * rmax and (found is None or cycle_length < found[0]):
                    found = (cycle_length, u, v, k, path)
            if found is None:
                return collapsed
            _, u, v, k, path = found
            g.remove_edge(u, v, k)
            keep = max(path, key=self.radius)
            for node in path:
                if node != keep:
                    self.contract(keep, node)
            # branches left between merged nodes are now loops at ``keep``
            for a, b, key in [(a, b, key) for a, b, key in g.edges(keep, keys=True) if a == b]:
                if self.length(a, b, key) < ratio * self.radius(keep):
                    g.remove_edge(a, b, key)
            collapsed += 1
            self.dissolve_all()


def build_branch_graph(traced: TracedSkeleton, points: np.ndarray, radii: np.ndarray) -> BranchGraph:
    """A :class:`BranchGraph` from a traced voxel skeleton.

    ``points`` and ``radii`` are the world positions and SDF values of the voxels.
    A junction cluster is represented by its voxel of largest radius (the centre of
    the largest inscribed ball).
    """
    graph = BranchGraph()
    ids = []
    for voxels in traced.node_voxels:
        best = voxels[np.argmax(radii[voxels])]
        ids.append(graph.add_node(points[best], radii[best]))
    for (u, v), voxels in zip(traced.branch_ends, traced.branch_voxels):
        graph.add_branch(ids[u], ids[v], points[voxels], radii[voxels])
    return graph


# ---------------------------------------------------------------------------
# Ends: caps, flat ends, rounded ends
# ---------------------------------------------------------------------------


def _end_tangent(pts: np.ndarray, window: float) -> np.ndarray:
    """Unit direction of the last ``window`` of arclength (principal axis of its points,
    pointing towards the last point); a hook of a few voxels at the very end barely
    turns it."""
    seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    from_end = np.concatenate([np.cumsum(seg[::-1])[::-1], [0.0]])
    near = pts[from_end <= max(window, 1e-12)]
    if len(near) < 3:
        near = pts[-3:]
    centre = near.mean(axis=0)
    direction = np.linalg.svd(near - centre, full_matrices=False)[2][0] if len(near) >= 2 else np.zeros(3)
    if direction @ (near[-1] - near[0]) < 0:
        direction = -direction
    norm = np.linalg.norm(direction)
    return direction / norm if norm > 0 else np.array([1.0, 0.0, 0.0])


def _straight(a: np.ndarray, b: np.ndarray, step: float) -> np.ndarray:
    """Points strictly between ``a`` and ``b``, at most ``step`` apart."""
    n = int(np.ceil(np.linalg.norm(b - a) / max(step, 1e-12)))
    t = np.arange(1, n)[:, None] / max(n, 1)
    return a + t * (b - a)


def _match_caps(ends: np.ndarray, end_radii: np.ndarray, caps) -> dict:
    """Greedy one-to-one matching of skeleton ends to caps, nearest first.

    An end matches a cap when it lies inside the vessel behind the cap (depth up
    to a few cap radii along the inward normal) and within a cap radius of its axis.
    """
    pairs = []
    for c, cap in enumerate(caps):
        centre, normal, radius = np.asarray(cap.center, float), np.asarray(cap.normal, float), float(cap.radius)
        rel = centre - ends
        depth = rel @ normal
        lateral = np.linalg.norm(rel - depth[:, None] * normal, axis=1)
        reach = 3.0 * radius + 2.0 * end_radii
        ok = (depth > -0.5 * radius) & (depth < reach) & (lateral < 1.2 * radius)
        for e in np.flatnonzero(ok):
            pairs.append((float(np.linalg.norm(rel[e])), int(e), c))
    pairs.sort()
    matched, used_ends, used_caps = {}, set(), set()
    for _, e, c in pairs:
        if e not in used_ends and c not in used_caps:
            matched[e] = c
            used_ends.add(e)
            used_caps.add(c)
    return matched


def place_ends(graph: BranchGraph, sdf: SdfFunction, spacing: float, caps=None, end_depth: float = 0.5) -> dict:
    """Move every end of the skeleton to where the vessel ends.

    * With ``caps`` (objects with ``center``, ``normal``, ``radius``): each end is
      matched to the cap of its open end and extended straight to the cap centre;
      a cap without a skeleton end (its branch was too short to survive thinning)
      gets a new branch from the nearest skeleton point with a path inside the
      vessel to it (:func:`_attach_cap`); caps without one are listed under
      ``unreached``. A cap overlapping a reached one (a cap face detected in two
      parts) needs no end of its own.
    * Other ends are extended along their end tangent to the wall. A flat end
      (the cross-section keeps its full width up to the wall) ends on the axis
      through the centre of the end face, at the last cross-section behind it that
      meets only the side wall (:func:`flat_end_sections`: a quarter radius behind
      a clean face, more behind a tilted, rough or rounded-rim one, as a clipped face
      without a detected cap is); a rounded end (an aneurysm dome, a capsule)
      ends where the inscribed radius has dropped to ``end_depth`` x the radius at
      the medial end.

    Returns the number of ends of each kind (``cap``, ``flat``, ``rounded``, ``added``)
    and, when some cap could not be reached, the list ``unreached`` of their indices.
    """
    counts = {"cap": 0, "flat": 0, "rounded": 0, "added": 0}
    ends = [n for n in graph.graph.nodes if graph.degree(n) == 1]
    info = [(node, *_trim_end(graph, node, spacing)) for node in ends]
    caps = list(caps or [])
    matched = {}
    if caps and ends:
        end_pos = np.array([graph.pos(n) for n in ends])
        matched = _match_caps(end_pos, np.array([i[2] for i in info]), caps)
    for e, (node, tangent, r_ref) in enumerate(info):
        if e in matched:
            cap = caps[matched[e]]
            _extend(graph, node, np.asarray(cap.center, float), float(cap.radius), spacing)
            graph.graph.nodes[node]["end"] = ("cap", matched[e])
            counts["cap"] += 1
    free = [i for e, i in enumerate(info) if e not in matched]
    taken = set(matched.values())
    if free:
        counts_free = _extend_to_wall(graph, sdf, free, spacing, end_depth, caps, taken)
        for key, value in counts_free.items():
            counts[key] += value
    for c in sorted(set(range(len(caps))) - taken):
        centre = np.asarray(caps[c].center, float)
        if any(np.linalg.norm(np.asarray(caps[o].center, float) - centre) < caps[o].radius + caps[c].radius for o in taken):
            continue  # overlaps a reached cap: two open ends cannot, it is a piece of that one
        if _attach_cap(graph, caps[c], c, spacing, sdf):
            counts["added"] += 1
        else:
            counts.setdefault("unreached", []).append(c)
    return counts


def _trim_end(graph: BranchGraph, node: int, spacing: float) -> tuple[np.ndarray, float]:
    """Cut the wall-ward tail off a terminal branch and return its end tangent and radius.

    Near a flat end the medial axis fans out into a cone towards the rim, and the
    thinned curve follows one side of it; the points whose inscribed radius has
    dropped below 85 % of the largest radius near the end are that tail. What
    remains ends on the vessel axis, about a radius before the end face.
    """
    (u, v, k), = list(graph.graph.edges(node, keys=True))
    other = graph.other(u, v, node)
    pts, rad = graph.polyline(u, v, k, start=other)
    seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    from_end = np.concatenate([np.cumsum(seg[::-1])[::-1], [0.0]])
    window = min(float(from_end[0]), 2.0 * float(np.median(rad)) + 2 * spacing)
    tail = np.flatnonzero(from_end <= window)
    r_ref = float(rad[tail].max())
    keep = tail[rad[tail] >= 0.85 * r_ref]
    last = int(keep[-1]) if len(keep) else len(pts) - 1
    if 0 < last < len(pts) - 1:
        data = graph.graph.edges[u, v, k]
        inner = pts[1:last] if data["start"] == other else pts[1:last][::-1]
        inner_r = rad[1:last] if data["start"] == other else rad[1:last][::-1]
        data["pts"], data["rad"] = inner, inner_r
        graph.graph.nodes[node]["pos"] = pts[last]
        graph.graph.nodes[node]["r"] = float(rad[last])
        pts, from_end = pts[: last + 1], from_end[: last + 1] - from_end[last]
    return _end_tangent(pts, max(2.5 * r_ref, 4 * spacing)), r_ref


def _extend(graph: BranchGraph, node: int, target: np.ndarray, radius: float, spacing: float, direction=None) -> None:
    """Move end ``node`` to ``target``, keeping its old position as part of the branch.

    With ``direction`` (the outward axis at the end), branch points that do not lie
    clearly behind ``target`` along it are cut off first: a target set back from an
    end face may lie behind the traced end, and going there and back would fold the
    branch."""
    (u, v, k), = list(graph.graph.edges(node, keys=True))
    data = graph.graph.edges[u, v, k]
    target = np.asarray(target, float)
    towards_end = data["start"] != node
    pts = data["pts"] if towards_end else data["pts"][::-1]
    rad = data["rad"] if towards_end else data["rad"][::-1]
    old, old_r = graph.pos(node), graph.radius(node)
    if direction is not None and (old - target) @ direction > -spacing:
        behind = np.flatnonzero((pts - target) @ np.asarray(direction, float) < -spacing)
        keep = behind[-1] + 1 if len(behind) else 0
        pts, rad = pts[:keep], rad[:keep]
        old = pts[-1] if keep else graph.pos(graph.other(u, v, node))
        old_r = rad[-1] if keep else old_r
        extra = _straight(old, target, spacing)
    else:
        extra = np.concatenate([old[None], _straight(old, target, spacing)])
    pts = np.concatenate([pts, extra])
    rad = np.concatenate([rad, np.full(len(extra), old_r)])
    data["pts"], data["rad"] = (pts, rad) if towards_end else (pts[::-1].copy(), rad[::-1].copy())
    graph.graph.nodes[node]["pos"] = target
    graph.graph.nodes[node]["r"] = float(radius)


def flat_end_sections(
    sdf: SdfFunction,
    faces: np.ndarray,
    normals: np.ndarray,
    tangents: np.ndarray,
    radii: np.ndarray,
    setbacks=(0.25, 0.5, 0.75, 1.0),
    rays: int = 16,
    max_wall_angle: float = 30.0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The last full cross-section behind each flat end face.

    A cross-section on a clipped end face itself runs along the face's bumps and its
    rounded rim, not along the vessel wall: its rays are short on one side, and the
    boundary-layer blocks projected onto the wall there fold. Candidates are set back
    from the face centre along the inward face normal by ``setbacks`` x the radius,
    centred in the plane orthogonal to the axis; the first one whose ``rays`` in-plane
    rays all meet the wall where it is within ``max_wall_angle`` of parallel to the axis
    (the side wall, not the face or its rim) is kept; where none is, the one with the
    most such rays (the nearest of those).

    Parameters
    ----------
    sdf : callable
        Signed distance, positive inside.
    faces, normals : (n, 3)
        Centres of the end faces and their outward unit normals.
    tangents : (n, 3)
        Unit vessel axes at the ends (outward).
    radii : (n,)
        Vessel radii near the ends.
    setbacks : sequence of float
        Candidate distances behind the face, in radii, nearest first.
    rays : int
        Rays per candidate section.
    max_wall_angle : float
        Largest angle (degrees) between the axis and the wall the rays meet.

    Returns
    -------
    centres : (n, 3)
        The chosen section centres.
    section : (n,)
        Their section radii (mean half-chord, see :func:`center_in_cross_sections`).
    setback : (n,)
        The chosen setbacks, in radii.
    """
    faces = np.asarray(faces, float).reshape(-1, 3)
    normals = np.asarray(normals, float).reshape(-1, 3)
    radii = np.asarray(radii, float).reshape(-1)
    n, s = len(faces), np.asarray(setbacks, float)
    m = len(s)
    # candidates (n, m) flattened end by end
    probes = faces[:, None, :] - (radii[:, None] * s[None, :])[..., None] * normals[:, None, :]
    r = np.repeat(radii, m)
    t = np.repeat(np.asarray(tangents, float).reshape(-1, 3), m, axis=0)
    centres, section = center_in_cross_sections(sdf, probes.reshape(-1, 3), t, r)
    e1, e2 = plane_basis(t)
    ang = 2 * np.pi * np.arange(rays) / rays
    dirs = (np.cos(ang)[None, :, None] * e1[:, None, :] + np.sin(ang)[None, :, None] * e2[:, None, :]).reshape(-1, 3)
    origins = np.repeat(centres, rays, axis=0)
    hit = distance_to_wall(sdf, origins, dirs, np.repeat(2.5 * r, rays), samples=20)
    found = np.isfinite(hit) & (hit > 0)
    back = np.repeat(0.05 * r, rays)  # the wall normal just inside the hit
    g = sdf_gradient(sdf, origins + (np.where(found, hit, 0.0) - back)[:, None] * dirs, back)
    along = np.abs(np.einsum("ij,ij->i", g, np.repeat(t, rays, axis=0)))
    side = (found & (along < np.sin(np.radians(max_wall_angle)))).reshape(n, m, rays).sum(axis=2)
    side = np.where(np.isfinite(section).reshape(n, m), side, -1)
    pick = np.argmax(side == side.max(axis=1, keepdims=True), axis=1)
    rows = np.arange(n)
    return centres.reshape(n, m, 3)[rows, pick], section.reshape(n, m)[rows, pick], s[pick]


def end_face_normals(sdf: SdfFunction, centres: np.ndarray, tangents: np.ndarray, radii: np.ndarray, reach: np.ndarray, rings: int = 2, per_ring: int = 8) -> np.ndarray:
    """Outward normals of the end faces ahead of points on the vessel axis.

    From a disc of points around each centre (up to half a radius from the axis, half a
    radius behind it) rays are cast along the axis; a least-squares plane through the
    wall points they meet gives the normal, pointing along ``tangents``. Where fewer
    than five rays meet the wall the SDF gradient at the axis' wall point is used.

    Parameters
    ----------
    sdf : callable
        Signed distance, positive inside.
    centres, tangents : (n, 3)
        Points on the vessel axis near its end and the unit axis directions (outward).
    radii : (n,)
        Vessel radii.
    reach : (n,)
        How far ahead the rays look for the wall.
    rings, per_ring : int
        Rings of the disc of ray origins and rays per ring (plus one on the axis).

    Returns
    -------
    (n, 3) unit normals.
    """
    c = np.asarray(centres, float).reshape(-1, 3)
    t = np.asarray(tangents, float).reshape(-1, 3)
    r = np.asarray(radii, float).reshape(-1)
    n = len(c)
    e1, e2 = plane_basis(t)
    ang = 2 * np.pi * np.arange(per_ring) / per_ring
    frac = np.r_[0.0, np.repeat(np.arange(1, rings + 1) / rings * 0.5, per_ring)]  # × radius off the axis
    cos = np.r_[0.0, np.tile(np.cos(ang), rings)]
    sin = np.r_[0.0, np.tile(np.sin(ang), rings)]
    k = len(frac)
    offset = (frac * cos)[None, :, None] * e1[:, None, :] + (frac * sin)[None, :, None] * e2[:, None, :]
    origins = c[:, None, :] + r[:, None, None] * (offset - 0.5 * t[:, None, :])
    dirs = np.repeat(t[:, None, :], k, axis=1)
    hit = distance_to_wall(sdf, origins.reshape(-1, 3), dirs.reshape(-1, 3), np.repeat(np.asarray(reach, float) + 0.5 * r, k), samples=24).reshape(n, k)
    good = np.isfinite(hit) & (hit > 0)
    points = origins + np.where(good, hit, 0.0)[..., None] * dirs
    # fallback: the gradient where the axis meets the wall
    axis_hit = np.where(good[:, 0], hit[:, 0], 0.5 * r)
    normal = -sdf_gradient(sdf, origins[:, 0] + (axis_hit - 0.1 * r)[:, None] * t, 0.05 * r)
    w = good.astype(float)
    count = w.sum(axis=1)
    mean = (points * w[..., None]).sum(axis=1) / np.maximum(count, 1)[:, None]
    rel = (points - mean[:, None, :]) * w[..., None]
    cov = np.einsum("nki,nkj->nij", rel, rel)
    fit = np.linalg.eigh(cov)[1][:, :, 0]  # smallest principal axis
    fit *= np.where(np.einsum("ij,ij->i", fit, t) < 0, -1.0, 1.0)[:, None]
    return np.where((count >= 5)[:, None], fit, normal)


def _extend_to_wall(graph: BranchGraph, sdf: SdfFunction, free, spacing: float, end_depth: float, caps=(), taken=None) -> dict:
    """Extend free ends along their tangent: to just behind a flat end face, or into a rounded end.

    An end whose axis meets the wall on a cap not matched yet (its branch bent away
    from the cap's axis) goes to that cap's centre; ``taken`` collects such caps."""
    nodes = [f[0] for f in free]
    origin = np.array([graph.pos(n) for n in nodes])
    tangent = np.array([f[1] for f in free])
    r_ref = np.array([f[2] for f in free])
    # the axis near the end: through the centres of two sections a radius apart
    origin, _ = center_in_cross_sections(sdf, origin, tangent, r_ref)
    behind, _ = center_in_cross_sections(sdf, origin - r_ref[:, None] * tangent, tangent, r_ref)
    axis = origin - behind
    length = np.linalg.norm(axis, axis=1, keepdims=True)
    ok = (length[:, 0] > 0.5 * r_ref) & (np.einsum("ij,ij->i", axis, tangent) > 0.7 * length[:, 0])
    tangent = np.where(ok[:, None], axis / np.maximum(length, 1e-300), tangent)
    reach = 4.0 * r_ref + 2 * spacing
    hit = distance_to_wall(sdf, origin, tangent, reach, samples=24)
    has_hit = np.isfinite(hit)
    hit = np.where(has_hit, hit, 0.0)
    # the wall normal where the axis meets it, from a point a little before the hit
    centre0, _ = center_in_cross_sections(sdf, origin + np.maximum(hit - 0.3 * r_ref, 0)[:, None] * tangent, tangent, r_ref)
    to_wall = distance_to_wall(sdf, centre0, tangent, reach)
    to_wall = np.where(np.isfinite(to_wall), to_wall, 0.3 * r_ref)
    wall_point = centre0 + to_wall[:, None] * tangent
    # the end face's normal from a plane through many face points: the gradient at one
    # point follows every bump of a rough (clipped, smoothed) end face and, tilted, would
    # put the end off the axis
    normal = end_face_normals(sdf, centre0, tangent, r_ref, reach)
    # flat end: facing the axis, and the section a quarter radius inside is still full
    probe = wall_point - 0.25 * r_ref[:, None] * normal
    centre, section = center_in_cross_sections(sdf, probe, normal, r_ref)
    facing = np.einsum("ij,ij->i", normal, tangent) > np.cos(np.radians(45))
    flat = has_hit & facing & (section >= 0.8 * r_ref)
    to_face = distance_to_wall(sdf, centre, normal, 0.5 * r_ref + 2 * spacing)
    face = centre + np.where(np.isfinite(to_face), to_face, 0.25 * r_ref)[:, None] * normal
    # the end itself is the last full cross-section behind the face
    flat_end, flat_section, _ = flat_end_sections(sdf, face, normal, tangent, np.where(np.isfinite(section), section, r_ref))
    # rounded end: where the inscribed radius has dropped to end_depth x r_ref, centred
    samples = 32
    t = hit[:, None] * (np.arange(samples + 1) / samples)[None, :]
    d = evaluate_sdf(sdf, (origin[:, None, :] + t[..., None] * tangent[:, None, :]).reshape(-1, 3)).reshape(len(nodes), -1)
    target = end_depth * r_ref
    below = d <= target[:, None]
    first = np.where(below.any(axis=1), np.argmax(below, axis=1), samples)
    j0 = np.maximum(first - 1, 0)
    rows = np.arange(len(nodes))
    d0, d1 = d[rows, j0], d[rows, first]
    frac = np.where(first > 0, np.clip((d0 - target) / np.maximum(d0 - d1, 1e-300), 0, 1), 0.0)
    t_end = t[rows, j0] + frac * (t[rows, first] - t[rows, j0])
    rounded_end, rounded_section = center_in_cross_sections(sdf, origin + t_end[:, None] * tangent, tangent, r_ref)
    counts = {"flat": 0, "rounded": 0, "cap": 0}
    taken = set() if taken is None else taken
    for i, node in enumerate(nodes):
        if not has_hit[i]:
            continue
        on_cap = [
            c
            for c, cap in enumerate(caps)
            if c not in taken and _on_cap_face(wall_point[i], cap)
        ]
        if on_cap:
            cap = caps[on_cap[0]]
            _extend(graph, node, np.asarray(cap.center, float), float(cap.radius), spacing)
            graph.graph.nodes[node]["end"] = ("cap", on_cap[0])
            taken.add(on_cap[0])
            counts["cap"] += 1
            continue
        if flat[i]:
            position, radius = flat_end[i], flat_section[i]
            if not np.isfinite(radius):
                radius = section[i]
        else:
            position, radius = rounded_end[i], rounded_section[i]
            if not np.isfinite(radius):
                radius = target[i]
        _extend(graph, node, position, float(radius), spacing, direction=tangent[i])
        graph.graph.nodes[node]["end"] = ("flat",) if flat[i] else ("rounded",)
        counts["flat" if flat[i] else "rounded"] += 1
    return counts


def _on_cap_face(point: np.ndarray, cap) -> bool:
    """Whether a wall point lies on the flat face of ``cap``."""
    rel = np.asarray(point, float) - np.asarray(cap.center, float)
    normal = np.asarray(cap.normal, float)
    depth = float(rel @ normal)
    lateral = float(np.linalg.norm(rel - depth * normal))
    return abs(depth) < 0.3 * float(cap.radius) and lateral < 1.2 * float(cap.radius)


def _attach_cap(graph: BranchGraph, cap, index: int, spacing: float, sdf: SdfFunction | None = None, candidates: int = 64) -> bool:
    """Add a branch from the skeleton to a cap that no end reached.

    The branch starts at the skeleton point nearest to the cap's centre from which a
    straight line to the centre stays inside the vessel (``sdf`` positive along it);
    failing that, from which a line to the point two cap radii behind the cap does
    (the branch then bends there). Ends of other branches are no start: a branch
    continuing through one would carry that end to the wrong cap. Without ``sdf``
    the nearest point is taken. Returns whether a branch was added: none when every
    such path runs through the outside (more than half a cap radius).
    """
    centre = np.asarray(cap.center, float)
    radius = float(cap.radius)
    where, pts = [], []
    for u, v, k, data in graph.graph.edges(keys=True, data=True):
        where += [("branch", u, v, k, i) for i in range(len(data["pts"]))]
        pts.append(data["pts"])
    for n in graph.graph.nodes:
        if graph.degree(n) != 1:
            where.append(("node", n))
            pts.append(graph.pos(n)[None])
    if not where:
        return False
    pts = np.concatenate(pts)
    order = np.argsort(np.linalg.norm(pts - centre, axis=1))[:candidates]
    behind = centre - 2.0 * radius * np.asarray(cap.normal, float)
    pick, via = int(order[0]), None
    if sdf is not None:
        t = (np.arange(1, 17) / 17.0)[None, :, None]
        paths = []  # (depth, weight) along each candidate path, for the direct and the bent one
        for target in (centre, behind):
            probes = pts[order][:, None, :] + t * (target - pts[order][:, None, :])
            if target is behind:  # via the bend: the last stretch, to the cap, too
                probes = np.concatenate([probes, np.broadcast_to(behind + t[0] * (centre - behind), (len(order), 16, 3))], axis=1)
            depth = evaluate_sdf(sdf, probes.reshape(-1, 3)).reshape(len(order), -1)
            # the cap centre is on the surface: the margin asked for fades out over a cap radius
            weight = np.clip(np.linalg.norm(probes - centre, axis=2) / radius, 0.0, 1.0)
            paths.append((depth, weight))
        pick = -1
        # well inside if possible (a path along the wall makes thin nodes); a path that
        # grazes the wall is centred later; one through the outside is no path
        for least in (0.25 * radius, 0.0, -0.5 * radius):
            for (depth, weight), bend in zip(paths, (None, behind)):
                ok = np.flatnonzero((depth >= least * weight).all(axis=1))
                if len(ok):
                    pick, via = int(order[ok[0]]), bend
                    break
            if pick >= 0:
                break
        if pick < 0:
            from .skeleton.march import attach_by_march

            return attach_by_march(graph, cap, index, spacing, sdf, where, pts)
    location = where[pick]
    base = location[1] if location[0] == "node" else graph.split(*location[1:])
    end = graph.add_node(centre, radius, end=("cap", index))
    start = graph.pos(base)
    if via is None:
        path = _straight(start, centre, spacing)
    else:
        path = np.concatenate([_straight(start, via, spacing), via[None], _straight(via, centre, spacing)])
    graph.add_branch(base, end, path, np.full(len(path), radius))
    return True


# ---------------------------------------------------------------------------
# Branch geometry: smoothing, resampling, centring
# ---------------------------------------------------------------------------


def smooth_polyline(points: np.ndarray, iterations: int) -> np.ndarray:
    """Laplacian smoothing (weights 1/4, 1/2, 1/4) with fixed end points.

    ``iterations`` passes smooth like a Gaussian of standard deviation
    ``sqrt(iterations / 2)`` point spacings.
    """
    p = np.array(points, float)
    for _ in range(int(iterations)):
        if len(p) < 3:
            break
        p[1:-1] = 0.5 * p[1:-1] + 0.25 * (p[:-2] + p[2:])
    return p


def _station_positions(s: np.ndarray, step: np.ndarray, a: float, b: float, keep_a: bool, keep_b: bool) -> np.ndarray:
    """Arclengths of nodes on ``[a, b]`` spaced by the local ``step(s)``.

    Nodes are equally spaced in ``u = integral ds / step``; ``keep_a`` / ``keep_b``
    say whether a node sits exactly at ``a`` / ``b`` (junction clearance) or
    whether the interval ends at an existing node (an end of the skeleton).
    """
    if b < a:
        return np.zeros(0)
    u = np.concatenate([[0.0], np.cumsum(np.diff(s) * 0.5 * (1 / step[1:] + 1 / step[:-1]))])
    ua, ub = np.interp([a, b], s, u)
    if keep_a and keep_b and ub - ua < 0.5:
        return np.array([0.5 * (a + b)])
    n = max(1, int(round(ub - ua)))
    j = np.arange(0 if keep_a else 1, n + 1 if keep_b else n)
    return np.interp(ua + (ub - ua) * j / n, u, s)


def junction_clearances(graph: BranchGraph, factor: float, cap: float = 4.0) -> dict:
    """How far from each junction the first node of each of its branches must be.

    At least ``factor`` junction radii; further where a branch leaves another at
    a small angle ``theta``: its cross-section overlaps the other vessel until
    about ``(r_branch + r_other) / sin(theta)`` from the junction (a thin side
    branch leaving a wide trunk, two daughters of a narrow bifurcation). At most
    ``cap`` junction radii. Keys are ``(junction, u, v, key)``; a loop at a
    junction has ``"first"`` / ``"last"`` appended for its two ends.
    """
    out = {}
    for node in graph.graph.nodes:
        if graph.degree(node) < 3:
            continue
        r_j = graph.radius(node)
        arms = []  # (key, direction, radius)
        for u, v, k in graph.graph.edges(node, keys=True):
            ends = ["first", "last"] if u == v else [None]
            for end in ends:
                pts, rad = graph.polyline(u, v, k, start=node)
                if end == "last":
                    pts, rad = pts[::-1], rad[::-1]
                s = _arclength(pts)
                near = (s >= r_j) & (s <= 3.0 * r_j)
                if near.sum() >= 2:
                    direction = pts[near][-1] - pts[near][0]
                    radius = float(np.median(rad[near]))
                else:
                    direction = pts[min(len(pts) - 1, np.searchsorted(s, 3.0 * r_j))] - pts[0]
                    radius = float(np.median(rad))
                direction = direction / max(np.linalg.norm(direction), 1e-300)
                key = (node, u, v, k) if end is None else (node, u, v, k, end)
                arms.append((key, direction, radius))
        for key, d, r in arms:
            need = factor * r_j
            for other, d_o, r_o in arms:
                if other == key:
                    continue
                cos = float(np.clip(d @ d_o, -1.0, 1.0))
                if cos > 0:  # diverging at less than 90 degrees
                    need = max(need, min((r + r_o) / max(np.sqrt(1 - cos * cos), 1e-6), cap * r_j))
            out[key] = need
    return out


def _center_loop_cuts(graph: BranchGraph, sdf: SdfFunction, spacing: float) -> None:
    """Centre the node where a cycle without junctions was cut (a voxel position)."""
    g = graph.graph
    # a cut cycle is one node whose single branch is a loop (a node between two
    # branches, e.g. where a cap branch was attached to an end, is no cut)
    cuts = [n for n in g.nodes if g.degree(n) == 2 and g.number_of_edges(n, n) == 1]
    if not cuts:
        return
    tangents, radii = [], []
    for n in cuts:
        u, v, k = next(iter(g.edges(n, keys=True)))
        pts, rad = graph.polyline(u, v, k)
        window = max(3, len(pts) // 20)
        t = pts[min(window, len(pts) - 1)] - pts[-1 - min(window, len(pts) - 1)]
        tangents.append(t / max(np.linalg.norm(t), 1e-300))
        radii.append(max(float(np.median(rad)), spacing))
    centres, _ = center_in_cross_sections(sdf, np.array([graph.pos(n) for n in cuts]), np.array(tangents), np.array(radii))
    depth = evaluate_sdf(sdf, centres)
    for n, c, d in zip(cuts, centres, depth):
        if d > graph.radius(n):
            graph.graph.nodes[n]["pos"] = c
            graph.graph.nodes[n]["r"] = float(d)


def resample_branches(
    graph: BranchGraph,
    sdf: SdfFunction,
    spacing: float,
    node_spacing: float = 1.0,
    junction_clearance: float = 1.5,
    smoothing: float = 0.5,
) -> Skeleton:
    """Turn a cleaned :class:`BranchGraph` into a :class:`~vmesh.skeleton.Skeleton`.

    Every branch polyline is smoothed over ``smoothing`` x the local radius,
    resampled with nodes ``node_spacing`` x the local radius apart, starting
    ``junction_clearance`` x the junction radius away from a junction (inside a
    crotch the medial axis runs between the daughter vessels, not along them),
    and each new node is centred in its cross-section
    (:func:`center_in_cross_sections`); its radius is its distance to the wall.
    """
    g = graph.graph
    _center_loop_cuts(graph, sdf, spacing)
    node_ids = {n: i for i, n in enumerate(g.nodes)}
    points = [graph.pos(n) for n in g.nodes]
    radii = [graph.radius(n) for n in g.nodes]
    tags = []
    for n in g.nodes:
        end = g.nodes[n].get("end")
        kind = {"cap": "cap_end", "flat": "flat_end", "rounded": "rounded_end"}.get(end[0]) if end else None
        tags.append(("vessel", kind) if kind else ("vessel",))
    clearance = junction_clearances(graph, junction_clearance)
    stations, tangents, guesses, owners = [], [], [], []
    for u, v, k in graph.branches():
        start = g.edges[u, v, k]["start"]
        end = graph.other(u, v, start)
        pts, rad = graph.polyline(u, v, k, start=start)
        r_typical = float(np.median(rad))
        iterations = int(np.clip(2.0 * (smoothing * r_typical / spacing) ** 2, 1, 400))
        smooth = smooth_polyline(pts, iterations)
        smooth_r = smooth_polyline(rad[:, None], iterations)[:, 0]
        s = _arclength(smooth)
        if s[-1] <= 0:
            owners.append((start, end, None))
            continue
        step = np.maximum(node_spacing * np.maximum(smooth_r, spacing), 2 * spacing)
        clear_a = clearance.get((start, u, v, k), 0.0)
        clear_b = clearance.get((end, u, v, k), 0.0)
        if start == end:  # a loop leaves and enters its junction: both clearances apply
            clear_a, clear_b = clearance.get((start, u, v, k, "first"), clear_a), clearance.get((start, u, v, k, "last"), clear_b)
        at = _station_positions(s, step, clear_a, s[-1] - clear_b, clear_a > 0, clear_b > 0)
        at = at[(at > 1e-9 * s[-1]) & (at < s[-1] * (1 - 1e-9))]
        if start == end and len(at) < 2:  # a loop needs two interior nodes
            at = s[-1] * np.array([1 / 3, 2 / 3])
        elif len(at) == 0 and any(
            o[:2] in ((start, end), (end, start)) for o in owners if o[2] is None
        ):  # a second direct edge between the same nodes needs a node
            at = np.array([0.5 * s[-1]])
        derivative = np.gradient(smooth, s, axis=0) if len(s) > 2 else np.repeat(smooth[[-1]] - smooth[[0]], len(s), 0)
        p = np.stack([np.interp(at, s, smooth[:, c]) for c in range(3)], axis=1)
        t = np.stack([np.interp(at, s, derivative[:, c]) for c in range(3)], axis=1)
        t /= np.maximum(np.linalg.norm(t, axis=1, keepdims=True), 1e-300)
        stations.append(p)
        tangents.append(t)
        guesses.append(np.interp(at, s, smooth_r))
        owners.append((start, end, len(at) if len(at) else None))
    if stations:
        p = np.concatenate(stations)
        t = np.concatenate(tangents)
        r_guess = np.concatenate(guesses)
        centred, section = center_in_cross_sections(sdf, p, t, np.maximum(r_guess, spacing))
        r_centred = evaluate_sdf(sdf, centred)
        r_initial = evaluate_sdf(sdf, p)
        # keep the centred point unless centring left the vessel
        use = r_centred >= 0.5 * np.maximum(r_initial, 0)
        final = np.where(use[:, None], centred, p)
        final_r = np.where(use, r_centred, r_initial)
        final_r = np.where(final_r > 0, final_r, r_guess)
        # next to an end face the inscribed sphere touches the face, not the wall:
        # there the radius of the cross-section is the vessel's
        ends = np.array([graph.pos(n) for n in g.nodes if g.degree(n) == 1]).reshape(-1, 3)
        if len(ends):
            from scipy.spatial import cKDTree

            to_end = cKDTree(ends).query(final)[0]
            near_end = np.isfinite(section) & (to_end < 1.2 * np.nan_to_num(section)) & (final_r < section)
            final_r = np.where(near_end, section, final_r)
    else:
        final, final_r = np.zeros((0, 3)), np.zeros(0)
    edges = []
    offset = len(points)
    cursor = 0
    for start, end, count in owners:
        count = count or 0
        chain = [node_ids[start]] + list(range(offset + cursor, offset + cursor + count)) + [node_ids[end]]
        edges.extend(zip(chain[:-1], chain[1:]))
        cursor += count
    all_points = np.concatenate([np.array(points).reshape(-1, 3), final])
    all_radii = np.concatenate([np.array(radii, float), final_r])
    all_tags = tags + [("vessel",)] * len(final)
    return Skeleton(all_points, all_radii, np.array(edges, np.int64).reshape(-1, 2), all_tags)


# ---------------------------------------------------------------------------
# The whole extraction
# ---------------------------------------------------------------------------


@dataclass
class ExtractionSettings:
    """Parameters of :func:`extract_skeleton` (lengths relative to the local radius)."""

    spacing: float | None = None
    voxels_per_radius: float = 3.0
    max_voxels: int = 60_000_000
    spur_ratio: float = 2.0
    merge_ratio: float = 1.0
    cycle_ratio: float = 6.0
    node_spacing: float = 1.0
    junction_clearance: float = 1.5
    end_depth: float = 0.5
    smoothing: float = 0.5


def surface_genus(vertices: np.ndarray, faces: np.ndarray) -> int | None:
    """Number of independent cycles of the solid bounded by a closed surface
    (its total genus, ``(2 * components - Euler characteristic) / 2``); ``None`` for
    an open surface, whose genus says nothing about the solid."""
    from . import topology

    faces = np.asarray(faces, np.int64)
    if len(faces) == 0 or topology.boundary_loops(faces):
        return None
    components = topology.face_components(faces, len(vertices))[0]
    genus2 = 2 * components - topology.euler_characteristic(faces)
    return max(genus2 // 2, 0)


def choose_spacing(min_radius: float, bounds, voxels_per_radius: float, max_voxels: int) -> tuple[float, bool]:
    """Voxel size: ``min_radius / voxels_per_radius``, enlarged to stay within
    ``max_voxels`` over the bounding box. Returns (spacing, was_limited)."""
    lo, hi = (np.asarray(b, float) for b in bounds)
    extent = np.maximum(hi - lo, 1e-12)
    h = min_radius / voxels_per_radius
    limit = (np.prod(extent) / max_voxels) ** (1.0 / 3.0)
    if h < limit:
        return float(limit), True
    return float(h), False


def extract_skeleton(
    sdf: SdfFunction,
    bounds,
    *,
    min_radius: float | None = None,
    surface=None,
    caps=None,
    expected_cycles: int | None = None,
    settings: ExtractionSettings | None = None,
    progress: Callable | None = None,
) -> tuple[Skeleton, dict]:
    """Extract the centerline skeleton of a vessel from its signed distance.

    Parameters
    ----------
    sdf : callable
        ``sdf(points (n, 3)) -> (n,)`` signed distance, positive inside.
    bounds : (lo, hi)
        Bounding box of the vessel.
    min_radius : float, optional
        Radius of the thinnest vessel to resolve; estimated from ``surface`` when
        not given (ignored when ``settings.spacing`` is set).
    surface : (vertices, faces), optional
        The closed surface: for the radius estimate, and its genus is the number
        of cycles the skeleton keeps.
    caps : sequence, optional
        Open-end caps (objects with ``center``, ``normal``, ``radius``).
    expected_cycles : int, optional
        Number of independent cycles of the vessel (default: the genus of
        ``surface`` when it is closed). Extra cycles, made where the voxel mask
        bridges two close vessels, are cut at their narrowest branch; without it
        cycles shorter than ``cycle_ratio`` radii are collapsed instead.
    settings : ExtractionSettings, optional
    progress : callable, optional
        ``progress(fraction, message)``.

    Returns
    -------
    skeleton : Skeleton
    stats : dict
        Spacing, grid size, SDF evaluations, voxel counts, what cleaning removed
        and the time of each stage.
    """
    settings = settings or ExtractionSettings()
    tick = progress or (lambda fraction, message="": None)
    evaluations = [0]
    user_sdf = sdf

    def sdf(points):  # counts evaluations for the report
        evaluations[0] += len(points)
        return user_sdf(points)

    timings = {}
    clock = time.perf_counter()
    stats: dict = {}
    lo, hi = (np.asarray(b, float) for b in bounds)
    if settings.spacing is not None:
        spacing, limited = float(settings.spacing), False
    else:
        if min_radius is None:
            if surface is None:
                raise ValueError("extract_skeleton needs spacing, min_radius or a surface")
            tick(0.0, "estimating the smallest vessel radius")
            min_radius = estimate_min_radius(sdf, *surface)
            if caps:  # an open end is a vessel the estimate must resolve, however small its area
                min_radius = min(min_radius, min(float(c.radius) for c in caps))
        if not np.isfinite(min_radius) or min_radius <= 0:
            raise ValueError("could not estimate the vessel radius (is the surface closed?)")
        spacing, limited = choose_spacing(min_radius, (lo, hi), settings.voxels_per_radius, settings.max_voxels)
        stats["min_radius"] = float(min_radius)
    stats["spacing"] = spacing
    stats["spacing_limited"] = limited
    timings["radius_estimate"] = time.perf_counter() - clock

    clock = time.perf_counter()
    grid = grid_for_bounds((lo, hi), spacing)
    stats["grid"] = list(grid.shape)
    mask, mask_evaluations = inside_mask(sdf, grid, progress=lambda f, m: tick(0.05 + 0.45 * f, m))
    stats["sdf_evaluations_mask"] = int(mask_evaluations)
    stats["inside_voxels"] = int(mask.sum())
    timings["voxelise"] = time.perf_counter() - clock

    clock = time.perf_counter()
    tick(0.5, f"thinning {stats['inside_voxels']} inside voxels")
    ijk = voxel_skeleton(mask, sdf, grid)
    del mask
    stats["skeleton_voxels"] = int(len(ijk))
    timings["thin"] = time.perf_counter() - clock
    if len(ijk) == 0:
        raise ValueError("no voxel lies inside the surface: the vessel is thinner than the voxel size")

    clock = time.perf_counter()
    tick(0.65, f"tracing {len(ijk)} skeleton voxels")
    voxel_points = grid.points(ijk)
    voxel_radii = evaluate_sdf(sdf, voxel_points)
    traced = trace_branches(voxel_adjacency(ijk))
    graph = build_branch_graph(traced, voxel_points, voxel_radii)
    stats["raw_nodes"] = graph.graph.number_of_nodes()
    stats["raw_branches"] = graph.graph.number_of_edges()
    timings["trace"] = time.perf_counter() - clock

    clock = time.perf_counter()
    tick(0.75, "cleaning the skeleton graph")
    if expected_cycles is None and surface is not None:
        expected_cycles = surface_genus(*surface)
    stats["expected_cycles"] = expected_cycles
    removed = {"specks": 0, "spurs": 0, "merged_junctions": 0, "small_cycles": 0, "bridges": 0}

    graph.dissolve_all()
    for _ in range(20):
        step = {
            "specks": graph.drop_small_components(2.0 * settings.spur_ratio),
            "bridges": graph.break_extra_cycles(expected_cycles) if expected_cycles is not None else 0,
            "merged_junctions": graph.merge_junctions(settings.merge_ratio),
            "small_cycles": graph.collapse_small_cycles(settings.cycle_ratio) if expected_cycles is None else 0,
            "spurs": graph.prune_spurs(settings.spur_ratio),
        }
        graph.dissolve_all()
        for key, value in step.items():
            removed[key] += value
        if not any(step.values()):
            break
    stats.update(removed)
    stats["centred_junctions"] = graph.center_junctions(sdf, spacing)
    timings["clean"] = time.perf_counter() - clock

    clock = time.perf_counter()
    tick(0.85, "placing the ends")
    stats["ends"] = place_ends(graph, sdf, spacing, caps=caps, end_depth=settings.end_depth)
    timings["ends"] = time.perf_counter() - clock

    clock = time.perf_counter()
    tick(0.9, "resampling and centring the branches")
    skeleton = resample_branches(
        graph,
        sdf,
        spacing,
        node_spacing=settings.node_spacing,
        junction_clearance=settings.junction_clearance,
        smoothing=settings.smoothing,
    )
    timings["resample"] = time.perf_counter() - clock
    order = {n: i for i, n in enumerate(graph.graph.nodes)}
    stats["cap_of_node"] = {
        order[n]: data["end"][1] for n, data in graph.graph.nodes(data=True) if data.get("end", ("",))[0] == "cap"
    }
    stats["sdf_evaluations"] = int(evaluations[0])
    stats["timings"] = {k: round(v, 4) for k, v in timings.items()}
    stats.update({k: v for k, v in skeleton.summary().items()})
    tick(1.0, f"skeleton: {skeleton.n_nodes} nodes")
    return skeleton, stats
