"""Side sacs on a vessel's path: split off as branches of their own (stage 4 of the extraction).

An aneurysm sac wider than its parent vessel and close beside it swallows the parent's
medial axis: thinning runs the parent's path through the sac's centre (a junction there,
with the dome's spurs), and once the spurs are pruned that junction has degree 2 and is
dissolved like any other. Resampling then centres the path back on the parent's axis, no
skeleton node is left in the sac, and the mesh leaves its dome out (seed 1 g0015
extracted). Such a detour is recognised on the path itself: the inscribed radius peaks at
a point whose ball is clearly wider than the vessel on both sides of it, the vessel runs on
past the ball on both sides, and the ball's centre lies outside the parent's tube (off the
chord the path leaves the ball by). The path is straightened along that chord and the sac
becomes a side branch from the chord's point nearest its centre, as a given centerline has
it. A fusiform aneurysm (the ball centred on
the path's chord) and a bend (no wider ball; the chord leaves the vessel) stay as they are.
"""

from __future__ import annotations

import numpy as np

from .branch_graph import BranchGraph
from .probe import SdfFunction, _arclength, evaluate_sdf

#: The sac's inscribed radius over the vessel's on both sides (``ends_in_bulb`` takes 1.15
#: as a bulb; a sac taken off the path must be clearly wider).
SAC_RISE = 1.25
#: The chord (the straightened path) must stay this deep, x the vessel's radius.
CHORD_DEPTH = 0.5


def _side_radius(rad: np.ndarray, s: np.ndarray, start: int, step: int, reach: float) -> float:
    """Median inscribed radius along the path from index ``start`` outwards (``step`` +-1),
    over an arclength of ``reach``; the vessel's radius beside the sac."""
    idx = np.arange(start, -1 if step < 0 else len(rad), step)
    within = idx[np.abs(s[idx] - s[start]) <= reach]  # holds ``start`` itself
    return float(np.median(rad[within]))


def _sac_on_path(pts: np.ndarray, rad: np.ndarray, sdf: SdfFunction, spacing: float, rise: float, peaks: int = 4):
    """The sac a branch's path (points and radii, end nodes included) runs through, or None.

    The ``peaks`` widest balls along the path (each the widest within its own ball) are
    tried in turn. Returns the indices ``(a, peak, b)`` (the path leaves the peak's ball at
    ``a`` and ``b``), the foot of the peak on the chord ``a``-``b`` and the vessel's radius
    beside it.
    """
    if len(pts) < 5:
        return None
    s = _arclength(pts)
    open_ = np.ones(len(pts), bool)
    open_[[0, -1]] = False
    for _ in range(peaks):
        if not open_.any():
            return None
        peak = int(np.flatnonzero(open_)[np.argmax(rad[open_])])
        inside = np.linalg.norm(pts - pts[peak], axis=1) < rad[peak]
        open_ &= ~inside
        found = _sac_at(pts, rad, s, peak, ~inside, sdf, spacing, rise)
        if found is not None:
            return found
    return None


def _sac_at(pts, rad, s, peak, outside, sdf, spacing, rise):
    """:func:`_sac_on_path` for one peak (``outside``: the path's points outside its ball)."""
    centre, r_sac = pts[peak], rad[peak]
    before, after = np.flatnonzero(outside[:peak]), np.flatnonzero(outside[peak:]) + peak
    if not len(before) or not len(after):
        return None  # the ball reaches an end of the branch (a sac at a junction or end: a branch already)
    a, b = int(before[-1]), int(after[0])
    if min(s[a], s[-1] - s[b]) < r_sac:
        return None  # the vessel does not run on a sac radius past the ball on both sides: a widening near its end
    r_vessel = max(_side_radius(rad, s, a, -1, 2.0 * r_sac), _side_radius(rad, s, b, 1, 2.0 * r_sac))
    if r_sac < rise * r_vessel:
        return None
    chord = pts[b] - pts[a]
    length = float(np.linalg.norm(chord))
    t = float(np.dot(centre - pts[a], chord)) / max(length, 1e-12) ** 2
    if min(t, 1.0 - t) * length < spacing:
        return None  # the centre is not beside the chord (within a voxel of an end or past it): no junction there
    foot = pts[a] + t * chord
    if np.linalg.norm(centre - foot) < r_vessel:
        return None  # the ball's centre lies in the vessel's tube: a fusiform widening, not a side sac
    samples = pts[a] + np.linspace(0.0, 1.0, max(3, int(np.ceil(np.linalg.norm(chord) / spacing)) + 1))[:, None] * chord
    if evaluate_sdf(sdf, samples).min() < CHORD_DEPTH * r_vessel:
        return None  # the chord cuts out of the vessel: a bend, not a detour
    return a, peak, b, foot, r_vessel


def _segment(p: np.ndarray, q: np.ndarray, spacing: float) -> np.ndarray:
    """Interior points of the segment ``p``-``q``, about ``spacing`` apart."""
    n = max(1, int(np.ceil(np.linalg.norm(q - p) / spacing)))
    return p + np.linspace(0.0, 1.0, n + 1)[1:-1, None] * (q - p)


def split_side_sacs(graph: BranchGraph, sdf: SdfFunction, spacing: float, rise: float = SAC_RISE) -> int:
    """Take every side sac off the path of the branch that runs through it (module doc).

    The branch's points between where it enters and leaves the sac's ball are replaced by
    the straight chord between those two points, with a new junction on it nearest the
    sac's centre and a new terminal branch from there to the sac's centre (its end then
    placed into the dome by :func:`~.ends.place_ends`). Radii of new points are the signed
    distance. Returns the number of sacs split off.
    """
    split = 0
    todo = [branch for branch in graph.branches() if branch[0] != branch[1]]
    while todo:  # each branch once; a split branch's two pieces again (one may hold a second sac)
        u, v, k = todo.pop(0)
        pts, rad = graph.polyline(u, v, k, start=u)
        found = _sac_on_path(pts, rad, sdf, spacing, rise)
        if found is None:
            continue
        a, peak, b, foot, _ = found
        before, after = _segment(pts[a], foot, spacing), _segment(foot, pts[b], spacing)
        into = _segment(foot, pts[peak], spacing)
        depth = evaluate_sdf(sdf, np.concatenate([before, after, into, foot[None]]))
        d1, d2, d3 = np.split(depth[:-1], np.cumsum([len(before), len(after)]))
        graph.graph.remove_edge(u, v, k)
        junction = graph.add_node(foot, depth[-1])
        sac = graph.add_node(pts[peak], rad[peak])
        first = graph.add_branch(u, junction, np.concatenate([pts[1 : a + 1], before]), np.concatenate([rad[1 : a + 1], d1]))
        second = graph.add_branch(junction, v, np.concatenate([after, pts[b:-1]]), np.concatenate([d2, rad[b:-1]]))
        graph.add_branch(junction, sac, into, d3)
        todo += [(u, junction, first), (junction, v, second)]
        split += 1
    return split
