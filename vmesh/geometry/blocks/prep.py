"""Skeleton preparation for the block builder: splitting and merging junctions, matching
endpoints to caps, and placing sections along a branch."""

from __future__ import annotations

import numpy as np

from ...skeleton import Skeleton
from .. import cross_sections as cs
from ..variation import closest_on_segments


# ---------------------------------------------------------------------------
# skeleton preparation
# ---------------------------------------------------------------------------
def split_nonplanar_junctions(skeleton: Skeleton, nodes, length: float = 1.2, distance=None, inside: float = 0.5, rank: int = 0) -> Skeleton:
    """Split junctions into chains of 3-junctions.

    At each node of degree ``m > 3`` two neighbours are moved onto a new node placed
    ``length × radius`` along their mean direction and joined to the original node by a
    new segment; repeated until every node has at most three neighbours. Tags are
    inherited. With ``distance`` (signed, positive inside) the new node goes no further
    than where it is still ``inside × radius`` inside the vessel, and the pairs are ranked
    by how deep inside their new node lies (a node pushed into the wall between two
    ostia makes blocks that cannot be fixed), then by how close their directions are;
    without it by closeness alone. Nearly opposite pairs come last.

    Parameters
    ----------
    skeleton : Skeleton
    nodes : sequence of int
        Junctions to split.
    length : float
        Distance of a new node from its junction (× the junction radius).
    distance : callable, optional
        Signed distance, positive inside.
    inside : float
        Least depth of a new node (× the junction radius).
    rank : int
        Which pair to split off at each step (0: the best ranked; alternatives when the
        best one's blocks cannot be made valid).

    Returns
    -------
    Skeleton
        The split skeleton (the original nodes keep their numbers).
    """
    sk = skeleton
    pts = list(sk.points)
    rad = list(sk.radii)
    ntags = list(sk.node_tags)
    edges = [tuple(e) for e in sk.edges.tolist()]
    etags = list(sk.edge_tags)
    todo = [int(n) for n in nodes]
    while todo:
        c = todo.pop()
        inc = [k for k, e in enumerate(edges) if c in e]
        if len(inc) <= 3:
            continue
        nb = [edges[k][0] if edges[k][1] == c else edges[k][1] for k in inc]
        d = cs.unit(np.asarray([pts[j] for j in nb]) - pts[c])
        pi, pj = np.triu_indices(len(nb), 1)
        w = cs.unit(d[pi] + d[pj])  # (pairs, 3)
        t = np.full(len(pi), length * rad[c])
        depth = np.zeros(len(pi))
        if distance is not None:
            ts = np.linspace(0.25, 1.0, 16) * length * rad[c]
            probe = np.asarray(pts[c]) + ts[None, :, None] * w[:, None, :]
            ok = np.asarray(distance(probe.reshape(-1, 3))).reshape(len(pi), -1) >= inside * rad[c]
            t = np.where(ok.any(axis=1), np.where(ok, ts[None, :], 0.0).max(axis=1), ts[0])
            depth = np.asarray(distance(np.asarray(pts[c]) + t[:, None] * w)) / rad[c]
        closeness = np.sum(d[pi] * d[pj], axis=1)
        # deeper first (to 1 % of the radius), then closer directions; nearly opposite
        # branches have no mean direction to put a node on: last
        degenerate = np.linalg.norm(d[pi] + d[pj], axis=1) < 0.2
        order = np.lexsort((-closeness, -np.round(depth, 2), degenerate))
        best = order[min(int(rank), len(order) - 1)]
        i, j = int(pi[best]), int(pj[best])
        new = len(pts)
        pts.append(np.asarray(pts[c]) + t[best] * w[best])
        rad.append(rad[c])
        ntags.append(ntags[c])
        for k in (inc[i], inc[j]):
            a, b = edges[k]
            edges[k] = (new if a == c else a, new if b == c else b)
        edges.append((c, new))
        etags.append(tuple(sorted(set(etags[inc[i]]) | set(etags[inc[j]]))))
        todo.append(c)
    return Skeleton(np.asarray(pts), np.asarray(rad), np.asarray(edges), ntags, etags, name=sk.name)


def merge_junction_pair(skeleton: Skeleton, a: int, b: int, own_lumen: bool = False) -> tuple[Skeleton, int]:
    """Merge junctions ``a`` and ``b`` and the branch between them into one junction.

    The merged junction sits at the mean of the two with the larger radius; the other
    nodes keep their order. With ``own_lumen``, a branch of either junction that runs
    fused with the link past the link's middle (:func:`_fused_runs`) leaves the
    merged junction from the link's middle: its fused nodes up to its first one past the
    middle whose axis lies outside the link's lumen go into the junction (else it would
    leave the junction backwards, along the link); from that one on they stay its first
    nodes, so that its first segment follows its fused stretch (re-rooted at the end of the
    stretch, the segment cuts the stretch's outer side out of the blocks; through a node
    still inside the link's lumen, it leaves along the link again: docs/junctions.md,
    h17/pair to h19/pair). Where the fused siblings come from one end only and leave the
    link past its other end (the node they leave through is nearest that end), the
    merged junction stands at that other junction instead: their lumen parts from the
    link where its branches do (the dense pair, h20/pair).

    Returns
    -------
    skeleton : Skeleton
    node : int
        The merged junction's number in the new skeleton.
    """
    from ..skeleton.graph import branch_paths, contract_nodes

    sk = skeleton
    paths = branch_paths(sk.n_nodes, sk.edges)
    path = next(p for p in paths if {int(p[0]), int(p[-1])} == {a, b})
    keep = min(a, b)
    group = np.arange(sk.n_nodes)
    group[np.asarray(path)] = keep
    at = 0.5 * (sk.points[a] + sk.points[b])
    if own_lumen:
        runs = _fused_runs(sk, paths, path, own_half=True)
        for nodes, _ in runs.values():
            group[nodes] = keep
        (end, (taken, beyond)), *others = runs.items() if runs else [(None, ([], False))]
        if taken and beyond and not others:
            # the fused siblings all come from one end and leave the link past its other end
            # (they part from it where the other junction's branches do): the junction stands there
            at = sk.points[b if end == a else a].copy()
    labels = np.unique(group)
    positions = sk.points[labels].copy()
    positions[np.searchsorted(labels, keep)] = at
    merged = contract_nodes(sk, group, positions)
    return merged, int(np.searchsorted(labels, keep))


def _fused_along_link(sk: Skeleton, paths: list, link: np.ndarray, own_half: bool = False) -> np.ndarray:
    """All the nodes of :func:`_fused_runs`."""
    runs = _fused_runs(sk, paths, link, own_half)
    return np.asarray([n for nodes, _ in runs.values() for n in nodes], np.int64)


def _fused_runs(sk: Skeleton, paths: list, link: np.ndarray, own_half: bool = False) -> dict:
    """Nodes of the link's sibling branches that lie in one lumen with the link past its middle.

    Two 3-junctions closer than their half-sections reach fail where, at one of them, a
    sibling of the link leaves at a narrow angle (or backwards along it): the two tubes
    overlap (axes closer than the sum of the radii) beyond the link's middle, so the
    half-section between them reaches past the other junction (docs/junctions.md, h16/pair).
    Merged, such a sibling would still leave the junction along the link, inside it. Per
    sibling: the run of its first nodes (from the junction; never its last node) whose
    tubes overlap the link's, when that run reaches past the link's middle; else none.
    With ``own_half``, the run ends before its first node that lies past the middle
    (projected onto the link) with its axis outside the link's lumen (at least the link's
    radius from its axis); without such a node, the whole run.

    Returns
    -------
    dict
        The link's end node -> (the fused nodes of its siblings, whether every one of them
        leaves through a node whose nearest point on the link is the link's other end, i.e.
        they all run fused past the other junction); ends without a fused sibling left out.
    """
    P = sk.points[link]
    seg = P[1:] - P[:-1]
    seg_len = np.linalg.norm(seg, axis=1)
    arc = np.r_[0.0, np.cumsum(seg_len)]
    ends = {int(link[0]): 0.0, int(link[-1]): arc[-1]}
    out: dict = {}
    for p in paths:
        if p is link or len(p) < 3:
            continue
        for end, from_end in ends.items():
            if int(p[0]) != end and int(p[-1]) != end:
                continue
            nodes = (p if int(p[0]) == end else p[::-1])[1:-1]
            if len(nodes) == 0:
                continue
            X = sk.points[nodes]
            shape = (len(nodes), len(seg))
            _, t, d = closest_on_segments(X, np.broadcast_to(P[:-1], shape + (3,)), np.broadcast_to(P[1:], shape + (3,)),
                                          np.zeros(shape), np.ones(shape))  # (n, segments); a repeated link point is safe
            k = np.argmin(d, axis=1)
            rows = np.arange(len(nodes))
            r_link = sk.radii[link[k]] + t[rows, k] * (sk.radii[link[k + 1]] - sk.radii[link[k]])
            fused = d[rows, k] < sk.radii[nodes] + r_link
            run = len(nodes) if fused.all() else int(np.argmin(fused))
            along = np.abs(arc[k[:run]] + t[rows[:run], k[:run]] * seg_len[k[:run]] - from_end)
            if run and along.max() > 0.5 * arc[-1]:
                # it leaves through its first fused node past the middle whose axis lies
                # outside the link's lumen (where its own lumen goes on); one inside the
                # lumen would make it leave along the link again (the dense pair)
                outside = (along > 0.5 * arc[-1]) & (d[rows[:run], k[:run]] >= r_link[:run])
                cut = int(np.argmax(outside)) if own_half and outside.any() else run
                taken, beyond = out.get(end, ([], True))
                past = cut < run and np.isclose(along[cut], arc[-1], rtol=1e-9, atol=0.0)
                out[end] = (taken + nodes[:cut].tolist(), bool(beyond and past))
    return out


#: how far (× local radius) the wall may stand from the blocks around a merged pair: the
#: depth from which ``check_coverage`` calls an uncovered patch a missing part (its default)
MERGE_COVER_DEPTH = 0.3


def pair_wall(skeleton: Skeleton, a: int, b: int, project, around: int = 16) -> tuple[np.ndarray, np.ndarray]:
    """Wall points around junctions ``a`` and ``b`` and the branches they start, and the
    local radius at each: the wall that merging the pair must still cover.

    Each branch at ``a`` or ``b`` (the link between them included) is sampled up to the
    second node past its run fused with the link (:func:`_fused_along_link`; the first
    node where there is none): a ring of ``around`` points one radius from the axis, at each
    node and half way to the next, projected onto the wall with ``project``.
    """
    from ..skeleton.graph import branch_paths
    from ..skeleton.probe import plane_basis

    sk = skeleton
    paths = branch_paths(sk.n_nodes, sk.edges)
    link = next(p for p in paths if {int(p[0]), int(p[-1])} == {a, b})
    fused = set(_fused_along_link(sk, paths, link).tolist())
    starts, ends = [], []
    for p in paths:
        for end in {a, b} & {int(p[0]), int(p[-1])}:
            q = p if int(p[0]) == end else p[::-1]
            j = 1 + sum(int(n) in fused for n in q[1:]) if p is not link else len(q) - 1
            stop = min(j + 1, len(q) - 1)
            starts.extend(q[:stop].tolist())
            ends.extend(q[1:stop + 1].tolist())
    seg0, seg1 = np.asarray(starts), np.asarray(ends)
    tangent = sk.points[seg1] - sk.points[seg0]
    length = np.linalg.norm(tangent, axis=1)
    seg0, seg1, tangent = seg0[length > 0], seg1[length > 0], tangent[length > 0] / length[length > 0, None]  # a repeated point has no ring
    e1, e2 = plane_basis(tangent)
    angle = np.linspace(0.0, 2.0 * np.pi, around, endpoint=False)
    ring = np.cos(angle)[None, :, None] * e1[:, None] + np.sin(angle)[None, :, None] * e2[:, None]  # (segments, around, 3)
    w = np.array([0.0, 0.5])[:, None]  # at the node and half way along the segment
    centre = sk.points[seg0][None] + w[..., None] * (sk.points[seg1] - sk.points[seg0])[None]  # (2, segments, 3)
    radius = sk.radii[seg0][None] + w * (sk.radii[seg1] - sk.radii[seg0])[None]  # (2, segments)
    points = centre[:, :, None] + radius[..., None, None] * ring[None]
    return np.asarray(project(points.reshape(-1, 3))), np.repeat(radius.ravel(), around)


def endpoint_caps(points: np.ndarray, radii: np.ndarray, endpoints: np.ndarray, caps, cap_distance: float = 1.0) -> dict:
    """Match endpoints to caps: ``{endpoint node: cap}`` for endpoints within
    ``cap_distance × max(node radius, cap radius)`` of a cap centre (nearest first, one
    endpoint per cap)."""
    if not caps or len(endpoints) == 0:
        return {}
    centers = np.asarray([c.center for c in caps], float)
    crad = np.asarray([c.radius for c in caps], float)
    d = np.linalg.norm(points[endpoints][:, None, :] - centers[None, :, :], axis=2)
    limit = cap_distance * np.maximum(radii[endpoints][:, None], crad[None, :])
    pairs = sorted((d[i, j], i, j) for i, j in zip(*np.nonzero(d <= limit)))
    out, used_e, used_c = {}, set(), set()
    for _, i, j in pairs:
        if i in used_e or j in used_c:
            continue
        out[int(endpoints[i])] = caps[j]
        used_e.add(i)
        used_c.add(j)
    return out


def redistribute_sections(arc: np.ndarray, lo: float, hi: float, min_spacing: float = 0.6) -> tuple[np.ndarray, bool]:
    """Move the interior sections of a branch into ``[lo, hi]``.

    Sections closer to the start than ``lo`` are pushed beyond it together with as many
    following ones as needed to keep their spacing at least ``min_spacing`` times the
    branch's mean spacing (evenly spaced, the first at ``lo``); likewise from the end. When
    the pushes meet, all interior sections are spread evenly over ``[lo, hi]``.

    Returns
    -------
    s : (K+1,) new positions (ends unchanged)
    ok : False when ``lo >= hi`` with interior sections to place.
    """
    s = np.asarray(arc, float).copy()
    K = len(s) - 1
    if K < 2:
        return s, True
    if lo >= hi:
        return s, False
    h = (s[-1] - s[0]) / K * min_spacing

    def push(x, lim):
        m0 = int(np.sum(x[1:-1] < lim))
        if m0 == 0:
            return x
        for m in range(m0, K):
            end = x[m + 1]
            if (end - lim) / m >= h or m + 1 == K:
                break
        x = x.copy()
        x[1 : m + 1] = lim + np.arange(m) * (end - lim) / m
        return x

    s = push(s, lo)
    s = (s[-1] + s[0]) - push((s[-1] + s[0]) - s[::-1], (s[-1] + s[0]) - hi)[::-1]
    inner = s[1:-1]
    if np.any(np.diff(s) <= 0) or inner.min() < lo - 1e-9 or inner.max() > hi + 1e-9:
        n = K - 1
        s[1:-1] = (lo + hi) / 2 if n == 1 else np.linspace(lo, hi, n)
    return s, True


def branch_tubes(branches, pos: np.ndarray, radii: np.ndarray, spacing: float = 0.25) -> tuple:
    """Samples along every branch's axis, ``spacing`` times the local radius apart.

    Returns
    -------
    points (m, 3), radii (m,), the skeleton node nearest each sample along its branch (m,)
    and the distance to it (m,).
    """
    P, R, N, D = [], [], [], []
    for br in branches:
        x, r = pos[br.nodes], radii[br.nodes]
        seg = np.linalg.norm(np.diff(x, axis=0), axis=1)
        n = np.maximum(1, np.ceil(seg / (spacing * np.maximum(np.minimum(r[:-1], r[1:]), 1e-12)))).astype(int)
        f = np.concatenate([np.arange(k) / k for k in n] + [[1.0]])
        e = np.r_[np.repeat(np.arange(len(seg)), n), len(seg) - 1]
        P.append(x[e] + f[:, None] * (x[e + 1] - x[e]))
        R.append(r[e] + f * (r[e + 1] - r[e]))
        far = f > 0.5
        N.append(np.asarray(br.nodes)[e + far])
        D.append(np.where(far, 1.0 - f, f) * seg[e])
    return tuple(map(np.concatenate, (P, R, N, D)))


class SkeletonWays:
    """Distances along the skeleton between its nodes (shortest paths over its segments),
    found from each source node out to the reach its queries need.

    Each source is searched once (again, further, only when a later query needs more
    reach), with the sources of one call batched by the reach they need, so that a large
    tree's sources each explore their own neighbourhood, not the whole tree out to the
    longest reach any one of them needs.

    Parameters
    ----------
    edges : (e, 2) int
    pos : (n, 3) node positions.
    limit : float
        Default reach: ways longer than this are ``inf`` unless a query asks further.
    """

    def __init__(self, edges: np.ndarray, pos: np.ndarray, limit: float):
        from scipy.sparse import coo_matrix

        w = np.linalg.norm(pos[edges[:, 0]] - pos[edges[:, 1]], axis=1)
        n = len(pos)
        self.graph = coo_matrix((np.maximum(w, 1e-12), (edges[:, 0], edges[:, 1])), shape=(n, n)).tocsr()
        self.limit = float(limit)
        self.n = n
        self.reach = np.full(n, -1.0)  # how far each source was searched (-1: not yet)
        # the finite ways found, keyed src * n + dst, in two sorted levels (the recent
        # searches apart until they are an eighth of the rest, as rays.RayCache): a large
        # tree's sources reach few nodes, so dense rows would be mostly inf, and re-sorting
        # every way found on every call was the cost
        self.levels = [(np.empty(0, np.int64), np.empty(0)), (np.empty(0, np.int64), np.empty(0))]

    def _search(self, src: np.ndarray, reach: np.ndarray) -> None:
        """Search from each ``src`` (unique) out to its ``reach``, in chunks of sources of
        similar reach."""
        from scipy.sparse.csgraph import dijkstra

        order = np.argsort(reach, kind="stable")
        src, reach = src[order], reach[order]
        keys, ways = [], []
        for lo in range(0, len(src), 256):  # bounded (256, n) blocks
            chunk, lim = src[lo:lo + 256], float(reach[lo:lo + 256].max())
            d = dijkstra(self.graph, directed=False, indices=chunk, limit=lim)
            r, c = np.nonzero(np.isfinite(d))
            keys.append(chunk[r] * self.n + c)
            ways.append(d[r, c])
            self.reach[chunk] = lim
        k, v = np.concatenate(keys), np.concatenate(ways)
        main, recent = self.levels
        k, v = np.concatenate([recent[0], k]), np.concatenate([recent[1], v])
        if 8 * len(k) > len(main[0]):
            k, v = np.concatenate([main[0], k]), np.concatenate([main[1], v])
            main = (np.empty(0, np.int64), np.empty(0))
        # a source searched again further: its newer (longer) row last, found first below
        o = np.argsort(k, kind="stable")
        self.levels = [main, (k[o], v[o])]

    def __call__(self, src: np.ndarray, dst: np.ndarray, reach=None) -> np.ndarray:
        """(k,) way from node ``src[i]`` to node ``dst[i]``: exact where it is at most
        ``reach[i]`` (default: the ``limit``), else exact or ``inf``."""
        src, dst = np.asarray(src, np.int64), np.asarray(dst, np.int64)
        need = np.broadcast_to(np.asarray(self.limit if reach is None else reach, float), src.shape)
        short = need > self.reach[src]
        if short.any():
            s, inv = np.unique(src[short], return_inverse=True)
            most = np.zeros(len(s))
            np.maximum.at(most, inv, need[short])
            # a quarter more than asked: a source asked again a little further is not searched again
            self._search(s, np.maximum(1.25 * most, self.limit))
        q = src * self.n + dst
        out = np.full(len(q), np.inf)
        for keys, ways in reversed(self.levels):  # the recent level first
            if len(keys) == 0:
                continue
            i = np.searchsorted(keys, q, side="right") - 1  # the last of equal keys: the latest search
            hit = (i >= 0) & np.isinf(out)
            hit[hit] = keys[i[hit]] == q[hit]
            out[hit] = ways[i[hit]]
        return out


class Territory:
    """What the section rays' territory cut (:meth:`_Sections._own_territory`) needs from
    the skeleton, kept while the skeleton does not change.

    A builder assembles the whole tree on every fix round, but its branches, node
    positions and radii mostly stay as they were (only junction moves and splits change
    them): the tube samples (:func:`branch_tubes`) and their tree, the ways along the
    skeleton (:class:`SkeletonWays`) and the cut of every ray already clipped (each ray's cut
    depends only on the ray, its section's node and the skeleton) are found once.

    Parameters
    ----------
    branches : list of _Branch
    pos : (n, 3) node positions.
    radii : (n,) node radii.
    edges : (e, 2) int
    """

    def __init__(self, branches, pos: np.ndarray, radii: np.ndarray, edges: np.ndarray):
        from scipy.spatial import cKDTree

        from ..rays import RowCache

        self.key = Territory.key_of(branches, pos, radii, edges)
        self.graph_key = Territory.key_of(branches, np.zeros((0, 3)), radii, edges)  # all but the positions
        self.pos, self.edges = np.array(pos, float), np.array(edges)
        self.Q, self.rq, self.q_node, self.q_off = branch_tubes(branches, self.pos, radii)
        self.tree = cKDTree(self.Q) if len(self.Q) else None
        self.ways = SkeletonWays(self.edges, self.pos, 0.0)  # searched as far as each source's rays need
        # ray origin (3), direction (3), length, radius, section node -> cut length
        self.cuts = RowCache(9)
        self.ended = {}  # touched cap ids -> the rays' end test at their planes (:func:`.ended.ended_at_touched_caps`)

    @staticmethod
    def key_of(branches, pos: np.ndarray, radii: np.ndarray, edges: np.ndarray) -> bytes:
        """A digest of everything the territory depends on (exact bytes)."""
        import hashlib

        h = hashlib.blake2b(digest_size=16)
        for a in (pos, radii, edges):
            a = np.ascontiguousarray(a)
            h.update(str((a.dtype, a.shape)).encode())
            h.update(a.tobytes())
        for br in branches:
            h.update(np.ascontiguousarray(br.nodes, np.int64).tobytes())
            h.update(b"|")
        return h.digest()

    def inherit(self, old: "Territory") -> None:
        """Keep the cuts of ``old`` (the same skeleton with some nodes moved: a junction
        moved by a fix) that the move cannot change.

        A ray's cut depends on the tube samples within their radius of its points (at most
        its length from its origin) and on the ways from its section's node out to its
        reach (length + 2 r + start + 3 r_q + q_off, see :meth:`_Sections._own_territory`);
        a way through a moved segment is at least as long as the straight way to it. So a
        ray whose node stayed and whose node lies farther from every moved segment (before
        and after the move) than its reach plus its start and the largest tube radius cuts
        as it did."""
        if old.graph_key != self.graph_key or len(old.cuts) == 0:
            return
        moved = np.flatnonzero(np.any(old.pos != self.pos, axis=1))
        if len(moved) == 0:
            self.cuts = old.cuts
            return
        e = self.edges[np.isin(self.edges, moved).any(axis=1)]
        a = np.r_[old.pos[e[:, 0]], self.pos[e[:, 0]]]
        b = np.r_[old.pos[e[:, 1]], self.pos[e[:, 1]]]
        rq, qo = max(self.rq.max(initial=0.0), old.rq.max(initial=0.0)), max(self.q_off.max(initial=0.0), old.q_off.max(initial=0.0))
        stayed = np.ones(len(self.pos), bool)
        stayed[moved] = False

        def unchanged(rows):
            node, row_of = np.unique(rows[:, 8].astype(np.int64), return_inverse=True)  # per node, not per ray
            x = self.pos[node]
            ab = b - a
            t = np.clip(np.einsum("pkj,kj->pk", x[:, None, :] - a[None], ab) / np.maximum(np.sum(ab * ab, axis=1), 1e-300), 0.0, 1.0)
            near = np.linalg.norm(x[:, None, :] - (a[None] + t[:, :, None] * ab[None]), axis=2).min(axis=1)
            start = np.linalg.norm(rows[:, :3] - x[row_of], axis=1)
            bound = np.nan_to_num(rows[:, 6]) + 2.0 * rows[:, 7] + 2.0 * start + 4.0 * rq + qo
            return stayed[node][row_of] & (near[row_of] > bound)

        old.cuts.keep(unchanged)
        self.cuts = old.cuts
