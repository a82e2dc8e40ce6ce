"""Spur candidates that alone explain part of the wall: side stubs, not noise.

:meth:`~.branch_graph.BranchGraph.prune_spurs` takes a terminal branch whose inscribed
balls barely leave its junction's ball for noise. A short side stub (a vessel of 0.3-0.6
of its parent's radius standing one or two of its own radii out) scores the same, and
pruning it leaves the stub out of the mesh, which ``check_coverage`` then names as a
missing part. Here a candidate is noise only when the wall it alone explains is explained
by the rest of the skeleton too, up to the tolerance ``check_coverage`` allows a missing
part: the extractor and the verdict judge the same wall by the same rule
(:func:`~vmesh.geometry.coverage.judge_patches`), so a branch the verdict would call
missing is not pruned.

"The rest" is the graph without every candidate of the round: the medial axis's fan
towards a flat end face's rim is several candidates at one junction, and without all of
them that junction is a free end of the rest; the rim's wall lies past that end, where
:func:`~.ends.place_ends` extends the vessel, and is judged with the verdict's
``end_depth`` as the wall past a mesh's end face is. A real stub's junction lies on its
parent's path, which the rest keeps, and its wall stands out of the parent's balls by
more than its own radius.

Only side vessels are held (judged by their own radius, narrower than the rest where they
leave it, standing out of it by at least that radius), one at a time (the largest missing
part first; it then joins the rest), and never a candidate reaching a cap, whose end
:func:`~.ends.place_ends` gives (docs/coverage.md, h20/stubs).
"""

from __future__ import annotations

import numpy as np

from ..coverage import DEPTH, DISTANCE, END_DEPTH, PATCH_AREA, judge_patches


def surface_samples(vertices, faces, caps=()) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Centroids and areas of a surface's triangles, and which lie on one of ``caps`` (open
    ends; not the flat regions that may be facets of the wall, ``needs_end``): the verdict
    leaves caps out of the wall, and a candidate reaching a cap is an open end, which
    :func:`~.ends.place_ends` gives its branch."""
    faces = np.asarray(faces, np.int64)
    tri = np.asarray(vertices, float)[faces]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    on_cap = np.zeros(len(faces), bool)
    for cap in caps or ():
        if not getattr(cap, "needs_end", False):
            index = np.asarray(cap.faces, np.int64)
            on_cap[index[(index >= 0) & (index < len(faces))]] = True
    return tri.mean(axis=1), area, on_cap


def _balls(graph, spurs):
    """Every branch's medial samples (centres, radii) and, per sample, the index of the
    candidate it belongs to (-1: the rest). A candidate's junction sample is the rest's."""
    index = {}
    for i, (u, v, key, _, _) in enumerate(spurs):
        index[(u, v, key)] = index[(v, u, key)] = i
    centres, radii, owner = [], [], []
    for u, v, key in graph.branches():
        i = index.get((u, v, key), -1)
        start = spurs[i][4] if i >= 0 else None
        pts, rad = graph.polyline(u, v, key, start=start)
        if i >= 0:
            pts, rad = pts[1:], rad[1:]
        centres.append(pts)
        radii.append(rad)
        owner.append(np.full(len(rad), i))
    return np.concatenate(centres), np.concatenate(radii), np.concatenate(owner)


def _free_ends(graph, spurs, span: float = 2.0):
    """The rest's free ends: nodes left with one branch once the candidates are gone.
    Returns their positions, radii and outward tangents (from ``span`` radii back along
    the branch)."""
    lost = {}
    for _, _, _, tip, base in spurs:
        lost[tip] = lost.get(tip, 0) + 1
        lost[base] = lost.get(base, 0) + 1
    cand = {(u, v, k) for u, v, k, _, _ in spurs} | {(v, u, k) for u, v, k, _, _ in spurs}
    ends, radii, tangents = [], [], []
    for node, n_lost in lost.items():
        if graph.degree(node) - n_lost != 1:
            continue
        u, v, k = next(e for e in graph.graph.edges(node, keys=True) if e not in cand)
        pts, rad = graph.polyline(u, v, k, start=node)
        s = np.cumsum(np.r_[0.0, np.linalg.norm(np.diff(pts, axis=0), axis=1)])
        back = pts[min(int(np.searchsorted(s, span * rad[0])), len(pts) - 1)]
        t = pts[0] - back
        ends.append(pts[0])
        radii.append(rad[0])
        tangents.append(t / max(np.linalg.norm(t), 1e-300))
    return np.reshape(ends, (-1, 3)), np.asarray(radii, float), np.reshape(tangents, (-1, 3))


def spurs_explaining_wall(
    graph, wall, spurs, spacing: float, distance: float = DISTANCE, patch_area: float = PATCH_AREA,
    depth: float = DEPTH, end_depth: float = END_DEPTH, k: int = 8, details: list | None = None,
) -> np.ndarray:
    """Which spur candidates alone explain a part of the wall the verdict would call missing.

    The candidates are held one at a time, the one leaving the largest missing part first,
    and a held candidate joins the rest: two candidates along one stub (or one vessel's
    end) explain the same wall, and the second is then explained by the first.

    Parameters
    ----------
    graph : BranchGraph
    wall : (centroids (m, 3), areas (m,))
        The surface's triangles (:func:`surface_samples`).
    spurs : list of (u, v, key, tip, base)
        The candidates of one pruning round.
    spacing : float
        The voxel size: the medial samples are voxel centres, so a wall point up to one
        voxel outside the balls is explained (the sampled axis's own resolution).
    distance, patch_area, depth, end_depth : float
        ``check_coverage``'s: a wall point farther than ``distance`` local radii (plus
        ``spacing``) outside the rest's balls is unexplained; a candidate's unexplained
        wall is a missing part when it spans more than ``patch_area`` cross-sections and
        reaches deeper than ``depth`` radii (``end_depth`` past a free end of the rest),
        the radius its own where it stands out by at least that (the candidate's balls
        outside the rest's, median).
    k : int
        Balls looked at per wall point (the nearest centres).
    details : list, optional
        Receives one dict per candidate (area, depth, radii, the verdict) for probes.

    Returns
    -------
    numpy.ndarray of bool
        One per candidate: True where pruning it would leave wall unexplained.
    """
    from scipy.spatial import cKDTree

    held = np.zeros(len(spurs), bool)
    points, area, on_cap = wall if len(wall) == 3 else (*wall, np.zeros(len(wall[0]), bool))
    wall = (points[~on_cap], area[~on_cap])
    found = [{"tip": graph.pos(s[3]).round(3).tolist(), "junction": graph.pos(s[4]).round(3).tolist(),
              "junction_r": graph.radius(s[4]), "length": graph.length(*s[:3]), "held": False} for s in spurs]
    if spurs:
        wall_tree = cKDTree(wall[0])
        # a candidate whose balls reach a cap is an open end: place_ends gives every cap its
        # end (matched or attached), and a branch held there besides can leave the builder
        # two branches into one short stub (as spurs_at_flat_ends leaves caps out)
        at_cap = _reaches(graph, spurs, points[on_cap], spacing, distance)
        held[at_cap] = True  # out of the running; cleared below
        while not held.all():
            open_ = np.flatnonzero(~held)
            parts = _unexplained(graph, wall, wall_tree, [spurs[i] for i in open_], spacing, distance, k)
            area, deep, rest_r, own_r, at_end = (np.array([p[key] for p in parts]) for key in ("area", "depth", "rest_r", "own_r", "at_end"))
            missing, sections, depth_rel, _ = judge_patches(area, deep, rest_r, own_r, at_end, patch_area, depth, end_depth)
            # a side vessel: judged by its own radius, narrower than the rest where it leaves
            # it and standing out of it by at least that radius (as the verdict names one left
            # out); wall a vessel-wide candidate explains is the vessel's own, which the rest's
            # path runs beside where noise or a contact displaced it, and resampling centres
            side = missing & ~at_end & (own_r < rest_r) & (deep >= own_r)
            for i, p, sec, rel, is_side in zip(open_, parts, sections, depth_rel, side):
                found[i].update(p, sections=float(sec), depth_rel=float(rel), side=bool(is_side))
            if not side.any():
                break
            i = open_[np.argmax(np.where(side, area, -1.0))]
            held[i] = found[i]["held"] = True
        held[at_cap] = False
        for i in np.flatnonzero(at_cap):
            found[i]["at_cap"] = True
    if details is not None:
        details.extend(found)
    return held


def _reaches(graph, spurs, points, spacing, distance) -> np.ndarray:
    """Which candidates' balls, grown as for the wall they explain, contain one of ``points``."""
    from scipy.spatial import cKDTree

    if len(points) == 0:
        return np.zeros(len(spurs), bool)
    centres, radii, owner = _balls(graph, spurs)
    mine = owner >= 0
    d, _ = cKDTree(points).query(centres[mine])
    inside = d <= radii[mine] * (1.0 + distance) + spacing
    return np.bincount(owner[mine][inside], minlength=len(spurs)) > 0


def _unexplained(graph, wall, wall_tree, spurs, spacing, distance, k) -> list[dict]:
    """Per candidate, the wall it explains that the rest (the graph without ``spurs``) does
    not: its area, its deepest point's distance outside the rest's balls and the rest's
    radius there, whether it lies past a free end of the rest, and the candidate's own
    radius (its balls outside the rest's, median; ``inf`` where none)."""
    from scipy.spatial import cKDTree

    points, area = wall
    centres, radii, owner = _balls(graph, spurs)
    mine = owner >= 0
    rest_tree, rest_r = cKDTree(centres[~mine]), radii[~mine]
    kk = min(k, len(rest_r))

    def outside_rest(x):
        d, j = rest_tree.query(x, k=kk)
        d, j = d.reshape(len(x), -1), j.reshape(len(x), -1)
        best = np.argmin(d - rest_r[j], axis=1)
        rows = np.arange(len(x))
        return d[rows, best] - rest_r[j[rows, best]], rest_r[j[rows, best]]

    # the wall each candidate explains: within its balls up to the tolerance
    hits = wall_tree.query_ball_point(centres[mine], radii[mine] * (1.0 + distance) + spacing)
    sample_of = owner[mine]
    ends, end_r, end_t = _free_ends(graph, spurs)
    parts = []
    for i in range(len(spurs)):
        part = {"area": 0.0, "depth": 0.0, "rest_r": 1.0, "own_r": np.inf, "at_end": False}
        parts.append(part)
        near = np.unique(np.concatenate([np.asarray(h, np.int64) for h in hits[sample_of == i]] + [np.zeros(0, np.int64)]))
        if len(near) == 0:
            continue
        excess, r_local = outside_rest(points[near])
        out = excess > distance * r_local + spacing
        if not out.any():
            continue
        sel, deep = near[out], int(np.argmax(excess[out]))
        # past a free end of the rest: where place_ends extends the vessel (a flat end's rim)
        rel = points[sel][:, None, :] - ends[None]
        along = np.einsum("pej,ej->pe", rel, end_t)
        past = ((along > 0) & (np.linalg.norm(rel, axis=2) < (1.0 + END_DEPTH) * end_r[None])).any(axis=1)
        own_excess, _ = outside_rest(centres[mine][sample_of == i])
        own = radii[mine][sample_of == i][own_excess > 0]
        part.update(area=float(area[sel].sum()), depth=float(excess[out][deep]), rest_r=float(r_local[out][deep]),
                    own_r=float(np.median(own)) if len(own) else np.inf, at_end=bool(area[sel][past].sum() > 0.5 * area[sel].sum()))
    return parts
