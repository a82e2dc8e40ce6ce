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
leave it, standing out of it by at least that radius, and ending free of the rest's other
branches, :func:`_ends_free`), one at a time (the largest missing part first; it then joins
the rest), and never a candidate reaching a cap, whose end :func:`~.ends.place_ends` gives
(docs/coverage.md, h20/stubs, h21/stubs). A held stub's end is marked ``closed_stub``: it
ends where its axis meets the wall, not at the nearest cap (:func:`~.ends.place_ends`). Placed,
a held stub whose end lies in another branch's lumen, or whose end section meets a neighbour's
wall, is dropped again (:func:`drop_stubs_in_neighbours`, h22/stubs).
"""

from __future__ import annotations

import numpy as np

from ..coverage import DEPTH, DISTANCE, END_DEPTH, PATCH_AREA, judge_end_and_side
from ..rays import RAY_REACH


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


class Wall:
    """The wall the rule judges (not its caps) and its point tree, built once per extraction
    (:func:`~.extract.clean_branch_graph` judges every pruning pass against it)."""

    def __init__(self, wall):
        points, area, on_cap = wall if len(wall) == 3 else (*wall, np.zeros(len(wall[0]), bool))
        from scipy.spatial import cKDTree

        self.points, self.area, self.caps = points[~on_cap], area[~on_cap], points[on_cap]
        self.tree = cKDTree(self.points)


def spurs_explaining_wall(
    graph, wall, spurs, spacing: float, distance: float = DISTANCE, patch_area: float = PATCH_AREA,
    depth: float = DEPTH, end_depth: float = END_DEPTH, k: int = 8, details: list | None = None,
) -> np.ndarray:
    """Which spur candidates alone explain a part of the wall the verdict would call missing.

    The candidates are held one at a time, the one leaving the largest missing part first,
    and a held candidate joins the rest: two candidates along one stub (or one vessel's
    end) explain the same wall, and the second is then explained by the first. After a
    hold only the candidates it can change are judged again (:class:`_Judge`).

    Parameters
    ----------
    graph : BranchGraph
    wall : (centroids (m, 3), areas (m,)[, on a cap (m,)]) or Wall
        The surface's triangles (:func:`surface_samples`), or their :class:`Wall`.
    spurs : list of (u, v, key, tip, base)
        The candidates of one pruning round.
    spacing : float
        The voxel size: the medial samples are voxel centres, so a wall point up to one
        voxel outside the balls is explained (the sampled axis's own resolution).
    distance, patch_area, depth, end_depth : float
        ``check_coverage``'s: a wall point farther than ``distance`` local radii (plus
        ``spacing``) outside the rest's balls is unexplained; a candidate's unexplained
        wall is split into its end wall (past a free end of the rest, within ``1 + end_depth``
        of its radii) and its side wall (the rest), judged apart as the verdict judges a
        patch's (:func:`~vmesh.geometry.coverage.judge_end_and_side`): either is a missing
        part when it spans more than ``patch_area`` cross-sections and reaches deeper than
        ``depth`` radii (``end_depth`` for the end wall), the side wall's radius its own where
        it stands out by at least that (the candidate's balls outside the rest's, median).
        Only a missing side wall holds a candidate.
    k : int
        Balls looked at per wall point (the nearest centres).
    details : list, optional
        Receives one dict per candidate (area, depth, radii, the verdict) for probes.

    Returns
    -------
    numpy.ndarray of bool
        One per candidate: True where pruning it would leave wall unexplained.
    """
    wall = wall if isinstance(wall, Wall) else Wall(wall)
    held = np.zeros(len(spurs), bool)
    found = [{"tip": graph.pos(s[3]).round(3).tolist(), "junction": graph.pos(s[4]).round(3).tolist(),
              "junction_r": graph.radius(s[4]), "length": graph.length(*s[:3]), "held": False} for s in spurs]
    if spurs:
        # a candidate whose balls reach a cap is an open end: place_ends gives every cap its
        # end (matched or attached), and a branch held there besides can leave the builder
        # two branches into one short stub (as spurs_at_flat_ends leaves caps out)
        at_cap = _reaches(graph, spurs, wall.caps, spacing, distance)
        held[at_cap] = True  # out of the running (in the rest); cleared below
        free = _ends_free(graph, spurs)
        judge = _Judge(graph, wall, spurs, np.flatnonzero(~held), spacing, distance, end_depth, k) if not held.all() else None
        while not held.all():
            open_ = np.flatnonzero(~held)
            judged = [judge.parts[i] for i in open_]
            own_r = np.array([p["own_r"] for p in judged])
            side_wall, end_wall = (np.array([p[kind] for p in judged], float).reshape(-1, 3).T for kind in ("side_wall", "end_wall"))
            # the verdict's rule: the part's side wall and end wall judged apart
            missing, side_missing, _, sections, depth_rel, _ = judge_end_and_side(side_wall, end_wall, own_r, patch_area, depth, end_depth)
            # a side vessel: its side wall missing by its own radius, narrower than the rest
            # where it leaves it and standing out of it by at least that radius (as the verdict
            # names one left out), ending free of the rest; wall a vessel-wide candidate explains
            # is the vessel's own, which the rest's path runs beside where noise or a contact
            # displaced it, and resampling centres
            side_area, side_deep, side_rest_r = side_wall
            side = side_missing & (own_r < side_rest_r) & (side_deep >= own_r) & free[open_]
            for i, p, sec, rel, is_side in zip(open_, judged, sections, depth_rel, side):
                found[i].update(p, sections=float(sec), depth_rel=float(rel), side=bool(is_side), ends_free=bool(free[i]))
            if not side.any():
                break
            i = open_[np.argmax(np.where(side, side_area, -1.0))]
            held[i] = found[i]["held"] = True
            judge.hold(i, np.flatnonzero(~held))
        held[at_cap] = False
        for i in np.flatnonzero(at_cap):
            found[i]["at_cap"] = True
    if details is not None:
        details.extend(found)
    return held


def _ends_free(graph, spurs) -> np.ndarray:
    """Which candidates end free of the rest: their tip's ball overlaps no ball of a branch
    of the rest that does not meet their junction.

    A side vessel leaves the rest at its junction and ends on its own. A candidate whose
    tip reaches another branch of the rest joins two places of the rest through the lumen:
    it runs beside the rest's path between them (the main vessel's axis beside its fused
    acute daughters, the rest's path displaced towards one of them, seed 0 g0006 extracted),
    and the wall it explains is that vessel's, which the rest carries past the branch it
    reaches. Held, the junction gets two near-parallel vessel-wide branches that no block
    structure separates (docs/coverage.md, h21/stubs). The rest is the graph without the
    round's candidates.
    """
    from scipy.spatial import cKDTree

    out = np.ones(len(spurs), bool)
    candidate = {e for s in spurs for e in (s[:3], (s[1], s[0], s[2]))}
    rest = [e for e in graph.branches() if e not in candidate]
    if not spurs or not rest:
        return out
    centres, radii, ends = [], [], []
    for u, v, key in rest:
        pts, rad = graph.polyline(u, v, key)
        centres.append(pts)
        radii.append(rad)
        ends.append(np.tile([u, v], (len(rad), 1)))
    centres, radii, ends = np.concatenate(centres), np.concatenate(radii), np.concatenate(ends)
    tips = np.array([graph.pos(s[3]) for s in spurs])
    tip_r = np.array([graph.radius(s[3]) for s in spurs])
    near = cKDTree(centres).query_ball_point(tips, tip_r + radii.max())
    for i, (j, (_, _, _, _, base)) in enumerate(zip(near, spurs)):
        j = np.asarray(j, np.int64)
        j = j[(ends[j] != base).all(axis=1)]  # the branches of its own junction: where it leaves the rest
        out[i] = not (np.linalg.norm(centres[j] - tips[i], axis=1) < radii[j] + tip_r[i]).any()
    return out


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


class _Judge:
    """Per open candidate, the wall it explains that the rest (the graph without the open
    candidates) does not (:meth:`judge`), kept up to date as candidates are held.

    A hold adds the held branch's balls to the rest and changes the rest's free ends only at
    its two nodes. A candidate's part depends on the rest only through the ``k`` nearest
    rest centres of its points (its wall and its own centres) and the free ends near its
    wall: it is judged again only when a centre of the held branch comes within its points'
    ``k``-th nearest distance, or a free end that came or went lies within reach of its wall.
    The rest's tree is built once; the held branches' centres have a tree of their own.
    """

    def __init__(self, graph, wall, spurs, open_, spacing, distance, end_depth, k):
        from scipy.spatial import cKDTree

        self.graph, self.wall, self.spurs = graph, wall, spurs
        self.spacing, self.distance, self.end_depth, self.k = spacing, distance, end_depth, k
        centres, radii, owner = _balls(graph, [spurs[i] for i in open_])
        mine = owner >= 0
        self.rest = [cKDTree(centres[~mine]), radii[~mine], None, np.zeros(0), np.zeros((0, 3))]
        hits = wall.tree.query_ball_point(centres[mine], radii[mine] * (1.0 + distance) + spacing)
        of = owner[mine]
        self.balls = {}  # per candidate: the wall near its balls, its own centres and radii
        for n, i in enumerate(open_):
            near = np.unique(np.concatenate([np.asarray(h, np.int64) for h in hits[of == n]] + [np.zeros(0, np.int64)]))
            self.balls[i] = (near, centres[mine][of == n], radii[mine][of == n])
        self.lost = {}
        for i in open_:
            for node in spurs[i][3:]:
                self.lost[node] = self.lost.get(node, 0) + 1
        self.cand = {e for i in open_ for e in (spurs[i][:3], (spurs[i][1], spurs[i][0], spurs[i][2]))}
        self.ends = {node: end for node in self.lost if (end := self._free_end(node)) is not None}
        self.end_arrays = None  # the free ends' positions, radii and tangents, when asked for
        self.parts, self.probe = {}, {}
        for i in open_:
            self.judge(i)

    def _free_end(self, node, span: float = 2.0):
        """The rest's free end at ``node``, a node of an open candidate left with one branch
        (its position, radius and outward tangent, from ``span`` radii back along that branch),
        or None. A held candidate's tip is none (the rule's free ends are the junctions the
        open candidates leave)."""
        graph, lost = self.graph, self.lost.get(node, 0)
        if lost == 0 or graph.degree(node) - lost != 1:
            return None
        u, v, k = next(e for e in graph.graph.edges(node, keys=True) if e not in self.cand)
        pts, rad = graph.polyline(u, v, k, start=node)
        s = np.cumsum(np.r_[0.0, np.linalg.norm(np.diff(pts, axis=0), axis=1)])
        t = pts[0] - pts[min(int(np.searchsorted(s, span * rad[0])), len(pts) - 1)]
        return pts[0], rad[0], t / max(np.linalg.norm(t), 1e-300)

    def outside_rest(self, x):
        """How far points lie outside the rest's balls (the best of their ``k`` nearest
        centres), that ball's radius, and the ``k``-th nearest centre's distance."""
        tree, rest_r, held_tree, held_r, _ = self.rest
        d, r = [np.zeros((len(x), 0))], [np.zeros((len(x), 0))]
        for t, rr in ((tree, rest_r), (held_tree, held_r)):
            if t is not None and len(rr):
                dd, j = t.query(x, k=min(self.k, len(rr)))
                d.append(dd.reshape(len(x), -1))
                r.append(rr[j.reshape(len(x), -1)])
        d, r = np.hstack(d), np.hstack(r)
        kk = min(self.k, d.shape[1])
        order = np.argsort(d, axis=1, kind="stable")[:, :kk]
        d, r = np.take_along_axis(d, order, 1), np.take_along_axis(r, order, 1)
        rows, best = np.arange(len(x)), np.argmin(d - r, axis=1)
        kth = d[:, -1] if kk == self.k else np.full(len(x), np.inf)
        return d[rows, best] - r[rows, best], r[rows, best], kth

    def judge(self, i) -> None:
        """Candidate ``i``'s part: the area of the wall it alone explains, its deepest point's
        distance outside the rest's balls and the rest's radius there, its own radius (its
        balls outside the rest's, median), and the same three (area, depth, radius) of its
        **side wall** and of its **end wall** (past a free end of the rest), which are judged
        apart as the verdict judges a patch's (:func:`~vmesh.geometry.coverage.judge_end_and_side`)."""
        points, area = self.wall.points, self.wall.area
        near, own_c, own_r = self.balls[i]
        none = (0.0, 0.0, 1.0)
        part = self.parts[i] = {"area": 0.0, "depth": 0.0, "rest_r": 1.0, "own_r": np.inf, "side_wall": none, "end_wall": none}
        x = np.concatenate([points[near], own_c])
        if len(near) == 0:
            self.probe.pop(i, None)  # nothing the rest can change
            return
        all_excess, all_r, kth = self.outside_rest(x)
        mid = x.mean(axis=0)  # and a ball around them, for the quick test
        self.probe[i] = (x, kth, mid, float(np.linalg.norm(x - mid, axis=1).max()) + kth.max())
        excess, r_local = all_excess[: len(near)], all_r[: len(near)]
        out = excess > self.distance * r_local + self.spacing
        if not out.any():
            return
        sel, deep = near[out], int(np.argmax(excess[out]))
        # past a free end of the rest: where place_ends extends the vessel (a flat end's rim)
        if self.end_arrays is None:
            ends = list(self.ends.values())
            self.end_arrays = (np.reshape([e[0] for e in ends], (-1, 3)), np.array([e[1] for e in ends], float), np.reshape([e[2] for e in ends], (-1, 3)))
        e_pos, e_r, e_t = self.end_arrays
        mid, size = self.probe[i][2:]
        close = np.linalg.norm(e_pos - mid, axis=1) <= size + (1.0 + self.end_depth) * e_r  # the others are out of reach
        e_pos, e_r, e_t = e_pos[close], e_r[close], e_t[close]
        past = np.zeros(len(sel), bool)
        if len(e_r):
            rel = points[sel][:, None, :] - e_pos[None]
            along = np.einsum("pej,ej->pe", rel, e_t)
            past = ((along > 0) & (np.linalg.norm(rel, axis=2) < (1.0 + self.end_depth) * e_r[None])).any(axis=1)
        own = own_r[all_excess[len(near):] > 0]
        part.update(area=float(area[sel].sum()), depth=float(excess[out][deep]), rest_r=float(r_local[out][deep]),
                    own_r=float(np.median(own)) if len(own) else np.inf)
        for kind, mask in (("side_wall", ~past), ("end_wall", past)):
            if mask.any():
                k = int(np.argmax(np.where(mask, excess[out], -np.inf)))
                part[kind] = (float(area[sel][mask].sum()), float(excess[out][k]), float(r_local[out][k]))

    def hold(self, h, open_) -> None:
        """Candidate ``h`` joins the rest; judge again the ``open_`` candidates it can change."""
        from scipy.spatial import cKDTree

        u, v, key, tip, base = self.spurs[h]
        pts, rad = self.graph.polyline(u, v, key)
        tree, rest_r, _, held_r, held_c = self.rest
        held_c, held_r = np.vstack([held_c, pts]), np.r_[held_r, rad]
        self.rest = [tree, rest_r, cKDTree(held_c), held_r, held_c]
        self.cand -= {(u, v, key), (v, u, key)}
        changed = []
        for node in (tip, base):
            self.lost[node] -= 1
            before, after = self.ends.pop(node, None), self._free_end(node)
            if after is not None:
                self.ends[node] = after
            if (before is None) != (after is None):
                changed.append(before if before is not None else after)
                self.end_arrays = None
        new_tree, centre = cKDTree(pts), pts.mean(axis=0)
        reach = float(np.linalg.norm(pts - centre, axis=1).max())
        todo = [i for i in open_ if i in self.probe]
        if not todo:
            return
        mid = np.array([self.probe[i][2] for i in todo])
        size = np.array([self.probe[i][3] for i in todo])  # plus the k-th nearest distance
        near_h = np.linalg.norm(mid - centre, axis=1) <= size + reach
        for e in changed:  # a free end that came or went: the wall within its reach
            near_h |= np.linalg.norm(mid - e[0], axis=1) <= size + (1.0 + self.end_depth) * e[1]
        for i in np.asarray(todo)[near_h]:
            x, kth = self.probe[i][:2]
            if changed or (new_tree.query(x)[0] <= kth).any():
                self.judge(i)


def drop_stubs_in_neighbours(graph, sdf=None, spacing: float = 0.0, rays: int = 16) -> tuple[int, list]:
    """Drop the held stubs whose placed end lies in a neighbour's lumen.

    A stub held for its wall (``closed_stub``) is extended by :func:`~.ends.place_ends`
    along its axis to the wall. When that end lies inside a ball of another branch (its
    centre closer to the end than its radius), the stub runs along that branch's lumen
    rather than out of it: the wall it was held for is the neighbour's, which the
    neighbour's section reaches, and the stub never parts from it, so no block structure
    separates the two (a held stub 10 degrees from its sibling, its end 0.64 from the
    sibling's axis at radius 1.01; docs/coverage.md, h22/stubs). With ``sdf``, a stub's end section is
    judged too (:func:`_section_leaves`): where one of its ``rays`` meets wall that another
    branch's balls explain and its own do not, the section's plane runs along a
    neighbour's lumen, and its wall there is the neighbour's. A side vessel's end stands out
    of its parent by at least its own radius: it lies in no other ball, and its section meets
    its own wall all round. Such a stub is removed and its junction, left with two branches,
    dissolved. Every stub is judged on the graph :func:`~.ends.place_ends` gave: held stubs
    whose sections meet each other's wall (pieces of one wide lumen's medial sheet) are all
    dropped, not the last of them kept for the wall the others left. An end within its own
    junction's ball (a stub shorter than its parent's radius, ending at its own cap) has not
    left the ball it shares with its
    siblings and is not judged, nor is an end at a cap (an open end's section lies in the
    cap's plane). Returns how many were dropped and the junctions left with one branch
    (every sibling dropped): ends the caller must place (:func:`~.ends.extend_left_ends`).
    """
    from scipy.spatial import cKDTree

    stubs = [n for n, data in graph.graph.nodes(data=True) if data.get("closed_stub") and graph.degree(n) == 1]
    if not stubs:
        return 0, []
    # every branch's balls once, with the branch each belongs to: the graph is not changed
    # while the stubs are judged (two held stubs in one lumen explain each other's wall)
    branches = graph.branches()
    index = {(frozenset(e[:2]), e[2]): i for i, e in enumerate(branches)}
    lines = [graph.polyline(*e) for e in branches]
    centres, radii = np.concatenate([p for p, _ in lines]), np.concatenate([r for _, r in lines])
    owner = np.repeat(np.arange(len(lines)), [len(p) for p, _ in lines])
    tree = cKDTree(centres)
    drop = []
    for node in stubs:
        (u, v, key), = list(graph.graph.edges(node, keys=True))
        end, base = graph.pos(node), graph.other(u, v, node)
        if np.linalg.norm(end - graph.pos(base)) <= graph.radius(base) or graph.graph.nodes[node].get("end", ("",))[0] == "cap":
            continue  # it ends within its junction's ball, which it shares with its siblings, or at a cap
        others = owner != index[(frozenset((u, v)), key)]
        if not others.any():
            continue
        near = np.asarray(tree.query_ball_point(end, float(radii[others].max())), np.int64)
        near = near[others[near]]
        if (np.linalg.norm(centres[near] - end, axis=1) < radii[near]).any() or (
            sdf is not None and _section_leaves(graph, (u, v, key), base, centres[others], radii[others], sdf, spacing, rays)
        ):
            drop.append(node)
    bases = set()
    for node in drop:  # all removed before any junction is dissolved (two at one junction)
        (u, v, key), = list(graph.graph.edges(node, keys=True))
        bases.add(graph.other(u, v, node))
        graph.graph.remove_edge(u, v, key)
        graph.graph.remove_node(node)
    left = []
    for base in bases:
        if graph.degree(base) == 2:
            graph.dissolve(base)
        elif graph.degree(base) == 1:  # every sibling dropped: the base is now its vessel's end
            left.append(base)
        elif graph.degree(base) == 0:
            graph.graph.remove_node(base)
    return len(drop), left


def _section_leaves(graph, branch, base, centres, radii, sdf, spacing, rays, reach: float = RAY_REACH) -> bool:
    """Whether a stub's end section (the plane through its end across its end tangent) has a
    ray whose wall another branch's balls (``centres``, ``radii``) explain and the stub's own
    balls outside its junction's ball do not, by the verdict's rule (within ``DISTANCE`` radii
    plus ``spacing``); rays look ``reach`` end radii far, as the block builder's sections do."""
    from .ends import _end_tangent
    from .probe import distance_to_wall, plane_basis

    pts, rad = graph.polyline(*branch, start=base)
    own = np.linalg.norm(pts - graph.pos(base), axis=1) > graph.radius(base)
    if not own.any():
        return False
    end, r_end = pts[-1], rad[-1]
    e1, e2 = plane_basis(_end_tangent(pts, max(2.0 * r_end, 4 * spacing))[None])
    angle = np.linspace(0.0, 2.0 * np.pi, rays, endpoint=False)
    dirs = np.cos(angle)[:, None] * e1 + np.sin(angle)[:, None] * e2
    length = distance_to_wall(sdf, np.tile(end, (rays, 1)), dirs, reach * r_end, samples=48)
    hits = end + length[np.isfinite(length), None] * dirs[np.isfinite(length)]

    def explained(c, r):
        gap = np.linalg.norm(hits[:, None] - c[None], axis=2) - r[None]
        return (gap <= DISTANCE * r[None] + spacing).any(axis=1)

    return bool(len(hits)) and bool((explained(centres, radii) & ~explained(pts[own], rad[own])).any())
