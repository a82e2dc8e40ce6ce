"""Skeleton cleaning steps: merging close junctions, separating parallel branches,
reconnecting components, removing spurs, trimming at caps (moved from
:mod:`vmesh.geometry.skeleton_ops`, issue 20)."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from ...skeleton import Skeleton
from .graph import arc_length, polyline_at, branch_paths, branches_at, component_labels, contract_nodes, edge_lengths, END_TAGS, remove_nodes, vector_angle, _union
from .pairs import PAIR_REACH, _move_key, _point_key, _unblockable_moves


def node_scale(skeleton: Skeleton) -> np.ndarray:
    """Per-node length scale: the radius where it is known, else the median known radius,
    else the median segment length (1 where there is none)."""
    r = skeleton.radii
    good = np.isfinite(r) & (r > 0)
    if good.any():
        fill = float(np.median(r[good]))
    else:
        lengths = edge_lengths(skeleton.points, skeleton.edges)
        fill = float(np.median(lengths)) if len(lengths) and np.median(lengths) > 0 else 1.0
    return np.where(good, r, fill)


def merge_close_junctions(skeleton: Skeleton, tolerance: float = 0.5) -> tuple[Skeleton, int]:
    """Merge junctions joined by a branch shorter than ``tolerance`` x the larger of their
    radii into one junction (at the mean of the merged junctions).

    Skeletonisation often splits one junction of four or more branches into two or three
    junctions a short distance apart, or leaves a tiny loop at a junction; both collapse
    (a loop from a junction back to itself when it stays within the junction's diameter of
    it: the tube around it fills its hole).

    Returns
    -------
    skeleton : Skeleton
    n_merged : int
        Number of junctions that disappeared.
    """
    if tolerance <= 0 or skeleton.n_edges == 0:
        return skeleton.copy(), 0
    deg = skeleton.degrees
    scale = node_scale(skeleton)
    paths = branch_paths(skeleton.n_nodes, skeleton.edges)
    merge_sets = []
    for p in paths:
        a, b = p[0], p[-1]
        if deg[a] < 3 or deg[b] < 3:
            continue
        if a == b:  # a loop narrower than the vessel encloses no wall: a hole of a voxel skeleton
            reach = np.linalg.norm(skeleton.points[p] - skeleton.points[a], axis=1).max()
            if reach < 2 * scale[a]:
                merge_sets.append(p)
            continue
        length = arc_length(skeleton.points[p])[-1]
        if length < tolerance * max(scale[a], scale[b]):
            merge_sets.append(p)
    if not merge_sets:
        return skeleton.copy(), 0
    n = skeleton.n_nodes
    rows = np.concatenate([p[:-1] for p in merge_sets])
    cols = np.concatenate([p[1:] for p in merge_sets])
    adj = sp.coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(n, n))
    _, label = connected_components(adj, directed=False)
    involved = np.zeros(n, bool)
    involved[np.concatenate(merge_sets)] = True
    first = np.full(label.max() + 1, n)
    np.minimum.at(first, label, np.arange(n))
    group = np.where(involved, first[label], np.arange(n))
    # a merged junction sits at the mean of the junctions it replaces
    groups, inverse = np.unique(group, return_inverse=True)
    weight = np.where(deg >= 3, 1.0, 1e-9)
    pos = np.zeros((len(groups), 3))
    np.add.at(pos, inverse, skeleton.points * weight[:, None])
    pos /= np.bincount(inverse, weights=weight)[:, None]
    out = contract_nodes(skeleton, group, pos)
    n_merged = int((deg >= 3).sum() - (out.degrees >= 3).sum())
    return out, max(n_merged, 0)


def _pair_angle(m: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angle (radians) at ``m`` between the directions to ``a`` and to ``b`` (row-wise)."""
    return vector_angle(a - m, b - m)


def _parallel_pair(skel: Skeleton, done: set, limit: float, target: float, ahead: float, max_shift: float, distance=None, undone=frozenset(), unit: float = 1.0):
    """The first junction of ``skel`` not in ``done`` with two branches less than ``limit``
    (radians) apart that part by ``target`` within ``max_shift`` x its radius, or farther
    while they share one lumen (with ``distance``; see :func:`separate_parallel_branches`):
    ``(c, pi, ai, pj, aj, star, at, r_at, eps)``, the junction, the two branches from it and
    their arc lengths, the arc length, position and radius of the new junction and the
    tolerance on arc length; None if there is none. Adds the junctions looked at to ``done``;
    the moves in ``undone`` (:func:`.pairs._move_key`, positions in units of ``unit``) are left out."""
    scale = node_scale(skel)
    paths = branch_paths(skel.n_nodes, skel.edges)
    for c in np.flatnonzero(skel.degrees >= 3).tolist():
        if c in done:
            continue
        done.add(c)  # unless a move below changes it
        out = branches_at(paths, c)
        if len(out) < 2:
            continue
        rc = scale[c]
        arcs = [arc_length(skel.points[p]) for p in out]
        tips = np.stack([polyline_at(skel.points[p], a, np.array([ahead * rc]))[0] for p, a in zip(out, arcs)])
        i, j = np.triu_indices(len(out), 1)
        ang = _pair_angle(skel.points[c], tips[i], tips[j])
        for k in np.argsort(ang).tolist():
            if ang[k] >= limit:
                break
            pi, ai, pj, aj = out[i[k]], arcs[i[k]], out[j[k]], arcs[j[k]]
            if pi[-1] == pj[-1]:  # two paths between the same nodes: a loop, not a fork
                continue
            if undone and _move_key(skel, (c, pi, None, pj), unit) in undone:  # a move undone (:func:`separate_parallel_branches`)
                continue
            eps = 0.02 * rc
            top = min(ai[-1] - ahead * rc, aj[-1] - ahead * rc) - eps
            if distance is None:
                top = min(top, max_shift * rc - eps)
            if top <= 0:
                continue
            # candidate junctions: midpoints of the two branches, every twentieth of a radius
            s = np.arange(0.05 * rc, top + 1e-12, 0.05 * rc)
            Pi, Pj, Ri, Rj = skel.points[pi], skel.points[pj], scale[pi], scale[pj]
            mid = 0.5 * (polyline_at(Pi, ai, s) + polyline_at(Pj, aj, s))
            r = np.maximum(np.interp(s, ai, Ri), np.interp(s, aj, Rj))
            if distance is not None:
                # past max_shift only while the two still run in one lumen (an acute branch
                # along its parent): the midpoint a quarter radius inside, up to the first point not
                shared = np.asarray(distance(mid), float) >= 0.25 * r
                far = (s > max_shift * rc) & ~shared
                n_ok = int(np.argmax(far)) if far.any() else len(s)
                s, mid, r = s[:n_ok], mid[:n_ok], r[:n_ok]
            spread = _pair_angle(mid, polyline_at(Pi, ai, s + ahead * r), polyline_at(Pj, aj, s + ahead * r))
            wide = np.flatnonzero(spread >= target)
            if len(wide):
                return (c, pi, ai, pj, aj, s[wide[0]], mid[wide[0]], r[wide[0]], eps)
            if distance is not None:
                job = _fused_to_junction(skel, c, pi, ai, pj, aj, scale, distance)
                if job is not None:
                    return job
    return None


#: how far (x its radius) a junction's own stretch reaches: the block builder's REACH_RADII
#: (its half-sections' reach); a shorter branch to another junction is a pair of close
#: junctions (the builder's business, :mod:`.pairs`), not a fused pair.
FUSED_REACH = PAIR_REACH


def _fused_to_junction(skel: Skeleton, c: int, pi, ai, pj, aj, scale, distance):
    """The job that moves junction ``c`` onto the far junction of the shorter of its two
    branches ``pi``, ``pj`` when that branch runs in one lumen with the other all the way to
    it (every midpoint of the two, matched by arc length, a quarter radius or more inside):
    the two never part before it, so the junction ``c`` stands for lies there. None if not,
    or if that branch is no longer than :data:`FUSED_REACH` radii of ``c``."""
    if ai[-1] < aj[-1]:
        pi, ai, pj, aj = pj, aj, pi, ai  # j: the shorter
    e = int(pj[-1])
    if skel.degrees[e] < 3 or aj[-1] <= FUSED_REACH * scale[c]:
        return None  # a junction within the junction's own reach: two close junctions, not a fused pair
    s = np.arange(0.05 * scale[c], aj[-1], 0.05 * scale[c])
    mid = 0.5 * (polyline_at(skel.points[pi], ai, s) + polyline_at(skel.points[pj], aj, s))
    r = np.maximum(np.interp(s, ai, scale[pi]), np.interp(s, aj, scale[pj]))
    if not (np.asarray(distance(mid), float) >= 0.25 * r).all():
        return None
    return (c, pi, ai, pj, aj, None, None, None, 0.02 * scale[c])


def _join_parallel(skel: Skeleton, job: tuple, distance=None) -> tuple[Skeleton, np.ndarray]:
    """Move the junction of ``job`` (from :func:`_parallel_pair`) to where its two branches
    part: the common stretch of the two onto their midpoints; returns the new skeleton and
    the mask of the nodes of ``skel`` (and the new junction, last) dropped."""
    c, pi, ai, pj, aj, star, at, r_at, eps = job
    if star is None:
        return _join_fused(skel, job, distance)
    # branch i: pi[:ki] before the new junction (moved onto the midpoints), pi[li:] after
    # it, nodes at it dropped; branch j: pj[lj:] after it, the rest but c dropped
    ki = int(np.searchsorted(ai, star - eps, side="left"))
    li = int(np.searchsorted(ai, star + eps, side="right"))
    lj = int(np.searchsorted(aj, star + eps, side="right"))
    n = skel.n_nodes
    scale = node_scale(skel)
    pts = np.r_[skel.points, at[None]]
    rad = np.r_[skel.radii, r_at]
    inner = pi[1:ki]
    pts[inner] = 0.5 * (skel.points[inner] + polyline_at(skel.points[pj], aj, ai[1:ki]))
    rad[inner] = np.maximum(scale[inner], np.interp(ai[1:ki], aj, scale[pj]))
    if distance is not None:
        ids = np.r_[inner, n]
        depth = np.asarray(distance(pts[ids]), float)
        rad[ids] = np.where(depth > 0, depth, rad[ids])
    tags = list(skel.node_tags) + [tuple(t for t in skel.node_tags[c] if t not in END_TAGS)]
    drop = np.zeros(n + 1, bool)
    drop[pi[ki:li]] = True
    drop[pj[1:lj]] = True
    cut = np.sort([[pi[ki - 1], pi[ki]], [pi[li - 1], pi[li]], [pj[lj - 1], pj[lj]]], axis=1)
    keep = ~(np.sort(skel.edges, axis=1)[:, None, :] == cut[None]).all(-1).any(-1)
    edges = np.r_[skel.edges[keep], [[pi[ki - 1], n], [n, pi[li]], [n, pj[lj]]]]
    etags = [t for t, k in zip(skel.edge_tags, keep) if k] + [()] * 3
    grown = Skeleton(pts, rad, edges, tags, etags, name=skel.name)
    return contract_nodes(grown, np.where(drop, -1, np.arange(n + 1))), drop


def _join_fused(skel: Skeleton, job: tuple, distance=None) -> tuple[Skeleton, np.ndarray]:
    """Join a fused pair (from :func:`_fused_to_junction`): the shorter branch ``pj`` onto
    the midpoints of the two (it joins the vessel they leave), the longer branch ``pi``
    leaves from the far junction of ``pj``; returns the new skeleton and the mask of the
    nodes of ``skel`` (and one unused slot, last, as :func:`_join_parallel`) dropped."""
    c, pi, ai, pj, aj, _, _, _, eps = job
    e, n = int(pj[-1]), skel.n_nodes
    li = int(np.searchsorted(ai, aj[-1] + eps, side="right"))
    if li >= len(pi):  # no node of the longer branch past the far junction
        li = len(pi) - 1
    scale = node_scale(skel)
    pts, rad = skel.points.copy(), skel.radii.copy()
    inner = pj[1:]  # the far junction too: it moves onto the axis of the shared lumen
    pts[inner] = 0.5 * (skel.points[inner] + polyline_at(skel.points[pi], ai, aj[1:]))
    rad[inner] = np.maximum(scale[inner], np.interp(aj[1:], ai, scale[pi]))
    if distance is not None and len(inner):
        depth = np.asarray(distance(pts[inner]), float)
        rad[inner] = np.where(depth > 0, depth, rad[inner])
    drop = np.zeros(n + 1, bool)
    drop[pi[1:li]] = True
    drop[n] = True
    path = np.sort(np.c_[pi[:li], pi[1 : li + 1]], axis=1)
    keep = ~(np.sort(skel.edges, axis=1)[:, None, :] == path[None]).all(-1).any(-1)
    edges = np.r_[skel.edges[keep], [[e, pi[li]]]]
    etags = [t for t, k in zip(skel.edge_tags, keep) if k] + [()]
    grown = Skeleton(pts, rad, edges, list(skel.node_tags), etags, name=skel.name)
    return contract_nodes(grown, np.where(drop[:n], -1, np.arange(n))), drop


def separate_parallel_branches(
    skeleton: Skeleton,
    min_angle: float = 30.0,
    part_angle: float = 60.0,
    ahead: float = 1.0,
    max_shift: float = 4.0,
    distance=None,
) -> tuple[Skeleton, int]:
    """Move junctions whose branches leave nearly parallel downstream, to where they part.

    Centerlines traced from an inlet to every outlet (VMTK, SimVascular) split as soon as
    the paths are a fraction of the radius apart, well before the carina: two daughters
    then leave the junction a few degrees apart and run side by side for a radius or two,
    and the junction's half cross-sections become slivers reaching down to the carina. At
    every junction whose two closest branches make an angle below ``min_angle``
    (directions to the points ``ahead`` x radius along them), the common stretch of those
    two joins the vessel they leave (nodes on the midpoints of the two, matched by arc
    length) and the junction moves to the first midpoint from which the two branches,
    ``ahead`` x radius further on, are ``part_angle`` apart (about where the medial axis
    of the surface branches).

    At a junction of four or more branches a move leaves the junction behind, one branch
    fewer, and a new junction on the pair: once all of a junction's moves are made, those
    whose pair the block builder cannot block (:func:`.pairs.blockable_pair`) are undone
    when that leaves the junction in no other close pair and gives back five or more
    branches (a planar fan of daughters 20-30 degrees apart is blocked whole; its split
    pairs are not).

    Parameters
    ----------
    skeleton : Skeleton
    min_angle : float
        Least angle (degrees) between two branches at a junction; 0 moves nothing.
    part_angle : float
        Angle (degrees, at least ``min_angle``) between the two branches seen from the
        moved junction.
    ahead : float
        Where the branch directions are measured (x radius along the branches).
    max_shift : float
        Farthest a junction moves along its branches (x its radius); a junction whose
        branches are not yet ``part_angle`` apart there is left where it is. With
        ``distance``, farther while the two branches still share one lumen (their midpoint
        a quarter radius or more inside the wall): an acute branch running inside its
        parent for many radii parts where its own lumen does. When the shorter of the two
        ends in a junction (more than ``FUSED_REACH`` radii on) before they part, the
        junction moves onto that one (:func:`_fused_to_junction`).
    distance : callable, optional
        Signed distance (positive inside): radii of the moved nodes and the shared lumen.
        Without it (or where it is not positive), the larger of the two branch radii at
        each midpoint.

    Returns
    -------
    skeleton : Skeleton
    n_moved : int
        Number of junctions moved.
    """
    if min_angle <= 0 or skeleton.n_edges == 0:
        return skeleton.copy(), 0
    limit, target = np.radians(min_angle), np.radians(max(part_angle, min_angle))
    # a move's pair is judged once all of its junction's moves are made (the siblings a
    # daughter is measured against are those the other moves leave), then the moves
    # again from the start without those undone
    undone = frozenset()
    for _ in range(skeleton.n_edges + 1):  # a safety bound only: see the argument below
        skel, moved, made = _separate(skeleton, limit, target, ahead, max_shift, distance, undone)
        undo = _unblockable_moves(skel, made)
        if not undo or undo <= undone:
            break
        # terminates: every pass that goes on adds a move of its own to undone, and a move
        # once undone is not made again (_parallel_pair skips it), so the passes are at most
        # the distinct moves seen, each a pair of branches at a junction, plus one
        undone = undone | undo
    return skel.copy() if skel is skeleton else skel, moved


def _separate(skeleton: Skeleton, limit, target, ahead, max_shift, distance, undone) -> tuple[Skeleton, int, list]:
    """The moves of :func:`separate_parallel_branches` but those in ``undone`` (move keys);
    the skeleton, the number of moves and ``(junction, new junction, move key,
    junction key)`` per move that left its junction behind, as nodes of the result."""
    skel, moved, done, made = skeleton, 0, set(), []
    unit = float(np.median(node_scale(skeleton)))  # move keys in radii: the same in mm, cm or m
    while True:
        job = _parallel_pair(skel, done, limit, target, ahead, max_shift, distance, undone, unit)
        if job is None:
            break
        c = job[0]
        key, ckey = _move_key(skel, job, unit), _point_key(skel.points[c], unit)
        skel, drop = _join_parallel(skel, job, distance)
        n = len(drop) - 1
        # contract_nodes numbers the kept nodes in order; c is looked at again (it may have
        # more branches), the new junction is not
        new_index = np.cumsum(~drop) - 1
        made = [(int(new_index[a]), int(new_index[b]), k, ck) for a, b, k, ck in made if not (drop[a] or drop[b])]
        if job[5] is None:  # a fused pair: the far junction, which gained the branch, is looked at again
            e = int(job[3][-1])
            done = {int(new_index[d]) for d in done if d not in (c, e) and not drop[d]}
        else:
            done = {int(new_index[d]) for d in done if d != c and not drop[d]} | {int(new_index[n])}
            made.append((int(new_index[c]), int(new_index[n]), key, ckey))
        moved += 1
    return skel, moved, made


def _node_at_foot(skel: Skeleton, seg: int, t: float, scale: np.ndarray) -> tuple[Skeleton, int]:
    """The node where something joins segment ``seg`` at parameter ``t``: an end node of
    the segment within a quarter of its radius (``scale``) of the foot point, else a new
    node splitting the segment there (radius interpolated, tags both ends share)."""
    a, b = (int(x) for x in skel.edges[seg])
    length = np.linalg.norm(skel.points[b] - skel.points[a])
    if t * length <= 0.25 * scale[a]:
        return skel, a
    if (1 - t) * length <= 0.25 * scale[b]:
        return skel, b
    foot = skel.points[a] + t * (skel.points[b] - skel.points[a])
    r = (1 - t) * skel.radii[a] + t * skel.radii[b]
    node = skel.n_nodes
    edges = np.r_[np.delete(skel.edges, seg, axis=0), [[a, node], [node, b]]]
    etags = [x for i, x in enumerate(skel.edge_tags) if i != seg] + [skel.edge_tags[seg]] * 2
    shared = tuple(x for x in skel.node_tags[a] if x in skel.node_tags[b])
    out = Skeleton(np.r_[skel.points, [foot]], np.r_[skel.radii, r], edges, list(skel.node_tags) + [shared], etags, skel.name)
    return out, node


def reconnect_components(skeleton: Skeleton, tolerance: float = 1.0) -> tuple[Skeleton, int]:
    """Reconnect separated pieces: an endpoint (or isolated node) within ``tolerance`` x its
    radius of another component is joined to it, at the foot point on the nearest segment
    (a new node there, unless an end node of that segment is within a quarter radius).

    Pieces are joined one at a time, closest gap first, so two pieces that could each
    join the other are joined once.

    Returns
    -------
    skeleton : Skeleton
    n_joined : int
    """
    if tolerance <= 0:
        return skeleton.copy(), 0
    skel = skeleton.copy()
    joined = 0
    while True:
        label = component_labels(skel.n_nodes, skel.edges)
        if label.max(initial=0) == 0:
            break
        deg = skel.degrees
        scale = node_scale(skel)
        a_seg, b_seg = skel.edges.T
        start, vec = skel.points[a_seg], skel.points[b_seg] - skel.points[a_seg]
        best = None  # (gap, endpoint, segment or -1, foot parameter, node or -1)
        for e in np.flatnonzero(deg <= 1).tolist():
            limit = tolerance * scale[e]
            segs = np.flatnonzero(label[a_seg] != label[e])
            if len(segs):
                rel = skel.points[e] - start[segs]
                t = np.clip((rel * vec[segs]).sum(1) / np.maximum((vec[segs] ** 2).sum(1), 1e-300), 0, 1)
                dist = np.linalg.norm(rel - t[:, None] * vec[segs], axis=1)
                k = int(np.argmin(dist))
                if dist[k] <= limit and (best is None or dist[k] < best[0]):
                    best = (dist[k], e, int(segs[k]), float(t[k]), -1)
            iso = np.flatnonzero((deg == 0) & (label != label[e]))
            if len(iso):
                dist = np.linalg.norm(skel.points[iso] - skel.points[e], axis=1)
                k = int(np.argmin(dist))
                if dist[k] <= limit and (best is None or dist[k] < best[0]):
                    best = (dist[k], e, -1, 0.0, int(iso[k]))
        if best is None:
            break
        _, e, seg, t, node = best
        if seg >= 0:
            skel, node = _node_at_foot(skel, seg, t, scale)
        skel = skel.copy(edges=np.r_[skel.edges, [[e, node]]], edge_tags=list(skel.edge_tags) + [()])
        joined += 1
    return skel, joined


def select_spurs(scores, junctions, degree) -> list[int]:
    """Which candidate spurs go in one round of spur pruning: the lowest ``scores`` first
    (the shortest or least salient), at most ``degree[j] - 2`` at junction ``j``, so that
    a junction keeps two branches (a short bifurcation keeps one daughter).

    The one pruning rule of both cleanings: the extraction's branch graph
    (:meth:`~.branch_graph.BranchGraph.prune_spurs`, where a spur is a tip whose ball
    barely leaves its junction's) and a given or extracted skeleton
    (:func:`remove_spurs`, where a spur is a short or shadowed branch); they differ only in
    which branches are candidates.

    Parameters
    ----------
    scores : sequence of float
        One per candidate, lower goes first (ties keep their order).
    junctions : sequence of int
        The junction each candidate leaves.
    degree : mapping or array
        ``degree[j]``: the number of branches at junction ``j`` now.

    Returns
    -------
    list of int
        Indices of the chosen candidates, in the order they were chosen.
    """
    budget, chosen = {}, []
    for k in sorted(range(len(scores)), key=lambda i: scores[i]):
        j = junctions[k]
        left = budget.setdefault(j, int(degree[j]) - 2)
        if left > 0:
            chosen.append(k)
            budget[j] = left - 1
    return chosen


def remove_spurs(
    skeleton: Skeleton, length: float = 1.0, protected: np.ndarray | None = None, shadow: float = 0.5
) -> tuple[Skeleton, int]:
    """Remove short side branches: a branch from an endpoint to a junction shorter than
    ``length`` x the junction radius is a bump on the wall, not a vessel.

    At most ``degree - 2`` spurs (shortest first) go per junction and round, so a short
    bifurcation (two short daughters) keeps one daughter; rounds repeat until nothing
    changes. ``protected`` endpoints (e.g. at caps) are never removed, except a spur of
    any length whose end lies within ``shadow`` x its radius of another branch of its
    junction: it runs inside that branch's lumen (an extracted skeleton's second path
    along one vessel, leaving the junction a few degrees from it) and adds no vessel.

    Returns
    -------
    skeleton : Skeleton
    n_removed : int
        Number of spurs removed.
    """
    from .defects import shadowed

    if length <= 0 and shadow <= 0:
        return skeleton.copy(), 0
    skel = skeleton
    prot = np.zeros(skel.n_nodes, bool) if protected is None else np.asarray(protected, bool).copy()
    removed = 0
    while True:
        deg = skel.degrees
        scale = node_scale(skel)
        candidates = []
        paths = branch_paths(skel.n_nodes, skel.edges)
        for p in paths:
            a, b = p[0], p[-1]
            if deg[a] == 1 and deg[b] >= 3:
                end, junction, inner = a, b, p[:-1]
            elif deg[b] == 1 and deg[a] >= 3:
                end, junction, inner = b, a, p[1:]
            else:
                continue
            s = arc_length(skel.points[p])[-1]
            if (s < length * scale[junction] and not prot[end]) or (
                shadow > 0 and shadowed(skel, end, junction, p, paths, scale, shadow)
            ):
                candidates.append((s, junction, inner))
        if not candidates:
            break
        drop = np.zeros(skel.n_nodes, bool)
        for k in select_spurs([c[0] for c in candidates], [c[1] for c in candidates], deg):
            drop[candidates[k][2]] = True
            removed += 1
        if not drop.any():
            break
        keep = ~drop
        skel = remove_nodes(skel, drop, bridge=False)
        prot = prot[keep]
    return skel.copy() if skel is skeleton else skel, removed


def trim_at_caps(
    skeleton: Skeleton, centers: np.ndarray, normals: np.ndarray, radii: np.ndarray, slack: float = 1.5
) -> tuple[Skeleton, int]:
    """Cut off what lies beyond the caps: where a segment passes through a cap (crosses
    its plane within ``slack`` x cap radius of its centre) and the part of the skeleton on
    the far side hangs on that segment alone and lies mostly beyond the plane, that part
    is removed and the outer node of the segment moves to the crossing point.

    Centerlines computed on a longer vessel than the surface (the surface was clipped
    afterwards) run out through the open ends; this makes them end there.

    Returns
    -------
    skeleton : Skeleton
    n_cut : int
        Number of pieces cut off.
    """
    centers = np.asarray(centers, float).reshape(-1, 3)
    normals = np.asarray(normals, float).reshape(-1, 3)
    normals = normals / np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-300)
    cap_r = np.asarray(radii, float).reshape(-1)
    skel = skeleton.copy()
    n_cut = 0
    for c in range(len(centers)):
        while True:
            h = (skel.points - centers[c]) @ normals[c]
            out = h > 1e-3 * cap_r[c]  # nodes on the plane (to rounding) are not beyond it
            a, b = skel.edges.T
            cross = out[a] != out[b]
            t = np.clip(h[a] / np.where(cross & (h[a] != h[b]), h[a] - h[b], 1.0), 0.0, 1.0)
            foot = skel.points[a] + t[:, None] * (skel.points[b] - skel.points[a])
            cand = np.flatnonzero(cross & (np.linalg.norm(foot - centers[c], axis=1) <= slack * cap_r[c]))
            done = True
            for e in cand.tolist():
                inner, outer = (a[e], b[e]) if not out[a[e]] else (b[e], a[e])
                rest = np.delete(skel.edges, e, axis=0)
                label = component_labels(skel.n_nodes, rest)
                beyond = np.flatnonzero(label == label[outer])
                if label[inner] == label[outer] or len(beyond) * 2 > skel.n_nodes or out[beyond].mean() < 0.5:
                    continue
                points, rad = skel.points.copy(), skel.radii.copy()
                te = t[e] if outer == b[e] else 1.0 - t[e]
                drop = label == label[outer]
                # the new end: the outer node moved onto the plane, or the inner node if it
                # is (nearly) there already
                end = inner if np.linalg.norm(foot[e] - skel.points[inner]) <= 0.05 * cap_r[c] else outer
                if end == outer:
                    rad[outer] = (1 - te) * skel.radii[inner] + te * skel.radii[outer]
                points[end] = foot[e]
                drop[end] = False
                tags = list(skel.node_tags)
                ends = tuple(x for i in np.flatnonzero(drop).tolist() for x in skel.node_tags[i] if x in END_TAGS)
                tags[end] = _union(tags[end], ends)
                skel = remove_nodes(skel.copy(points=points, radii=rad, node_tags=tags), drop, bridge=False)
                n_cut += 1
                done = False
                break
            if done:
                break
    return skel, n_cut
