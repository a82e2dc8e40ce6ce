"""Sharp bends of a resampled skeleton: nodes whose cross-sections would cross inside the vessel.

The block builder puts one cross-section on every node with two neighbours, in the plane
that bisects its two segments. Where a centerline turns by more than about 100 degrees
within a couple of radii (an SWC tracing corner, a hairpin, a chord across a tight bend),
the sections next to the corner stand at a large angle to each other and their planes
cross closer to the axis than the wall is: the blocks between them are inverted on the
inner side of the bend, and a tilted section can even run along the vessel without
meeting the wall ("no wall within reach"). Two planes of a segment may only cross
outside the vessel, so nodes are dropped, one at a time per offending segment, until
every segment's planes cross at least ``min_gap`` radii from it: the corner keeps its node
(a mitre section) and its neighbours step back along the arms.
"""

from __future__ import annotations

import numpy as np

from ...skeleton import Skeleton
from .. import cross_sections as cs


def section_gaps(skeleton: Skeleton, bias: float = 1.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Distance from each segment at which the cross-section planes of its two nodes cross.

    The planes are those of the block builder: bisecting planes at nodes with two
    neighbours (:func:`~vmesh.geometry.cross_sections.bisector_normals` with ``bias``),
    the plane normal to the segment at an endpoint. For a segment of length ``L`` and
    direction ``t`` with plane normals ``n_a, n_b`` (oriented along ``t``), a point
    ``w`` off the axis (``w ⟂ t``) lies between the planes while
    ``w · (n_b / n_b·t − n_a / n_a·t) < L``, so they cross ``L / |n_b / n_b·t − n_a / n_a·t|``
    from the axis. Segments at a junction get ``inf`` (the builder places junction sections
    itself).

    Returns
    -------
    gap : (e,) float
        Crossing distance per segment (``inf`` for parallel planes, 0 for a plane that
        contains its segment).
    side : (e, 3) float
        Unit direction from the segment towards the crossing (the inner side of the bend).
    turn : (n,) float
        Turning angle of the centerline at each node in radians (0 where it has not two
        neighbours).
    """
    P, E = skeleton.points, skeleton.edges
    n = skeleton.n_nodes
    deg = skeleton.degrees
    t = P[E[:, 1]] - P[E[:, 0]]
    L = np.linalg.norm(t, axis=1)
    t = t / np.maximum(L, 1e-300)[:, None]
    normal = np.zeros((n, 3))
    turn = np.zeros(n)
    ends = np.flatnonzero(deg == 1)
    at = np.r_[E[:, 0], E[:, 1]]
    seg = np.r_[np.arange(len(E)), np.arange(len(E))]
    # endpoints: the plane normal to their only segment
    first = np.full(n, -1)
    first[at[::-1]] = seg[::-1]
    normal[ends] = t[first[ends]]
    two = np.flatnonzero(deg == 2)
    if len(two):
        order = np.argsort(at, kind="stable")
        at_s, seg_s = at[order], seg[order]
        start = np.searchsorted(at_s, two)
        e1, e2 = seg_s[start], seg_s[start + 1]
        prev = np.where(E[e1, 0] == two, E[e1, 1], E[e1, 0])
        nxt = np.where(E[e2, 0] == two, E[e2, 1], E[e2, 0])
        normal[two] = cs.bisector_normals(P[prev], P[two], P[nxt], skeleton.radii[two], bias)
        din, dout = cs.unit(P[two] - P[prev]), cs.unit(P[nxt] - P[two])
        turn[two] = np.arccos(np.clip(np.sum(din * dout, axis=1), -1.0, 1.0))
    na, nb = normal[E[:, 0]], normal[E[:, 1]]
    ca, cb = np.sum(na * t, axis=1), np.sum(nb * t, axis=1)
    na = na * np.sign(ca + (ca == 0))[:, None]
    nb = nb * np.sign(cb + (cb == 0))[:, None]
    ca, cb = np.abs(ca), np.abs(cb)
    tiny = 1e-9
    g = nb / np.maximum(cb, tiny)[:, None] - na / np.maximum(ca, tiny)[:, None]
    g = g - np.sum(g * t, axis=1)[:, None] * t
    gn = np.linalg.norm(g, axis=1)
    gap = np.where(gn > 0, L / np.maximum(gn, 1e-300), np.inf)
    gap[(ca < tiny) | (cb < tiny)] = 0.0
    gap[(deg[E[:, 0]] > 2) | (deg[E[:, 1]] > 2)] = np.inf
    side = g / np.maximum(gn, 1e-300)[:, None]
    return gap, side, turn


def thin_sharp_bends(skeleton: Skeleton, min_gap: float = 1.0, distance=None, bias: float = 1.0, reach: float = 6.0, max_rounds: int = 64,
                     intersect_lines=None, rays: cs.RayCache | None = None) -> tuple[Skeleton, int]:
    """Drop nodes next to sharp bends until no two neighbouring cross-sections cross inside
    the vessel (see the module's docstring).

    Per round, every segment whose planes cross inside the vessel (:func:`section_gaps`:
    closer than ``min_gap`` × the wall's distance from the segment's middle towards the
    crossing, cast on ``distance`` up to ``reach`` radii; without ``distance`` the larger
    radius of its nodes) loses one node: the one that turns less (the corner
    stays), never a junction or an endpoint, never two neighbours in one round, and with
    ``distance`` (signed, positive inside) only where the segment that bridges the gap stays
    at least a fifth of a radius inside the wall. Rounds repeat until nothing changes.

    Parameters
    ----------
    skeleton : Skeleton
        Resampled, with radii.
    min_gap : float
        Least distance of the planes' crossing from the axis, × the wall's (0: off).
    distance : callable, optional
        Signed distance, positive inside. Near a corner the wall on the inner side of the
        bend is much farther than a radius (the other arm's tube): only a cast finds it.
    reach : float
        Farthest wall distance considered, × radius.
    bias : float
        As the block builder's ``plane_bias``.
    intersect_lines : callable, optional
        Line casts on the same surface (:func:`~vmesh.geometry.rays.cast_rays`): one tree
        traversal per ray where the march found the wall, instead of a bisection.
    rays : RayCache, optional
        Where the rays are cast (a new one by default): a segment whose nodes and
        neighbours did not change casts the same ray in the next round, answered from the
        cache, so each round casts only around the nodes the last one dropped.

    Returns
    -------
    skeleton : Skeleton
    n_removed : int
    """
    from .graph import remove_nodes

    sk = skeleton
    removed = 0
    if min_gap <= 0 or sk.n_edges == 0:
        return sk.copy(), 0
    rays = cs.RayCache() if rays is None else rays
    for _ in range(max_rounds):
        gap, side, turn = section_gaps(sk, bias)
        E = sk.edges
        r = np.maximum(sk.radii[E[:, 0]], sk.radii[E[:, 1]])
        bad = np.flatnonzero(gap < min_gap * (reach if distance is not None else 1.0) * r)
        if distance is not None and len(bad):
            mid = 0.5 * (sk.points[E[bad, 0]] + sk.points[E[bad, 1]])
            wall = rays.cast(distance, mid, side[bad], r[bad], reach=reach, intersect_lines=intersect_lines)
            wall = np.where(np.isfinite(wall), wall, reach * r[bad])
            bad = bad[gap[bad] < min_gap * wall]
        if len(bad) == 0:
            break
        deg = sk.degrees
        a, b = E[bad, 0], E[bad, 1]
        ta = np.where(deg[a] == 2, turn[a], np.inf)
        tb = np.where(deg[b] == 2, turn[b], np.inf)
        pick = np.where(ta <= tb, a, b)
        pick = np.unique(pick[np.minimum(ta, tb) < np.inf])
        pick = _bridgeable(sk, pick, distance)
        if len(pick) == 0:
            break
        mask = np.zeros(sk.n_nodes, bool)
        mask[pick] = True
        sk = remove_nodes(sk, mask, bridge=True)
        removed += len(pick)
    return sk, removed


def chamfer_hairpins(skeleton: Skeleton, max_turn: float = 90.0, distance=None, depth: float = 0.2) -> tuple[Skeleton, int]:
    """Cut the corner of every node that turns by more than ``max_turn`` degrees into two.

    A corner keeps one mitre cross-section (:func:`thin_sharp_bends`), in the plane that
    bisects its two segments; past a right angle that plane lies closer to each segment
    than square to it (it tilts by more than 45 degrees, towards containing both arms at a
    hairpin), and the blocks between it and the next section fold across the arm. The
    corner ``C`` with neighbours ``A`` and ``B`` is replaced by two nodes, one on each arm,
    one radius ``r_C`` from ``C``: each turns by half as much, so their planes tilt by at
    most 45 degrees, and the segment between them crosses the bend's wide lumen. Only where
    both arms are at least two radii long (room for a block beyond the new nodes), with
    ``distance`` (signed, positive inside) only where both nodes and the segment between
    them stay ``depth`` × ``r_C`` inside the wall, and not two neighbours at once. A turn
    near 180 degrees still leaves two 80-90 degree corners: better, not always valid.

    Parameters
    ----------
    skeleton : Skeleton
        Resampled (and thinned at sharp bends), with radii.
    max_turn : float
        Largest turn a node keeps, in degrees.
    distance : callable, optional
        Signed distance, positive inside.
    depth : float
        Least depth of the new nodes and their segment, × the corner's radius.

    Returns
    -------
    skeleton : Skeleton
    n_chamfered : int
    """
    sk = skeleton
    if sk.n_edges == 0:
        return sk.copy(), 0
    turn = section_gaps(sk)[2]
    corner = np.flatnonzero((sk.degrees == 2) & (turn > np.radians(max_turn)))
    if len(corner) == 0:
        return sk.copy(), 0
    E = sk.edges
    at = np.r_[E[:, 0], E[:, 1]]
    other = np.r_[E[:, 1], E[:, 0]]
    seg = np.r_[np.arange(len(E)), np.arange(len(E))]
    order = np.argsort(at, kind="stable")
    start = np.searchsorted(at[order], corner)
    a, b = other[order][start], other[order][start + 1]
    eb = seg[order][start + 1]  # the segment C-B, which B's new node takes over
    P, r = sk.points, sk.radii[corner]
    ua, ub = P[a] - P[corner], P[b] - P[corner]
    la, lb = np.linalg.norm(ua, axis=1), np.linalg.norm(ub, axis=1)
    h = r
    ok = np.minimum(la, lb) >= 2.0 * h  # arms that leave room beyond the new nodes
    c1 = P[corner] + (h / la)[:, None] * ua
    c2 = P[corner] + (h / lb)[:, None] * ub
    if distance is not None:
        f = np.linspace(0.0, 1.0, 5)
        probe = c1[:, None] * (1 - f)[None, :, None] + c2[:, None] * f[None, :, None]
        deep = np.asarray(distance(probe.reshape(-1, 3)), float).reshape(len(corner), -1).min(axis=1)
        ok &= deep >= depth * r
    # not two neighbouring corners at once (the second would move a node the first keeps)
    taken = np.zeros(sk.n_nodes, bool)
    for i in np.flatnonzero(ok):  # the corners only: a handful per tree
        if taken[a[i]] or taken[b[i]]:
            ok[i] = False
            continue
        taken[corner[i]] = True
    corner, b, eb, c1, c2 = corner[ok], b[ok], eb[ok], c1[ok], c2[ok]
    if len(corner) == 0:
        return sk.copy(), 0
    n, m = sk.n_nodes, len(corner)
    new = n + np.arange(m)
    points = np.vstack([P, c2])
    points[corner] = c1
    edges = E.copy()
    edges[eb] = np.where(edges[eb] == corner[:, None], new[:, None], edges[eb])
    edges = np.vstack([edges, np.c_[corner, new]])
    node_tags = list(sk.node_tags) + [sk.node_tags[c] for c in corner.tolist()] if sk.node_tags else []
    edge_tags = list(sk.edge_tags) + [sk.edge_tags[k] for k in eb.tolist()] if sk.edge_tags else []
    out = Skeleton(points, np.r_[sk.radii, sk.radii[corner]], edges, node_tags, edge_tags, name=sk.name)
    return out, m


def _bridgeable(sk: Skeleton, pick: np.ndarray, distance) -> np.ndarray:
    """The nodes of ``pick`` (all with two neighbours) that may go in one round: no two
    neighbours, no bridge that doubles a segment, and (with ``distance``) a bridge that stays
    inside."""
    E = sk.edges
    nbrs = np.full((sk.n_nodes, 2), -1)
    at = np.r_[E[:, 0], E[:, 1]]
    other = np.r_[E[:, 1], E[:, 0]]
    order = np.argsort(at, kind="stable")
    at_s, other_s = at[order], other[order]
    start = np.searchsorted(at_s, pick)
    nbrs[pick, 0], nbrs[pick, 1] = other_s[start], other_s[start + 1]
    inside = np.ones(len(pick), bool)
    if distance is not None and len(pick):
        # the bridging segment, sampled at five inner points per pick
        u, v = nbrs[pick, 0], nbrs[pick, 1]
        s = np.linspace(0.0, 1.0, 7)[1:-1]
        probe = sk.points[u][:, None] * (1 - s)[None, :, None] + sk.points[v][:, None] * s[None, :, None]
        depth = np.asarray(distance(probe.reshape(-1, 3)), float).reshape(len(pick), -1).min(axis=1)
        inside = depth >= 0.2 * np.minimum(sk.radii[u], sk.radii[v])
    chosen = np.zeros(sk.n_nodes, bool)
    keys = set(map(tuple, np.sort(E, axis=1).tolist()))
    ok = []
    for i, p in enumerate(pick.tolist()):  # the offending segments only: a few per round
        u, v = nbrs[p]
        if not inside[i] or chosen[u] or chosen[v] or (min(u, v), max(u, v)) in keys:
            continue
        chosen[p] = True
        ok.append(p)
    return np.asarray(ok, np.int64)


def thin_stubs(skeleton: Skeleton, depth: float = 1.0, side_ratio: float = 0.6) -> tuple[Skeleton, int]:
    """Drop the inner nodes of short branches that never leave their junctions' lumen.

    A side branch cut off one or two radii past the wall (a stub) is resampled with nodes
    whose cross-sections all reach into its (much wider) parent: they find no wall across
    the parent's lumen, and there is no room further out to move them to. Such a branch
    (from a junction to an endpoint, every inner node narrower than the junction and
    closer to the junction node than ``depth`` × the junction radius plus its own radius) keeps only its junction and end:
    the block builder closes it with the junction's half-sections and the end's section.
    A branch between two junctions, every inner node at most ``side_ratio`` × the wider
    junction's radius and so close to one of them (a thin side branch of a wide vessel that
    forks again before it leaves that vessel's lumen), is one segment likewise: the builder
    has no room between the two junctions' sections to move its sections out of the lumen.
    ``side_ratio`` is the scale of a side branch or stub (0.3-0.6 of its parent's radius);
    a branch between the junctions of a bifurcating tree is wider (0.8-1 × its junctions'
    radius, a Murray daughter) and keeps its nodes: the builder spreads its sections.

    Returns
    -------
    skeleton : Skeleton
    n_removed : int
        Nodes dropped.
    """
    from .graph import branch_paths, remove_nodes

    sk = skeleton
    deg = sk.degrees
    drop = np.zeros(sk.n_nodes, bool)
    for p in branch_paths(sk.n_nodes, sk.edges):  # per branch, not per point
        if len(p) < 3 or p[0] == p[-1]:
            continue
        if deg[p[0]] == 1 and deg[p[-1]] >= 3:
            p = p[::-1]
        if deg[p[0]] < 3 or deg[p[-1]] == 2:
            continue
        held = _near_junction(sk, p[0], p[1:-1], depth)
        # narrower than the junction: an aneurysm's sac, wider, keeps its sections
        narrow = sk.radii[p[1:-1]] < sk.radii[p[0]]
        if deg[p[-1]] >= 3:  # a node may lie in either junction's lumen
            held |= _near_junction(sk, p[-1], p[1:-1], depth)
            narrow = sk.radii[p[1:-1]] <= side_ratio * max(sk.radii[p[0]], sk.radii[p[-1]])
        if np.all(held & narrow):
            drop[p[1:-1]] = True
    if not drop.any():
        return sk.copy(), 0
    return remove_nodes(sk, drop, bridge=True), int(drop.sum())


def _near_junction(sk: Skeleton, junction: int, nodes, depth: float) -> np.ndarray:
    """Which of ``nodes`` are closer to ``junction`` than ``depth`` × its radius plus their
    own (their sections reach into the junction's lumen)."""
    reach = np.linalg.norm(sk.points[nodes] - sk.points[junction], axis=1)
    return reach <= depth * sk.radii[junction] + sk.radii[nodes]
