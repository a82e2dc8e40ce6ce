"""Rays from inside a vessel to its wall, and a cache of the rays cast.

:func:`cast_rays` marches rays on a signed distance and finds where they leave the vessel;
the block builder casts one per section vertex (:mod:`vmesh.geometry.blocks.sections`)
and the skeleton's bend thinning one per suspect segment
(:func:`~vmesh.geometry.skeleton.bends.thin_sharp_bends`). Both try the same rays again
and again (every fix round re-assembles the whole tree; every thinning round looks at the
segments still suspect), so both cast through a :class:`RayCache`, which answers a ray
cast before from memory, bit for bit.
"""

from __future__ import annotations

import numpy as np

RAY_REACH = 12.0  # how far a section's ray looks for the wall, in radii of its section


def cast_rays(
    distance,
    origins: np.ndarray,
    directions: np.ndarray,
    scale: np.ndarray,
    reach: float = RAY_REACH,
    step: float = 0.2,
    iterations: int = 24,
    intersect_lines=None,
) -> np.ndarray:
    """Distance along each ray to its first crossing of the wall.

    Marches each ray from its origin (inside the vessel) in steps of ``step × scale``
    until the signed distance turns negative, then finds the crossing in the bracketing
    step: by one exact line cast where ``intersect_lines`` is given, else by bisection.
    Either way a wall grazed between two march samples is stepped over (an exact first
    crossing moved 35 of the real coarctation's 33,249 section rays inward by up to 6
    radii and changed its mesh; the march keeps the sections the presets were tuned on).

    Parameters
    ----------
    distance : callable
        ``distance(points (n, 3)) -> (n,)`` signed distance, positive inside.
    origins, directions : (n, 3)
        Ray origins (inside) and unit directions.
    scale : (n,)
        Length scale per ray (the local radius).
    reach : float
        Rays are followed up to ``reach × scale``.
    step : float
        March step relative to ``scale``.
    iterations : int
        Bisection steps.
    intersect_lines : callable, optional
        ``intersect_lines(points, directions, reach, side) -> (moved, hit)`` of the same
        surface (:meth:`~vmesh.geometry.sdf.SignedDistance.intersect_lines`): one tree
        traversal per ray instead of ``iterations`` distance queries.

    Returns
    -------
    (n,) float: the distance to the wall; ``nan`` where a ray does not leave the
    vessel within its reach or starts outside.
    """
    o = np.asarray(origins, float).reshape(-1, 3)
    d = np.asarray(directions, float).reshape(-1, 3)
    sc = np.broadcast_to(np.asarray(scale, float), (len(o),)).copy()
    n = len(o)
    lo = np.zeros(n)
    hi = np.full(n, np.nan)
    todo = np.flatnonzero(_origins_inside(distance, o))
    n_steps = 12
    t0 = np.zeros(n)
    head = _FIRST_SAMPLES  # the first batch in two parts: most walls lie within its first half
    while len(todo):
        ts = t0[todo, None] + sc[todo, None] * step * np.arange(1, n_steps + 1)[None, :]
        pts = o[todo, None, :] + ts[:, :, None] * d[todo, None, :]
        outside = _march_batch(distance, pts, head)
        head = n_steps
        hit = outside.any(axis=1)
        first = np.argmax(outside, axis=1)
        r = todo[hit]
        fi = first[hit]
        hi[r] = ts[hit, fi]
        lo[r] = np.where(fi > 0, ts[hit, np.maximum(fi - 1, 0)], t0[r])
        rest = todo[~hit]
        t0[rest] = ts[~hit, -1]
        todo = rest[t0[rest] < reach * sc[rest]]
    ok = np.isfinite(hi)
    idx = np.flatnonzero(ok)
    out = np.full(n, np.nan)
    if intersect_lines is not None and len(idx):
        start = o[idx] + lo[idx, None] * d[idx]
        span = hi[idx] - lo[idx]
        moved, hit = intersect_lines(start, d[idx], span * (1 + 1e-9), np.ones(len(idx)))
        along = np.einsum("ij,ij->i", moved - start, d[idx]) / np.einsum("ij,ij->i", d[idx], d[idx])
        out[idx[hit]] = lo[idx[hit]] + along[hit]
        idx = idx[~hit]  # a crossing at a sample within rounding: bisect those
    a, b = lo[idx], hi[idx]
    for _ in range(iterations if len(idx) else 0):
        mid = 0.5 * (a + b)
        inside = np.asarray(distance(o[idx] + mid[:, None] * d[idx])) > 0
        a = np.where(inside, mid, a)
        b = np.where(inside, b, mid)
    out[idx] = 0.5 * (a + b)
    return out


def _origins_inside(distance, o: np.ndarray) -> np.ndarray:
    """(n,) bool: ``distance(o) > 0``, asked once per run of equal consecutive origins (the
    rays of a section share its centre, and callers repeat it)."""
    if len(o) == 0:
        return np.zeros(0, bool)
    start = np.r_[True, np.any(o[1:] != o[:-1], axis=1)]
    inside = np.asarray(distance(o[start])) > 0
    return inside[np.cumsum(start) - 1]


#: Samples of a ray's first march batch evaluated before the rest of it: sections are
#: centred, so the wall lies about a radius (5 steps) from the origin (brava: 90 % of the
#: builder's rays cross within 5.4 steps); the other samples are evaluated only for rays
#: that have not left the vessel by then. The samples are the same, so are the results.
_FIRST_SAMPLES = 6


def _march_batch(distance, pts: np.ndarray, head: int) -> np.ndarray:
    """(m, k) bool: which of the march samples ``pts`` (m, k, 3) lie outside; the first
    ``head`` samples of every ray first, the rest only for rays not outside by then (left
    False for the others, after their first outside sample)."""
    m, k = pts.shape[:2]
    outside = np.zeros((m, k), bool)
    rows = np.arange(m)
    for cols in (slice(0, head), slice(head, k)):
        if len(rows) == 0 or cols.start >= k:
            break
        sub = pts[rows, cols]
        outside[rows, cols] = np.asarray(distance(sub.reshape(-1, 3))).reshape(sub.shape[:2]) < 0
        rows = rows[~outside[rows, cols].any(axis=1)]
    return outside


_FNV_OFFSET = np.uint64(0xCBF29CE484222325)
_FNV_PRIME = np.uint64(0x100000001B3)


def _row_hashes(rows: np.ndarray) -> np.ndarray:
    """(n,) uint64 FNV-1a hash of each row's bytes (one pass per column, not per row)."""
    words = np.ascontiguousarray(rows, np.float64).view(np.uint64)
    h = np.full(len(words), _FNV_OFFSET, np.uint64)
    for c in range(words.shape[1]):
        h = (h ^ words[:, c]) * _FNV_PRIME
    return h


class RowCache:
    """One float per exact row of floats, found by the rows' hashes (:func:`_row_hashes`):
    results of a per-ray computation kept across calls whose rays mostly repeat.

    Parameters
    ----------
    width : int
        Floats per row.
    limit : int
        Most rows kept; beyond it the cache starts again empty.
    """

    def __init__(self, width: int, limit: int = 4_000_000):
        self.width, self.limit = int(width), int(limit)
        self.hits = self.misses = 0
        # two sorted levels: the rows added since the last merge are kept apart until they
        # are an eighth of the rest, so that the many small additions of a build (one
        # junction's half-planes at a time) do not re-sort the whole cache each
        self._levels = [_Level(self.width), _Level(self.width)]

    def __len__(self) -> int:
        return sum(len(level.keys) for level in self._levels)

    def find(self, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(values (n,), found (n,) bool)`` of ``rows`` (n, width); ``nan`` where not found."""
        rows = np.ascontiguousarray(rows, float)
        h = _row_hashes(rows)
        out = np.full(len(rows), np.nan)
        found = np.zeros(len(rows), bool)
        for level in self._levels:
            level.find(h, rows, out, found)
        self.hits += int(found.sum())
        self.misses += int(len(rows) - found.sum())
        return out, found

    def keep(self, mask_of) -> None:
        """Drop the rows for which ``mask_of(rows (m, width)) -> (m,) bool`` is False."""
        rows = np.concatenate([level.rows for level in self._levels])
        values = np.concatenate([level.values for level in self._levels])
        keys = np.concatenate([level.keys for level in self._levels])
        mask = np.asarray(mask_of(rows), bool) if len(rows) else np.zeros(0, bool)
        self._levels = [_Level(self.width), _Level(self.width)]
        self._levels[0].add(keys[mask], rows[mask], values[mask])

    def add(self, rows: np.ndarray, values: np.ndarray) -> None:
        """Keep ``values`` for ``rows`` (rows not in the cache yet)."""
        rows = np.ascontiguousarray(rows, float)
        if len(self) + len(rows) > self.limit:
            self._levels = [_Level(self.width), _Level(self.width)]
        main, recent = self._levels
        recent.add(_row_hashes(rows), rows, np.asarray(values, float))
        if 8 * len(recent.keys) > len(main.keys):  # merged rarely (see __init__)
            main.add(recent.keys, recent.rows, recent.values)
            self._levels[1] = _Level(self.width)


class RayCache(RowCache):
    """Wall distances of rays already cast (:func:`cast_rays`), keyed by the exact ray
    (origin, direction, scale, reach: a :class:`RowCache` of width 8).

    Parameters
    ----------
    limit : int
        Most rays kept; beyond it the cache starts again empty (memory stays bounded:
        about 90 bytes a ray).

    Attributes
    ----------
    hits, misses : int
        Rays answered from the cache and rays cast.
    """

    def __init__(self, limit: int = 4_000_000):
        super().__init__(8, limit)

    def cast(self, distance, origins, directions, scale, reach: float = RAY_REACH, intersect_lines=None) -> np.ndarray:
        """:func:`cast_rays` with the rays cast before answered from the cache (bit for bit
        the same: each ray is cast on its own)."""
        o = np.asarray(origins, float).reshape(-1, 3)
        d = np.asarray(directions, float).reshape(-1, 3)
        n = len(o)
        if n == 0:
            return np.zeros(0)
        rows = np.empty((n, 8))
        rows[:, :3], rows[:, 3:6] = o, d
        rows[:, 6] = np.broadcast_to(np.asarray(scale, float), (n,))
        rows[:, 7] = reach
        out, found = self.find(rows)
        miss = np.flatnonzero(~found)
        if len(miss):
            out[miss] = cast_rays(distance, o[miss], d[miss], rows[miss, 6], reach=reach, intersect_lines=intersect_lines)
            self.add(rows[miss], out[miss])
        return out


class _Level:
    """Rays sorted by their hash: ``keys`` (uint64), ``rows`` (the exact key, e.g. origin,
    direction, scale, reach) and ``values`` (e.g. the wall distances)."""

    def __init__(self, width: int = 8):
        self.keys = np.zeros(0, np.uint64)
        self.rows = np.zeros((0, width))
        self.values = np.zeros(0)

    def find(self, h, rows, out, found) -> None:
        """Fill ``out`` and set ``found`` where a ray not found yet is here."""
        todo = np.flatnonzero(~found)
        if len(self.keys) == 0 or len(todo) == 0:
            return
        pos = np.minimum(np.searchsorted(self.keys, h[todo]), len(self.keys) - 1)
        hit = (self.keys[pos] == h[todo]) & np.all(self.rows[pos] == rows[todo], axis=1)
        out[todo[hit]] = self.values[pos[hit]]
        found[todo[hit]] = True

    def add(self, keys, rows, values) -> None:
        keys = np.concatenate([self.keys, keys])
        order = np.argsort(keys, kind="stable")
        self.keys = keys[order]
        self.rows = np.concatenate([self.rows, rows])[order]
        self.values = np.concatenate([self.values, values])[order]


def _deeper_in_foreign(p, own_depth, rays, tree, k, rq, foreign, ended) -> np.ndarray:
    """(len(rays),) bool: each ray's point ``p`` is deeper in a foreign tube than its
    ``own_depth`` in its own (:func:`clip_to_territory`)."""
    dist, idx = tree.query(p, k=k)
    dist, idx = dist.reshape(len(rays), k), idx.reshape(len(rays), k)
    # inside a foreign tube (a bulge of this vessel wider than its radius is no contact)
    # and deeper there than in its own
    depth = dist - rq[idx]
    deeper = (depth < own_depth[:, None]) & (depth < 0.0)
    near = np.flatnonzero(deeper.any(axis=1))  # the foreign test only where it matters
    sub = deeper[near]
    r_idx, c_idx = np.nonzero(sub)
    sub[r_idx, c_idx] = foreign(rays[near][r_idx], idx[near][r_idx, c_idx])
    if ended is not None:  # past an open end the tube is no territory
        sub[r_idx, c_idx] &= ~ended(p[near][r_idx], idx[near][r_idx, c_idx])
    out = np.zeros(len(rays), bool)
    out[near] = sub.any(axis=1)
    return out


def clip_to_territory(
    origins: np.ndarray,
    directions: np.ndarray,
    lengths: np.ndarray,
    radius: np.ndarray,
    foreign,
    tubes: tuple,
    samples: int = 8,
    iterations: int = 10,
    neighbours: int = 12,
    tree=None, ended=None,
) -> np.ndarray:
    """Shorten wall rays where they cross from their own vessel into another one.

    Where two vessels touch, their lumens fuse and a ray cast from one skeleton across the
    contact runs on through the other vessel to its far wall: the section reaches into a
    lumen another branch meshes too. Each ray is cut where it leaves its own vessel's
    territory: at the first point ``p = o + t d`` inside a foreign tube and deeper there
    than inside its own, ``|p - q| - r_q < min(0, t - radius)`` for a foreign tube sample
    ``q``. ``t - radius`` is the depth in the own tube when the ray runs square to a
    straight axis (section rays do), so where the tubes overlap the cut lies on the contact
    where both are equally deep. Rays that end within their own radius are never cut, nor
    a ray through a bulge of its own vessel (an aneurysm sac wider than its skeleton
    radius) that does not enter another vessel's tube.

    Parameters
    ----------
    origins, directions : (n, 3)
        Rays from the axis of their own vessel (unit directions).
    lengths : (n,)
        Wall distance of each ray (:func:`cast_rays`); ``nan`` is left alone.
    radius : (n,)
        Own vessel's radius at each ray's origin.
    foreign : callable
        ``foreign(rays (k,), samples (k,)) -> (k,) bool``: whether tube sample ``samples[i]``
        belongs to a vessel other than ray ``rays[i]``'s own.
    tubes : tuple
        ``(points (m, 3), radii (m,))``: samples along every skeleton tube, spaced finer
        than their radius.
    samples, iterations, neighbours : int
        Points tested along each ray, bisection steps refining the cut, and tube samples
        asked per point.
    tree : scipy.spatial.cKDTree, optional
        The tube points' tree, when the caller keeps one (each ray's cut depends on that
        ray and the tubes alone: the block builder keeps them, :class:`RowCache`).
    ended : callable, optional
        ``ended(points (k, 3), samples (k,)) -> (k,) bool``: the sample's tube ended before the point (an open end).

    Returns
    -------
    (n,) float: the lengths, cut where a ray enters foreign territory.
    """
    from scipy.spatial import cKDTree

    Q, rq = tubes
    out = np.array(lengths, float)
    # a ray that ends within its own radius never left its own tube
    live = np.flatnonzero(np.isfinite(out) & (out > radius))
    if len(live) == 0 or len(Q) == 0:
        return out
    tree = cKDTree(Q) if tree is None else tree
    k = min(neighbours, len(Q))

    def beyond(rays, t):
        return _deeper_in_foreign(origins[rays] + t[:, None] * directions[rays], t - radius[rays], rays, tree, k, rq, foreign, ended)

    # samples from half a radius (the least cut) to the wall
    start = 0.5 * radius[live]
    frac = np.arange(1, samples + 1) / samples
    t = (start[:, None] + (out[live] - start)[:, None] * frac[None]).ravel()
    hit = beyond(np.repeat(live, samples), t).reshape(len(live), samples)
    cut = hit.any(axis=1)
    rays = live[cut]
    if len(rays) == 0:
        return out
    start = start[cut]
    first = np.argmax(hit[cut], axis=1)
    span = out[rays] - start
    a = start + span * np.where(first > 0, frac[np.maximum(first - 1, 0)], 0.0)
    b = start + span * frac[first]
    for _ in range(iterations):
        mid = 0.5 * (a + b)
        inside = beyond(rays, mid)
        a, b = np.where(inside, a, mid), np.where(inside, mid, b)
    out[rays] = 0.5 * (a + b)
    return out


def cut_at_necks(distance, origins: np.ndarray, directions: np.ndarray, scale: np.ndarray, reach: float = RAY_REACH,
                 step: float = 0.2, neck: float = 0.5) -> np.ndarray:
    """Where rays that find no wall within reach pass through a neck, the neck's distance.

    Where two lumens fuse (vessels in contact, a bulge beside a branch), a section ray can
    slip through the narrow passage between them and run along the other lumen past any
    reach: it never meets the wall, yet it passed within a hair of it. Its section belongs
    on this side of the passage. Along each ray (samples ``step x scale`` apart up to
    ``reach x scale``), the passage is the sample nearest the wall (refined between its
    neighbouring samples, where a wall crossing a coarse step missed ends it); it is a neck when the
    signed distance there is below ``neck`` times both the distance at the origin and the
    largest distance beyond it (the same half as :func:`~vmesh.geometry.skeleton.defects.cut_necks`
    takes for a node narrower than its neighbours). A ray running along an open lumen
    has no such dip and stays ``nan``.

    Returns
    -------
    (n,) float: the distance along each ray to its neck, ``nan`` where it has none.
    """
    o = np.asarray(origins, float).reshape(-1, 3)
    d = np.asarray(directions, float).reshape(-1, 3)
    sc = np.broadcast_to(np.asarray(scale, float), (len(o),))
    out = np.full(len(o), np.nan)
    if len(o) == 0:
        return out
    ts = sc[:, None] * step * np.arange(1, int(np.ceil(reach / step)) + 1)[None, :]
    f = np.asarray(distance((o[:, None, :] + ts[:, :, None] * d[:, None, :]).reshape(-1, 3))).reshape(ts.shape)
    f0 = np.asarray(distance(o))
    m = np.argmin(f, axis=1)
    rows = np.arange(len(o))
    beyond = np.where(np.arange(f.shape[1])[None, :] > m[:, None], f, -np.inf).max(axis=1)
    ok = (f[rows, m] > 0) & (f[rows, m] < neck * f0) & (f[rows, m] < neck * beyond)
    if not ok.any():
        return out
    # the coarse samples can straddle a gap thinner than a step (two lumens apart, not
    # fused): look between the neighbouring samples; the first wall crossing there is the
    # wall, else the finest sample nearest it
    r = rows[ok]
    lo = np.where(m[r] > 0, ts[r, np.maximum(m[r] - 1, 0)], 0.0)
    hi = ts[r, np.minimum(m[r] + 1, f.shape[1] - 1)]
    tf = lo[:, None] + (hi - lo)[:, None] * np.linspace(0.0, 1.0, 17)[None, :]
    ff = np.asarray(distance((o[r, None, :] + tf[:, :, None] * d[r, None, :]).reshape(-1, 3))).reshape(tf.shape)
    crossed = ff <= 0
    hit = crossed.any(axis=1)
    j = np.where(hit, np.argmax(crossed, axis=1), np.argmin(ff, axis=1))
    k = np.maximum(j - 1, 0)
    row = np.arange(len(r))
    # linear interpolation to the crossing between the last sample inside and the first outside
    frac = np.where(hit & (j > 0), ff[row, k] / np.maximum(ff[row, k] - ff[row, j], 1e-300), 0.0)
    at = np.where(hit, tf[row, k] + frac * (tf[row, j] - tf[row, k]), tf[row, j])
    out[r] = at
    return out
