"""Cuts between vessels in contact: the meshing domain keeps kissing vessels apart.

Two vessels that pass in contact with no junction between them
(:func:`vmesh.geometry.skeleton.contact.vessels_in_contact`) are two vessels, even where
their surfaces fuse into a neck. Each contact gets a *cut*: a planar patch on the power
(radical) plane of the two vessels' local axes, bounded to where it lies inside both
(inflated) tubes. The meshing domain is the vessel interior minus the cuts: the signed
distance is ``min(sdf, distance to the cut)`` where the cut's foot lies inside the
vessel, and closest points go to the cut where it is nearer than the wall.
:class:`CutSurface` (a :class:`~vmesh.geometry.surface_query.SurfaceQuery`) and
:class:`CutProjector` (a wall projector) give every stage that domain: the section rays,
edge and face projection, the optimisers' wall projection, the boundary distance.

Only points within a cut's reach do any extra work; far from contacts the wrappers answer
as the wrapped queries do.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from .projection import ON_CUT


@dataclass(frozen=True)
class ContactCuts:
    """Planar patches between vessels in contact (one row each).

    ``centre`` lies on the radical plane between the closest points of the two local axes,
    ``normal`` points from vessel ``a`` to vessel ``b``; a plane point belongs to the patch
    when it is within ``radius[:, 0]`` of axis segment ``axis_a`` and ``radius[:, 1]`` of
    ``axis_b``; ``reach`` bounds the patch (a sphere about ``centre``)."""

    centre: np.ndarray
    normal: np.ndarray
    axis_a: np.ndarray
    axis_b: np.ndarray
    radius: np.ndarray
    reach: np.ndarray
    nodes: np.ndarray
    #: (n, 2) bool: the axis segment starts at its vessel's open end (``axis_x[k, 0]``, on
    #: the cap's plane), so the patch stops there; None: no open ends
    open_end: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.centre)

    @cached_property
    def tree(self):
        """A k-d tree of the cut centres."""
        from scipy.spatial import cKDTree

        return cKDTree(self.centre)

    def summary(self) -> list[dict]:
        """One dict per cut for report.json."""
        return [{"nodes": [int(a), int(b)], "centre": np.round(c, 6).tolist(), "normal": np.round(n, 6).tolist(),
                 "reach": round(float(r), 6)} for (a, b), c, n, r in zip(self.nodes, self.centre, self.normal, self.reach)]


def _tangent(points: np.ndarray, edges: np.ndarray, node: int) -> np.ndarray:
    """Unit axis direction at ``node``: its neighbours' chord (one neighbour: that edge)."""
    nb = np.r_[edges[edges[:, 0] == node, 1], edges[edges[:, 1] == node, 0]]
    if len(nb) == 0:
        return np.array([1.0, 0.0, 0.0])
    if len(nb) >= 2:
        d = points[nb[1]] - points[nb[0]]
        if len(nb) == 2 and np.linalg.norm(d) > 0:
            return d / np.linalg.norm(d)
    d = points[nb[0]] - points[node]
    return d / max(np.linalg.norm(d), 1e-300)


def _axis(P, E, node, t, half):
    """The local axis segment at ``node``: ``half`` each way along ``t``, or only inwards
    from an end node (the tube ends there)."""
    if np.count_nonzero(E == node) == 1:
        return np.array([P[node], P[node] + half * t])
    return np.array([P[node] - half * t, P[node] + half * t])


def _segment_closest(p0, u, q0, v, half_p, half_q):
    """Closest points of segments ``p0 + s u`` (|s| <= half_p) and ``q0 + t v`` (|t| <= half_q), u, v unit."""
    w = p0 - q0
    b, d, e = float(u @ v), float(u @ w), float(v @ w)
    den = 1.0 - b * b
    s = 0.0 if den < 1e-9 else float(np.clip((b * e - d) / den, -half_p, half_p))
    t = float(np.clip(b * s + e, -half_q, half_q))
    s = float(np.clip(b * t - d, -half_p, half_p))
    return p0 + s * u, q0 + t * v


def contact_cuts(points: np.ndarray, radii: np.ndarray, edges: np.ndarray, found: np.ndarray, inflate: float = 1.3,
                 length: float = 2.0, open_ends=()) -> ContactCuts:
    """The cut of each contact ``found`` (rows node a, node b, gap, as
    :func:`~vmesh.geometry.skeleton.contact.vessels_in_contact` returns them).

    Each vessel's local axis is the straight segment through its node along the skeleton
    tangent, ``length`` x (r_a + r_b) each way; the plane is the radical plane of the two
    spheres about the segments' closest points (equal power: inside one tube there is
    inside the other, the fused neck), the patch is bounded by the tubes inflated by
    ``inflate`` (the smooth union widens the neck beyond the tubes' overlap). At a node of
    ``open_ends`` (end nodes on a cap) the tube ends on the plane through the node normal
    to its axis: the patch stops there rather than rounding the end, since past a cap the
    other vessel alone fills the lumen (a cut there would halve it)."""
    P = np.asarray(points, float)
    opened = {int(e) for e in open_ends}
    r = np.asarray(radii, float)
    E = np.asarray(edges, np.int64)
    rows = []
    for a, b, _ in np.asarray(found, float).reshape(-1, 3):
        a, b = int(a), int(b)
        half = length * (r[a] + r[b])
        ta, tb = _tangent(P, E, a), _tangent(P, E, b)
        sa, sb = _axis(P, E, a, ta, half), _axis(P, E, b, tb, half)
        ca, cb = _segment_closest(sa.mean(axis=0), ta, sb.mean(axis=0), tb, 0.5 * np.linalg.norm(sa[1] - sa[0]), 0.5 * np.linalg.norm(sb[1] - sb[0]))
        d = float(np.linalg.norm(cb - ca))
        if d < 1e-9 * half:  # axes that meet have no plane between them
            continue
        n = (cb - ca) / d
        s = (d * d + r[a] ** 2 - r[b] ** 2) / (2.0 * d)
        rows.append((ca + s * n, n, sa, sb,
                     inflate * np.array([r[a], r[b]]), half + inflate * max(r[a], r[b]), (a, b),
                     [node in opened and np.count_nonzero(E == node) == 1 for node in (a, b)]))
    if not rows:
        z = np.zeros((0, 3))
        return ContactCuts(z, z, np.zeros((0, 2, 3)), np.zeros((0, 2, 3)), np.zeros((0, 2)), np.zeros(0), np.zeros((0, 2), np.int64))
    cols = list(zip(*rows))
    ended = np.array(cols[7], bool)
    return ContactCuts(*(np.array(c, float) for c in cols[:6]), np.array(cols[6], np.int64), ended if ended.any() else None)


def _segment_distance(y: np.ndarray, seg: np.ndarray) -> np.ndarray:
    """Distance of points ``y`` (m, 3) to the segment ``seg`` (2, 3)."""
    ab = seg[1] - seg[0]
    t = np.clip((y - seg[0]) @ ab / max(float(ab @ ab), 1e-300), 0.0, 1.0)
    return np.linalg.norm(y - (seg[0] + t[:, None] * ab), axis=1)


def _before_end(y: np.ndarray, seg: np.ndarray) -> np.ndarray:
    """Whether points ``y`` lie on the segment's side of the plane through its first point
    normal to it (a tube that ends open at ``seg[0]`` has nothing beyond that plane)."""
    return (y - seg[0]) @ (seg[1] - seg[0]) >= 0.0


def _on_patch(cuts: ContactCuts, k: int, y: np.ndarray) -> np.ndarray:
    """Whether plane points ``y`` of cut ``k`` lie on its patch (inside both inflated tubes,
    and not beyond either vessel's open end: past its cap only the other vessel is there)."""
    on = (_segment_distance(y, cuts.axis_a[k]) < cuts.radius[k, 0]) & (_segment_distance(y, cuts.axis_b[k]) < cuts.radius[k, 1])
    if cuts.open_end is not None:
        for axis, ended in ((cuts.axis_a[k], cuts.open_end[k, 0]), (cuts.axis_b[k], cuts.open_end[k, 1])):
            if ended:
                on &= _before_end(y, axis)
    return on


def cut_feet(cuts: ContactCuts, points: np.ndarray, inside) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Nearest cut foot of each point: the point's foot on a cut's plane where that foot lies
    on the patch and inside the vessel (``inside(feet) > 0``, a signed distance).

    Returns (distance (n,), inf where none; foot (n, 3); signed side (n,): +1 on the
    side the normal points to, 0 where none; the cut's index (n,), -1 where none)."""
    p = np.asarray(points, float).reshape(-1, 3)
    n = len(p)
    dist = np.full(n, np.inf)
    foot = p.copy()
    side = np.zeros(n)
    which = np.full(n, -1, np.int64)
    for k in range(len(cuts)):
        near = np.flatnonzero(np.sum((p - cuts.centre[k]) ** 2, axis=1) < cuts.reach[k] ** 2)
        if not len(near):
            continue
        h = (p[near] - cuts.centre[k]) @ cuts.normal[k]
        y = p[near] - h[:, None] * cuts.normal[k]
        on = (np.abs(h) < dist[near]) & _on_patch(cuts, k, y)
        if not on.any():
            continue
        idx, y, h = near[on], y[on], h[on]
        ok = np.asarray(inside(y), float) > 0
        idx, y, h = idx[ok], y[ok], h[ok]
        dist[idx], foot[idx], side[idx], which[idx] = np.abs(h), y, np.where(h >= 0, 1.0, -1.0), k
    return dist, foot, side, which


def _near_any(cuts: ContactCuts, p: np.ndarray) -> np.ndarray:
    """Indices of the points within some cut's reach (a point that is has its nearest cut
    centre within the largest reach: one tree query, then the exact test on those few;
    the optimisers ask many small batches, a whole-brain tree has dozens of cuts)."""
    if not len(p):
        return np.zeros(0, np.int64)
    d, _ = cuts.tree.query(p, distance_upper_bound=float(cuts.reach.max()))
    cand = np.flatnonzero(np.isfinite(d))
    if not len(cand):
        return cand
    # every candidate against every cut at once (a Python loop over the cuts cost ~3 us a
    # cut and call; the same sums of three squares, so the same points)
    gap = p[cand][:, None, :] - cuts.centre[None, :, :]
    near = (np.sum(gap**2, axis=2) < cuts.reach**2).any(axis=1)
    return cand[near]


def _points(points) -> np.ndarray:
    return np.ascontiguousarray(np.asarray(points, np.float64).reshape(-1, 3))


def _nearer_cuts(cuts: ContactCuts, p: np.ndarray, found, inside):
    """``found`` (closest points, distances, faces of the wall) with the cut foot wherever a
    cut is nearer than the wall (face -1). The distances may be signed (positive inside) or
    not: a point outside the vessel (distance <= 0) keeps the wall, the cut is no boundary there."""
    closest, d, face = found
    near = _near_any(cuts, p)
    if not len(near):
        return closest, d, face
    closest, d, face = closest.copy(), d.copy(), face.copy()
    h, y, _, _ = cut_feet(cuts, p[near], inside)
    cut = (h < np.abs(d[near])) & (d[near] > 0)
    i = near[cut]
    closest[i], d[i], face[i] = y[cut], h[cut], ON_CUT
    return closest, d, face


class CutSurface:
    """A surface query (:class:`~vmesh.geometry.surface_query.SurfaceQuery`) of the vessel
    interior minus the contact cuts; every other member is the wrapped query's."""

    def __init__(self, inner, cuts: ContactCuts):
        self.inner = inner
        self.cuts = cuts

    def __getattr__(self, name):
        if name == "inner":  # not set yet (copy, unpickling): no recursion
            raise AttributeError(name)
        return getattr(self.inner, name)

    @property
    def fine(self):
        return self if self.inner.fine is self.inner else CutSurface(self.inner.fine, self.cuts)

    @property
    def coarse(self):
        return self if self.inner.coarse is self.inner else CutSurface(self.inner.coarse, self.cuts)

    def project(self, points):
        p = _points(points)
        return _nearer_cuts(self.cuts, p, self.inner.project(p), self.inner.distance)

    def distance(self, points):
        return self.project(points)[1]

    def closest_points(self, points):
        return self.project(points)[0]

    def gradient(self, points):
        p = _points(points)
        g = self.inner.gradient(p)
        near = _near_any(self.cuts, p)
        if len(near):
            g = g.copy()
            d = self.inner.distance(p[near])
            h, _, side, which = cut_feet(self.cuts, p[near], self.inner.distance)
            cut = (h < np.abs(d)) & (d > 0)
            g[near[cut]] = side[cut, None] * self.cuts.normal[which[cut]]
        return g

    def intersect_lines(self, points, directions, reach, side=None):
        p = _points(points)
        dirs = np.ascontiguousarray(np.asarray(directions, np.float64).reshape(-1, 3))
        moved, hit = self.inner.intersect_lines(p, dirs, reach, side)
        near = _near_any(self.cuts, p)
        if not len(near):
            return moved, hit
        moved, hit = moved.copy(), hit.copy()
        reach = np.broadcast_to(np.asarray(reach, float), (len(p),))
        t_wall = np.where(hit, np.einsum("ij,ij->i", moved - p, dirs) / np.maximum(np.einsum("ij,ij->i", dirs, dirs), 1e-300), np.inf)
        for k in range(len(self.cuts)):
            c, nk = self.cuts.centre[k], self.cuts.normal[k]
            q, d = p[near], dirs[near]
            dn = d @ nk
            with np.errstate(divide="ignore", invalid="ignore"):
                t = -((q - c) @ nk) / dn
            ok = np.isfinite(t) & (np.abs(t) <= reach[near]) & (np.abs(t) < np.abs(t_wall[near]))
            if side is not None:
                ok &= t * np.asarray(side, float).reshape(-1)[near] >= 0
            if not ok.any():
                continue
            y = q[ok] + t[ok, None] * d[ok]
            on = _on_patch(self.cuts, k, y)
            if on.any():
                on[on] = np.asarray(self.inner.distance(y[on]), float) > 0
            i = near[np.flatnonzero(ok)[on]]
            moved[i], hit[i], t_wall[i] = y[on], True, t[ok][on]
        return moved, hit


class CutProjector:
    """A wall projector (:class:`~vmesh.geometry.projection.SurfaceProjector`) onto the wall
    and the contact cuts: a point goes to its cut foot where that is nearer than the wall
    (face index -1). ``inside`` is the vessel's signed distance (cut feet outside the
    vessel are no boundary); ``tree`` stays the wall's."""

    def __init__(self, inner, cuts: ContactCuts, inside):
        self.inner = inner
        self.cuts = cuts
        self.inside = inside

    @property
    def tree(self):
        return self.inner.tree

    def project(self, points):
        p = _points(points)
        return _nearer_cuts(self.cuts, p, self.inner.project(p), self.inside)

    def __call__(self, points):
        return self.project(points)[0]


def with_cuts(query, projector, cuts: ContactCuts | None):
    """``query`` and ``projector`` seeing the cuts (unchanged when there are none)."""
    if cuts is None or not len(cuts):
        return query, projector
    q = CutSurface(query, cuts) if query is not None else None
    inside = (query.fine if query is not None else None)
    pr = projector
    if projector is not None and inside is not None:
        pr = CutProjector(projector, cuts, inside.distance) if hasattr(projector, "project") else q.closest_points
    return q, pr
