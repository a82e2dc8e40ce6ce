"""Defects of real centerlines that the cleaning undoes before the block builder sees them:
repeated points (two branches leaving a junction along one segment, zero-length segments),
second paths inside a vessel's lumen, pieces of surface pieces not meshed, and bridges
through the neck where two vessels touch."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from ...skeleton import Skeleton
from .clean import node_scale
from .graph import contract_nodes


def weld_coincident_nodes(skeleton: Skeleton, tolerance: float = 0.001) -> tuple[Skeleton, int]:
    """Weld nodes closer than ``tolerance`` x the smaller of their radii into one node.

    Centerline files repeat points: an SWC child that starts on its parent's point (a
    zero-length segment), or two children that both start on the same point, so that two
    branches leave their junction along one and the same segment (0 degrees apart) and
    only part at its far end. Welding makes the shared point the junction, where the
    branches really part, and removes the zero-length segments. Welding is transitive, so
    ``tolerance`` must stay well below the node spacing (a dense centerline would weld
    into one node).

    Returns
    -------
    skeleton : Skeleton
    n_welded : int
        Number of nodes that disappeared.
    """
    n = skeleton.n_nodes
    if tolerance <= 0 or n < 2:
        return skeleton.copy(), 0
    scale = node_scale(skeleton)
    pairs = cKDTree(skeleton.points).query_pairs(tolerance * float(scale.max()), output_type="ndarray")
    if len(pairs):
        a, b = pairs.T
        gap = np.linalg.norm(skeleton.points[a] - skeleton.points[b], axis=1)
        pairs = pairs[gap <= tolerance * np.minimum(scale[a], scale[b])]
    if len(pairs) == 0:
        return skeleton.copy(), 0
    adj = sp.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    label = connected_components(adj, directed=False)[1]
    first = np.full(label.max() + 1, n)
    np.minimum.at(first, label, np.arange(n))  # a group keeps its first node's place
    out = contract_nodes(skeleton, first[label])
    return out, n - out.n_nodes


def _distance_to_polyline(q: np.ndarray, P: np.ndarray) -> float:
    """Distance from point ``q`` to the polyline through the points ``P``."""
    if len(P) == 1:
        return float(np.linalg.norm(q - P[0]))
    a, d = P[:-1], np.diff(P, axis=0)
    t = np.clip(((q - a) * d).sum(1) / np.maximum((d * d).sum(1), 1e-300), 0.0, 1.0)
    return float(np.linalg.norm(a + t[:, None] * d - q, axis=1).min())


def shadowed(skel: Skeleton, end: int, junction: int, spur: np.ndarray, paths: list, scale: np.ndarray, shadow: float) -> bool:
    """Whether the free ``end`` of a spur lies within ``shadow`` x its radius of another
    branch leaving the same junction (inside that vessel's lumen, near its axis)."""
    for p in paths:
        if junction not in (p[0], p[-1]) or end in (p[0], p[-1]) or len(p) == len(spur) and np.array_equal(p, spur):
            continue
        if _distance_to_polyline(skel.points[end], skel.points[p]) < shadow * scale[end]:
            return True
    return False


def drop_outside_components(skeleton: Skeleton, distance, share: float = 0.5) -> tuple[Skeleton, list]:
    """Remove the connected pieces of a skeleton that lie mostly outside the surface.

    A centerline of several trees given with a surface of which only the largest piece is
    meshed (``repair_surface`` drops the others) holds the centerlines of the dropped
    pieces too: pulled inside, they would be crammed into the meshed vessel as junk
    branches. A piece with more than ``share`` of its nodes outside (signed distance below
    zero) goes, unless it is the piece most inside.

    Parameters
    ----------
    skeleton : Skeleton
    distance : callable
        Signed distance, positive inside.
    share : float
        Least share of a piece's nodes outside for it to go.

    Returns
    -------
    skeleton : Skeleton
    dropped : list of (n_nodes, centroid) per removed piece
    """
    from .graph import component_labels, remove_nodes

    if skeleton.n_nodes == 0 or skeleton.n_components < 2:
        return skeleton.copy(), []
    label = component_labels(skeleton.n_nodes, skeleton.edges)
    out = np.asarray(distance(skeleton.points), float) < 0
    size = np.bincount(label)
    frac = np.bincount(label, weights=out) / size
    gone = frac > share
    gone[np.argmin(frac)] = False  # the best piece always stays
    if not gone.any():
        return skeleton.copy(), []
    dropped = [(int(size[k]), skeleton.points[label == k].mean(axis=0)) for k in np.flatnonzero(gone)]
    return remove_nodes(skeleton, gone[label], bridge=False), dropped


def _lumen_groups(points: np.ndarray, radii: np.ndarray, distance, samples: int = 9) -> np.ndarray:
    """Group label per node of ``points``: two nodes are in one group when the chord between
    them stays inside the lumen at no less than half the smaller of their radii."""
    m = len(points)
    i, j = np.triu_indices(m, 1)
    t = np.linspace(0.0, 1.0, samples)[1:-1]
    chord = points[i, None, :] * (1.0 - t)[None, :, None] + points[j, None, :] * t[None, :, None]
    depth = np.asarray(distance(chord.reshape(-1, 3)), float).reshape(len(i), -1).min(axis=1)
    seen = depth >= 0.5 * np.minimum(radii[i], radii[j])
    adj = sp.coo_matrix((np.ones(int(seen.sum())), (i[seen], j[seen])), shape=(m, m))
    return connected_components(adj, directed=False)[1]


def cut_necks(skeleton: Skeleton, distance, neck: float = 0.25) -> tuple[Skeleton, int]:
    """Cut the bridges a skeleton makes through the neck where two vessels touch.

    Where two vessels touch (kissing vessels, a tree whose tubes overlap), thinning joins
    their centerlines across the contact: a junction node sits in the neck, with an
    inscribed radius a small fraction of its branches' (BraVa BG0002 extracted: 0.010
    against 0.36-0.76), and its branches leave it into one half-space, so that the block
    builder finds the junction far out of any plane. A junction whose radius is below
    ``neck`` x the median radius of its neighbours is such a neck when its neighbours fall
    into groups that do not see each other through the lumen (the chord between them
    leaves it, or runs shallower than half their radius): a group of one loses its edge
    to the node (the bridge), a group of two is joined directly (the vessel that ran
    through the neck), a larger group keeps the node. A cut that would split the skeleton
    in pieces is not made.

    Returns
    -------
    skeleton : Skeleton
    n_cut : int
        Number of necks cut.
    """
    from .graph import remove_nodes

    sk = skeleton.copy()
    n_cut = 0
    # from the last node down: removing a node renumbers only the nodes after it
    for c in np.flatnonzero(sk.degrees >= 3)[::-1].tolist():
        r = sk.radii
        nb = sk.neighbors(c)
        if not r[c] < neck * np.median(r[nb]):
            continue
        group = _lumen_groups(sk.points[nb], r[nb], distance)
        sizes = np.bincount(group)
        if len(sizes) < 2:
            continue  # one vessel on every side: a junction placed badly, not a neck
        gone = nb[sizes[group] <= 2]
        keep = ~(np.isin(sk.edges, gone).any(axis=1) & (sk.edges == c).any(axis=1))
        pairs = np.array([nb[group == g] for g in np.flatnonzero(sizes == 2)], np.int64).reshape(-1, 2)
        tags = [t for t, k in zip(sk.edge_tags, keep) if k] + [()] * len(pairs)
        cut = sk.copy(edges=np.r_[sk.edges[keep], pairs], edge_tags=tags)
        if not (sizes > 2).any():
            cut = remove_nodes(cut, np.arange(cut.n_nodes) == c, bridge=False)
        if cut.n_components > sk.n_components:
            continue  # the bridge is all that holds two parts together
        sk, n_cut = cut, n_cut + 1
    sk, n_links = _cut_neck_links(sk, distance)
    sk, n_cross = cut_crossing_bridges(sk)
    return sk, n_cut + n_links + n_cross


def cut_crossing_bridges(skeleton: Skeleton, reach: float = 1.25, straight: float = 135.0) -> tuple[Skeleton, int]:
    """Cut the short links thinning puts between two vessels that touch side by side.

    Where two vessels run past each other in contact (kissing vessels), their lumens fuse
    over the contact and thinning joins their centerlines with a short link: an "H", two
    3-junctions whose other two branches each run straight through (one vessel each) and
    a link between them no longer than the two vessels' radii together (generated g0000
    extracted: 0.106 between junctions of radius 0.048 and 0.059, the vessels straight
    through them at 180 and 138 degrees). The tree has no such cycle, and the block builder
    cannot give the link's two close junctions room. A link is cut (its edges and inner
    nodes removed) when it lies on a cycle (the skeleton stays connected), is at most
    ``reach`` x the sum of its end junctions' radii long (straight: every node of it within
    that distance of both junctions, the distance of two touching vessels' axes; the path
    thinning takes through the neck bends), and at both ends the other two
    branches, measured two junction radii along them, are at least ``straight`` degrees
    apart. A real bifurcation leaves its parent at less than that, and real anastomoses
    (communicating arteries) are many radii long.

    Returns
    -------
    skeleton : Skeleton
    n_cut : int
        Number of links cut.
    """
    from .graph import branch_paths, remove_nodes

    sk = skeleton
    deg = sk.degrees
    paths = [np.asarray(q) for q in branch_paths(sk.n_nodes, sk.edges)]
    arcs = [np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(sk.points[q], axis=0), axis=1))] for q in paths]

    def heading(c, q, arc):
        # direction from junction c along path q (which starts or ends at c), two radii on
        if q[0] != c:
            q, arc = q[::-1], arc[-1] - arc[::-1]
        k = min(int(np.searchsorted(arc, 2.0 * sk.radii[c])), len(q) - 1)
        v = sk.points[q[k]] - sk.points[c]
        return v / max(np.linalg.norm(v), 1e-300)

    for q, arc in zip(paths, arcs):
        a, b = int(q[0]), int(q[-1])
        # straight distances, not along the link: thinning's path through the neck bends
        # (2.07 along a link whose junctions are 1.54 apart, radii 0.61 + 0.97); a vessel
        # that wanders off between two close junctions is no such link
        span = np.linalg.norm(sk.points[q][:, None, :] - sk.points[[a, b]][None], axis=2).max()
        if a == b or deg[a] != 3 or deg[b] != 3 or span > reach * (sk.radii[a] + sk.radii[b]):
            continue
        through = True
        for c in (a, b):
            others = [(p, w) for p, w in zip(paths, arcs) if (p[0] == c or p[-1] == c) and p is not q]
            if len(others) != 2:
                through = False
                break
            d1, d2 = heading(c, *others[0]), heading(c, *others[1])
            through &= bool(np.degrees(np.arccos(np.clip(d1 @ d2, -1.0, 1.0))) >= straight)
        if not through:
            continue
        link = {(min(u, v), max(u, v)) for u, v in zip(q[:-1].tolist(), q[1:].tolist())}
        keep = np.array([(min(u, v), max(u, v)) not in link for u, v in sk.edges.tolist()])
        cut = sk.copy(edges=sk.edges[keep], edge_tags=[t for t, k in zip(sk.edge_tags, keep) if k])
        inner = np.zeros(sk.n_nodes, bool)
        inner[q[1:-1]] = True
        if inner.any():
            cut = remove_nodes(cut, inner, bridge=False)
        if cut.n_components > sk.n_components:
            continue  # the link holds two parts together
        more, n = cut_crossing_bridges(cut, reach, straight)  # node numbers changed: look again
        return more, n + 1
    return sk, 0


def _straightest_turn(sk: Skeleton, c: int, nb) -> float:
    """The largest turn, in degrees, of the path ``a - c - b`` (``nb = (a, b)``) at ``a``, ``c``
    and ``b``, each end continuing along its straightest other segment (0 where it has none).

    A skeleton link into a touching vessel leaves each vessel's axis sideways, towards the
    contact on its wall (turns near a right angle at ``a`` or ``b``); the throat of a
    stenosis lies on its vessel's axis, which the path follows (small turns): the same
    narrow node with two lumen groups (:func:`_lumen_groups` sees a throat narrower than
    half its neighbours as shallow as a contact), told apart by the way the path runs."""
    P = sk.points

    def angle(u, v):
        cos = float(u @ v) / max(float(np.linalg.norm(u) * np.linalg.norm(v)), 1e-300)
        return float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))

    a, b = int(nb[0]), int(nb[1])
    turns = [angle(P[c] - P[a], P[b] - P[c])]
    for end, nxt in ((a, c), (b, c)):
        others = [int(o) for o in sk.neighbors(end) if int(o) != nxt]
        if others:
            turns.append(min(angle(P[end] - P[o], P[nxt] - P[end]) for o in others))
    return max(turns)


def _cut_neck_links(skeleton: Skeleton, distance) -> tuple[Skeleton, int]:
    """Remove the nodes of a skeleton's cycles that sit in the neck where two vessels touch.

    Thinning can run one vessel's centerline across the contact into the other (generated
    g0015: the big vessel's axis turns, 0.8 short of its end, through a node of radius 0.2
    into the end of the kissing branch, radius 0.45, beside it), closing a cycle that the
    vessel tree does not have. Such a node is narrower than half the smaller of its two
    neighbours, and the chord between the neighbours leaves the lumen or runs shallower
    than half their radius (:func:`_lumen_groups`: they are in two vessels), and the path
    through it turns sideways (:func:`_straightest_turn`). A stenosis on a tree is never cut
    (removing its node would split the skeleton), nor one whose lumen still joins its
    neighbours, nor one on a loop whose skeleton runs straight through it.
    """
    from .graph import remove_nodes

    sk, r = skeleton, skeleton.radii
    cand = [c for c in np.flatnonzero(sk.degrees == 2).tolist()
            if len(sk.neighbors(c)) == 2 and r[c] < 0.5 * r[sk.neighbors(c)].min()]
    for c in sorted(cand, key=lambda c: r[c] / r[sk.neighbors(c)].min()):
        nb = sk.neighbors(c)
        if len(np.unique(_lumen_groups(sk.points[nb], r[nb], distance))) < 2:
            continue  # a narrowing that the lumen runs through
        if _straightest_turn(sk, c, nb) <= 45.0:
            continue  # the path runs on along its vessels' axes: a stenosis (on a loop), not a link
        cut = remove_nodes(sk, np.arange(sk.n_nodes) == c, bridge=False)
        if cut.n_components > sk.n_components:
            continue  # the only way between two parts: a stenosis, not a link
        more, k = _cut_neck_links(cut, distance)  # node numbers changed: look again
        return more, k + 1
    return sk.copy(), 0
