"""Matching skeleton ends to caps, extending them to the caps and grafting missing
branches (moved from :mod:`vmesh.geometry.skeleton_ops`, issue 20)."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import dijkstra
from scipy.spatial import cKDTree

from ...skeleton import Skeleton
from .clean import _node_at_foot, node_scale
from .graph import arc_length, edge_lengths, END_TAGS, _graph_distance, remove_nodes, _union


def match_ends_to_caps(skeleton: Skeleton, centers: np.ndarray, radii: np.ndarray, max_distance: float = 3.0) -> list[tuple[int, int]]:
    """Match caps to skeleton endpoints one to one: optimal assignment on distance / cap
    radius; pairs farther than ``max_distance`` x cap radius stay unmatched.

    Returns
    -------
    list of (endpoint node, cap index)
    """
    from scipy.optimize import linear_sum_assignment

    centers = np.asarray(centers, float).reshape(-1, 3)
    cap_r = np.asarray(radii, float).reshape(-1)
    ends = skeleton.endpoints
    if len(centers) == 0 or len(ends) == 0:
        return []
    cost = np.linalg.norm(skeleton.points[ends][:, None, :] - centers[None], axis=2) / cap_r[None]
    rows, cols = linear_sum_assignment(cost)
    ok = cost[rows, cols] <= max_distance
    return [(int(ends[r]), int(c)) for r, c in zip(rows[ok], cols[ok])]


def _end_chain(adj, deg: np.ndarray, end: int) -> np.ndarray:
    """The branch from the endpoint ``end`` inwards, up to and including the next key node
    (``adj``: the skeleton's adjacency, ``deg``: its node degrees)."""
    chain, prev, cur = [end], -1, end
    while cur == end or deg[cur] == 2:
        nb = [int(v) for v in adj.indices[adj.indptr[cur] : adj.indptr[cur + 1]] if v != prev]
        if not nb:
            break
        prev, cur = cur, nb[0]
        chain.append(cur)
    return np.asarray(chain)


def _cap_target(p_end: np.ndarray, direction: np.ndarray, center: np.ndarray, normal: np.ndarray, cap_radius: float, mode: str) -> np.ndarray:
    """Where an end at ``p_end`` going along ``direction`` is brought on its cap (see
    :func:`extend_to_caps`): the cap centre, or with ``mode="plane"`` where the direction
    meets the cap plane unless that is more than half a cap radius off-centre."""
    nd = np.linalg.norm(direction)
    target = center
    if mode == "plane" and nd > 0:
        direction = direction / nd
        cosang = direction @ normal
        if cosang > 0.2:
            hit = p_end + ((center - p_end) @ normal) / cosang * direction
            if np.linalg.norm(hit - center) <= 0.5 * cap_radius:
                target = hit
    return target


def _bend_end(pts: list, points: np.ndarray, rest: np.ndarray, s: np.ndarray, lateral: np.ndarray, cap_radius: float) -> None:
    """Shift the last two cap radii of the branch ``rest`` (end node first, arc lengths
    ``s``) sideways by ``lateral``, weight falling linearly from the end; writes ``pts``."""
    if len(rest) > 1:
        reach = min(2.0 * cap_radius, s[-1])
        weight = np.clip(1.0 - s / max(reach, 1e-300), 0.0, 1.0)
        weight[-1] = 0.0
        for node, w_ in zip(rest.tolist(), weight.tolist()):
            if w_ > 0:
                pts[node] = points[node] + w_ * lateral
    else:
        pts[rest[0]] = points[rest[0]] + lateral


def _extend_end(lists: tuple, keep_end: int, p_end, target, r0: float, cap_radius: float, gap: float, spacing: float, base: tuple, end_label: tuple) -> int:
    """Extend the end node ``keep_end`` (at ``p_end``) in a straight line to ``target``,
    ``gap`` away: new nodes about ``spacing`` apart, radii blending linearly from ``r0`` to
    ``cap_radius``, tags ``base`` and ``end_label`` on the new end. ``lists`` are the
    skeleton's ``(pts, rad, ntags, edges, etags)``, extended in place; returns the new end
    node."""
    pts, rad, ntags, edges, etags = lists
    steps = max(1, int(np.ceil(gap / spacing)))
    f = np.arange(1, steps + 1) / steps
    new_r = (1 - f) * r0 + f * cap_radius if np.isfinite(r0) else np.full(steps, cap_radius)
    ids = list(range(len(pts), len(pts) + steps))
    pts.extend(p_end + f[:, None] * (target - p_end))
    rad.extend(new_r)
    ntags[keep_end] = base
    ntags.extend([base] * (steps - 1) + [_union(base, end_label)])
    chain_ids = [keep_end] + ids
    edges.extend(zip(chain_ids[:-1], chain_ids[1:]))
    etags.extend([()] * steps)
    return ids[-1]


def _drop_trimmed(out: Skeleton, drop: np.ndarray, end_of_cap: dict, matched: np.ndarray) -> tuple[Skeleton, np.ndarray]:
    """Remove the trimmed nodes ``drop`` (of the original skeleton, the first nodes of
    ``out``) and number the end node of each cap in ``matched`` accordingly."""
    full_drop = np.r_[drop, np.zeros(out.n_nodes - len(drop), bool)]
    new_index = np.cumsum(~full_drop) - 1
    for c, node in end_of_cap.items():
        matched[c] = new_index[node]
    if full_drop.any():
        out = remove_nodes(out, full_drop, bridge=False)
    return out, matched


def _trimmed_to(beyond: np.ndarray, key_degree: int, askew: bool) -> int:
    """Index in an end chain (end first) of the node that stays its end after the run of
    end nodes past the cap plane (``beyond``) is trimmed, never the branch's other end.
    Nothing is trimmed when the whole branch lies past the plane, leaves a junction
    (``key_degree`` >= 3) and runs against the cap's outward normal (``askew``): the plane
    is not this branch's cut (a rim fitted askew, as a stub's ending against another
    vessel), and trimming would drop the branch and move its junction onto the cap. A
    branch running along the normal past its cap is trimmed as any other."""
    k = min(int(np.argmin(beyond)) if not beyond.all() else len(beyond) - 1, len(beyond) - 1)
    return 0 if k == len(beyond) - 1 and key_degree >= 3 and askew else k


def extend_to_caps(
    skeleton: Skeleton,
    centers: np.ndarray,
    normals: np.ndarray,
    radii: np.ndarray,
    names: list[str] | None = None,
    mode: str = "center",
    max_distance: float = 3.0,
) -> tuple[Skeleton, np.ndarray]:
    """Make the skeleton end exactly at the caps of the open ends.

    Every cap is matched to one endpoint (optimal assignment on distance / cap radius,
    pairs farther than ``max_distance`` x cap radius stay unmatched). For a matched
    endpoint, nodes beyond the cap plane are trimmed, then the end is brought to the cap
    centre (``mode="center"``) or to where the end direction meets the cap plane
    (``mode="plane"``; the centre when that point is more than half a cap radius
    off-centre): the part of the correction parallel to the cap bends the last two cap
    radii of the branch (weight falling linearly from the end), the part along the cap
    normal extends the branch in a straight line. New nodes keep the skeleton's median
    node spacing, radii blend linearly to the cap radius; the end node is tagged with the
    cap's name (``inlet``/``outlet`` tags move to it).

    Parameters
    ----------
    skeleton : Skeleton
    centers, normals : (c, 3)
        Cap centres and unit normals pointing out of the vessel.
    radii : (c,)
    names : list of str, optional
        Tag added to the end node of each cap.

    Returns
    -------
    skeleton : Skeleton
    matched : (c,) int64
        Node index of the end node of each cap in the returned skeleton, -1 if unmatched.
    """
    centers = np.asarray(centers, float).reshape(-1, 3)
    normals = np.asarray(normals, float).reshape(-1, 3)
    normals = normals / np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-300)
    cap_r = np.asarray(radii, float).reshape(-1)
    n_caps = len(centers)
    ends = skeleton.endpoints
    matched = np.full(n_caps, -1, np.int64)
    if n_caps == 0 or len(ends) == 0:
        return skeleton.copy(), matched
    pairs = match_ends_to_caps(skeleton, centers, cap_r, max_distance)

    pts, rad = list(skeleton.points), list(skeleton.radii)
    ntags = list(skeleton.node_tags)
    edges, etags = [tuple(e) for e in skeleton.edges.tolist()], list(skeleton.edge_tags)
    adj = skeleton.adjacency()
    deg = skeleton.degrees
    scale = node_scale(skeleton)
    lengths = edge_lengths(skeleton.points, skeleton.edges)
    spacing = float(np.median(lengths)) if len(lengths) else 1.0
    end_tags = set(END_TAGS) | set(names or ())
    drop = np.zeros(skeleton.n_nodes, bool)
    end_of_cap = {}
    for end, c in pairs:
        # the branch from the endpoint inwards, up to and including the next key node
        chain = _end_chain(adj, deg, end)
        height = (skeleton.points[chain] - centers[c]) @ normals[c]
        beyond = height > 1e-3 * cap_r[c]  # on the plane to rounding is not beyond
        # a cap's outward normal points along the branch it cuts, from the junction to the
        # end; a branch running against it ends at a rim fitted askew, not past its cut
        askew = bool((skeleton.points[chain[0]] - skeleton.points[chain[-1]]) @ normals[c] < 0)
        k = _trimmed_to(beyond, int(deg[chain[-1]]), askew)
        keep_end = int(chain[k])
        drop[chain[:k]] = True
        rest = chain[k:]
        p_end = skeleton.points[keep_end]
        s = arc_length(skeleton.points[rest])
        back = rest[min(int(np.searchsorted(s, scale[keep_end])), len(rest) - 1)]
        direction = p_end - skeleton.points[back]
        target = _cap_target(p_end, direction, centers[c], normals[c], cap_r[c], mode)
        # the sideways part of the correction bends the last stretch of the branch (no kink,
        # the branch's other end stays put); the part along the normal extends it
        shift = target - p_end
        lateral = shift - (shift @ normals[c]) * normals[c]
        _bend_end(pts, skeleton.points, rest, s, lateral, cap_r[c])
        p_end = np.asarray(pts[keep_end])
        # end labels (inlet/outlet/cap name), also of trimmed nodes, move to the new end node
        old = ntags[keep_end]
        trimmed = tuple(t for i in chain[:k].tolist() for t in ntags[i] if t in end_tags)
        moved = _union(tuple(t for t in old if t in end_tags), trimmed)
        base = tuple(t for t in old if t not in end_tags)
        end_label = _union(moved, (names[c],) if names else ())
        gap = np.linalg.norm(target - p_end)
        if gap <= 0.5 * spacing:  # too short for a segment of its own: move the end
            pts[keep_end] = target
            ntags[keep_end] = _union(old, end_label)
            end_of_cap[c] = keep_end
            continue
        lists = (pts, rad, ntags, edges, etags)
        end_of_cap[c] = _extend_end(lists, keep_end, p_end, target, skeleton.radii[keep_end], cap_r[c], gap, spacing, base, end_label)
    out = Skeleton(np.asarray(pts), np.asarray(rad), np.asarray(edges, np.int64).reshape(-1, 2), ntags, etags, skeleton.name)
    return _drop_trimmed(out, drop, end_of_cap, matched)


def _path_to(pred: np.ndarray, start: int, entry: int) -> np.ndarray:
    """Nodes of the shortest path from ``start`` to ``entry`` (predecessors ``pred`` of a
    search from ``start``), without ``entry``."""
    path = [entry]
    while path[-1] != start:
        path.append(int(pred[path[-1]]))
    return np.asarray(path[:0:-1], np.int64)


def _nearest_segment(skel: Skeleton, q: np.ndarray) -> tuple[int, float]:
    """The edge of ``skel`` nearest to ``q`` and the parameter (0 to 1) of the foot of ``q``
    on it."""
    p0, vec = skel.points[skel.edges[:, 0]], skel.points[skel.edges[:, 1]] - skel.points[skel.edges[:, 0]]
    t = np.clip(((q - p0) * vec).sum(1) / np.maximum((vec * vec).sum(1), 1e-300), 0.0, 1.0)
    seg = int(np.argmin(np.linalg.norm(q - p0 - t[:, None] * vec, axis=1)))
    return seg, float(t[seg])


def _attach_branch(skel: Skeleton, points: np.ndarray, radii: np.ndarray, node: int, base: tuple, end_label: tuple) -> tuple[Skeleton, np.ndarray]:
    """Append ``points``/``radii`` (from the cap end inwards) as a branch joined to ``node``,
    tagged ``base`` and its cap end ``end_label`` too; returns the skeleton and the nodes of
    the branch, ``node`` last."""
    n0 = skel.n_nodes
    chain = np.r_[n0 + np.arange(len(points)), node]
    tags = list(skel.node_tags) + [base] * len(points)
    tags[n0] = _union(base, end_label)
    skel = Skeleton(
        np.r_[skel.points, points],
        np.r_[skel.radii, radii],
        np.r_[skel.edges, np.c_[chain[:-1], chain[1:]]],
        tags,
        list(skel.edge_tags) + [()] * len(points),
        skel.name,
    )
    return skel, chain


def graft_branches(
    skeleton: Skeleton,
    source: Skeleton,
    centers: np.ndarray,
    radii: np.ndarray,
    names: list[str] | None = None,
    reach: float = 1.0,
    join: float = 0.5,
) -> tuple[Skeleton, list[dict]]:
    """Graft branches of ``source`` onto ``skeleton`` so that it reaches the given caps.

    A centerline that misses a vessel (a VMTK centerline without a line down one open
    end) leaves that vessel without blocks: the wall over its mouth is meshed by the
    blocks of its neighbours and badly. ``source`` is another skeleton of the same vessel
    (extracted from its signed distance) that does reach the cap. For each cap the
    grafted branch is the shortest path in ``source`` from its endpoint nearest the cap
    centre (at most ``reach`` x cap radius away) to the first node within ``join`` x
    radius of ``skeleton`` (distance to its segments; radius the larger of the two
    skeletons' there). That last node is replaced by the foot point on ``skeleton`` (an
    existing node within a quarter radius, else a new node splitting the segment), which
    becomes the junction. Caps are grafted in order, so a later branch may join an
    earlier one.

    Grafted nodes keep the positions and radii of ``source`` and get the tags both end
    nodes of the joined segment carry (end tags excepted); the end node also gets the
    cap's name and ``inlet`` (a cap named ``inlet*`` when no endpoint is tagged ``inlet``
    yet) or ``outlet``.

    Parameters
    ----------
    skeleton, source : Skeleton
    centers : (c, 3)
        Centres of the caps to reach.
    radii : (c,)
        Cap radii.
    names : list of str, optional
        Cap names, for the tags and the report.

    Returns
    -------
    skeleton : Skeleton
    grafts : list of dict
        One per cap: ``cap``, ``nodes`` (added), ``length`` of the branch, ``joined_at``
        (position of the junction), ``gap`` (distance / radius from the last source node
        to ``skeleton``); ``nodes == 0`` and a ``reason`` where nothing was grafted.
    """
    centers = np.asarray(centers, float).reshape(-1, 3)
    cap_r = np.asarray(radii, float).reshape(-1)
    names = list(names) if names is not None else [f"cap_{c}" for c in range(len(centers))]
    end_tags = set(END_TAGS) | set(names)
    src_ends = source.endpoints
    skel = skeleton.copy()
    grafts = []
    if not len(src_ends) or skel.n_edges == 0:
        return skel, [{"cap": n, "nodes": 0, "reason": "no skeleton to graft from or onto"} for n in names]
    w = edge_lengths(source.points, source.edges)
    a, b = source.edges.T
    src_adj = sp.coo_matrix((np.r_[w, w], (np.r_[a, b], np.r_[b, a])), shape=(source.n_nodes,) * 2).tocsr()
    src_r = node_scale(source)
    for c in range(len(centers)):
        gap_to_cap = np.linalg.norm(source.points[src_ends] - centers[c], axis=1)
        if gap_to_cap.min() > reach * cap_r[c]:
            grafts.append({"cap": names[c], "nodes": 0, "reason": "the source skeleton has no end at the cap"})
            continue
        start = int(src_ends[np.argmin(gap_to_cap)])
        scale = node_scale(skel)
        dist, near = _graph_distance(source.points, skel.points, skel.edges, cKDTree(skel.points))
        close = dist <= join * np.maximum(src_r, scale[near])
        along, pred = dijkstra(src_adj, indices=start, return_predecessors=True)
        cand = np.flatnonzero(close & np.isfinite(along))
        if not len(cand):
            grafts.append({"cap": names[c], "nodes": 0, "reason": "the source skeleton does not come near the skeleton"})
            continue
        entry = int(cand[np.argmin(along[cand])])
        new = _path_to(pred, start, entry)  # from the cap end inwards, without the entry node
        if not len(new):
            grafts.append({"cap": names[c], "nodes": 0, "reason": "the skeleton passes through the cap centre"})
            continue
        # the junction: the foot of the entry node on the nearest segment of the skeleton
        seg, t_seg = _nearest_segment(skel, source.points[entry])
        e0, e1 = skel.edges[seg]
        base = tuple(x for x in skel.node_tags[e0] if x in skel.node_tags[e1] and x not in end_tags)
        skel, node = _node_at_foot(skel, seg, t_seg, scale)
        has_inlet = any("inlet" in skel.node_tags[i] for i in skel.endpoints.tolist())
        kind = "inlet" if names[c].startswith("inlet") and not has_inlet else "outlet"
        skel, chain = _attach_branch(skel, source.points[new], source.radii[new], node, base, (kind, names[c]))
        grafts.append(
            {
                "cap": names[c],
                "nodes": int(len(new)),
                "length": float(arc_length(skel.points[chain])[-1]),
                "joined_at": skel.points[node].tolist(),
                "gap": float(dist[entry] / src_r[entry]),
            }
        )
    return skel, grafts
