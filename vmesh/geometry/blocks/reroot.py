"""A junction's thin sibling that runs backwards in the link's lumen, re-rooted at the other junction.

Two 3-junctions A and B closer than their half-sections reach, where B's thin branch T
leaves backwards (towards A) and runs inside the link's lumen until it parts from the link
past the link's middle, by A (the generator's ``kissing`` branch grown from a vessel next
to a junction: s1 g0012 given, docs/junctions.md h21/pair, h24/builder). No merge, split or
placement the builder has blocks it: B's half-plane between T and the link reaches past A,
and merged (at the link's middle) T still leaves along the link. Its lumen parts from the
link where A's branches do, so T is A's branch: it leaves A through its first node whose
tube clears the link's lumen, past a new node at the middle of its new first segment
moved to the deepest point of its section. The builder's last try, opt-in
(``reroot_backwards``): it builds the generated configuration
(``tests/test_reroot.py``). The sibling is judged by its tube, not its axis: a kissing
tube may leave the lumen with its axis before the link's middle and with its tube past
it; re-rooted through its first tube-clear node its blocks build and cover the pair's
wall. Where the deepest point fails, the builder tries the new node at ring placements
around the section's centre (:func:`section_placements`, the far junction then on the
link's chord), each on a share of a budget (docs/junctions.md, the re-rooted branch's
placements).
"""

from __future__ import annotations

import numpy as np

from ...skeleton import Skeleton
from ..skeleton.graph import branch_paths
from ..skeleton.probe import plane_basis
from ..variation import closest_on_segments

#: how far past the link's middle (towards the other junction, share of the link's length)
#: a sibling must run inside the link's lumen before it counts as the other junction's
#: branch: at the middle, either junction would do and the merge (at the middle) serves
REROOT_PAST_MIDDLE = 0.5
#: a sibling's node counts as inside the link's lumen while its axis lies within the link's
#: radius plus this share of its own radius: 1, its tube still overlaps the lumen. By the
#: axis alone (0) a kissing tube whose axis leaves the lumen just before the link's middle
#: but whose tube runs fused past it would not be offered
TUBE_CLEARANCE = 1.0
#: a backwards sibling is a thin branch: its radius at most this share of the link's
#: (median) radius. Two daughters of one junction, of like radii and a small angle apart,
#: run with their tubes fused past the middle of a short link too, and are an ordinary
#: bifurcation, not a branch of the other junction
THIN_SHARE = 0.6


def _link_path(sk: Skeleton, paths: list, a: int, b: int) -> np.ndarray | None:
    return next((p for p in paths if {int(p[0]), int(p[-1])} == {a, b}), None)


def _backwards_sibling(sk: Skeleton, paths: list, link: np.ndarray, end: int):
    """At the link's end ``end``: a thin sibling (``THIN_SHARE``) whose first node lies inside the link's lumen
    and which leaves the lumen past the link's middle from ``end``, judged by its *tube*:
    a node is inside while its axis lies closer to the link's axis than the link's radius
    plus its own (``TUBE_CLEARANCE``). Returns (the sibling's nodes from ``end``, the
    index of its first node whose tube clears the lumen) or None."""
    P = sk.points[link]
    seg_len = np.linalg.norm(P[1:] - P[:-1], axis=1)
    arc = np.r_[0.0, np.cumsum(seg_len)]
    from_end = 0.0 if int(link[0]) == end else arc[-1]
    thin = THIN_SHARE * float(np.median(sk.radii[link]))
    for p in paths:
        if p is link or len(p) < 3 or end not in (int(p[0]), int(p[-1])):
            continue
        nodes = p if int(p[0]) == end else p[::-1]
        if sk.radii[nodes[1]] > thin:
            continue
        X = sk.points[nodes[1:-1]]
        shape = (len(X), len(seg_len))
        _, t, d = closest_on_segments(X, np.broadcast_to(P[:-1], shape + (3,)), np.broadcast_to(P[1:], shape + (3,)),
                                      np.zeros(shape), np.ones(shape))
        k = np.argmin(d, axis=1)
        rows = np.arange(len(X))
        r_link = sk.radii[link[k]] + t[rows, k] * (sk.radii[link[k + 1]] - sk.radii[link[k]])
        along = np.abs(arc[k] + t[rows, k] * seg_len[k] - from_end)
        inside = d[rows, k] < r_link + TUBE_CLEARANCE * sk.radii[nodes[1:-1]]
        if not inside[0] or inside.all():
            continue
        out = int(np.argmin(inside))  # its first node outside the link's lumen
        if along[out] > REROOT_PAST_MIDDLE * arc[-1]:
            return nodes, out + 1
    return None


#: the new first node's search in its section: rings (× the branch's radius) and directions
SECTION_RINGS = np.linspace(0.125, 1.0, 8)
SECTION_DIRECTIONS = 16


def deepest_in_section(distance, point: np.ndarray, tangent: np.ndarray, radius: float) -> tuple[np.ndarray, float]:
    """The point of the section through ``point`` (normal ``tangent``) within ``radius``
    of it that lies deepest inside the wall, and its wall distance: the centre of the
    branch's lumen where it runs fused with others (chords there escape into them)."""
    trial = np.r_[point[None], section_rings(point, tangent, radius, SECTION_RINGS, SECTION_DIRECTIONS)]
    d = np.asarray(distance(trial), float)
    best = int(np.argmax(d))
    return trial[best], float(d[best])


#: the other placements of the new first node, around its section's centre (the middle of
#: the new first segment): rings at these shares of the branch's radius, ``PLACEMENT_DIRECTIONS``
#: directions each. Whether the re-rooted 4-junction builds turns on where in its section
#: that node lies, by no rule found (s1 g0012 given: the deepest point fails, 4 of 16 ring
#: points build; docs/junctions.md h25/builder), so the builder tries them in turn
PLACEMENT_RINGS = (0.3, 0.6)
PLACEMENT_DIRECTIONS = 8
#: placements in all: the deepest point, then the rings
N_PLACEMENTS = 1 + len(PLACEMENT_RINGS) * PLACEMENT_DIRECTIONS


def section_rings(point: np.ndarray, tangent: np.ndarray, radius: float, rings, directions: int) -> np.ndarray:
    """(len(rings) * directions, 3) points around ``point`` in the plane normal to
    ``tangent``: circles of ``rings`` × ``radius``, ``directions`` evenly spaced points each,
    the first ring first."""
    e1, e2 = plane_basis(tangent[None])
    angle = 2 * np.pi * np.arange(directions) / directions
    ring = np.cos(angle)[:, None] * e1 + np.sin(angle)[:, None] * e2  # (directions, 3)
    return (point + radius * np.asarray(rings, float)[:, None, None] * ring[None]).reshape(-1, 3)


def section_placements(point: np.ndarray, tangent: np.ndarray, radius: float) -> np.ndarray:
    """The ring placements (k, 3) of a re-rooted branch's new first node around ``point`` in
    the plane normal to ``tangent``: ``PLACEMENT_RINGS`` × ``radius``, ``PLACEMENT_DIRECTIONS``
    directions each, the inner ring first."""
    return section_rings(point, tangent, radius, PLACEMENT_RINGS, PLACEMENT_DIRECTIONS)


def _on_chord(sk: Skeleton, end: int, gone: int, distance) -> tuple[np.ndarray, float]:
    """The far junction ``end`` once its sibling (first node ``gone``) has gone: a plain node
    of the link, moved onto the chord between its two other neighbours (its position was
    the junction's, off the link's own course), with its wall distance as radius."""
    nb = [int(n) for n in sk.neighbors(end) if int(n) != gone]
    if len(nb) != 2:
        return sk.points[end], float(sk.radii[end])
    u = sk.points[nb[1]] - sk.points[nb[0]]
    s = float(np.clip((sk.points[end] - sk.points[nb[0]]) @ u / max(u @ u, 1e-300), 0.0, 1.0))
    at = sk.points[nb[0]] + s * u
    depth = float(np.asarray(distance(at[None]), float)[0])
    return (at, depth) if depth > 0 else (sk.points[end], float(sk.radii[end]))


def reroot_backwards_siblings(skeleton: Skeleton, a: int, b: int, distance, placement: int = 0) -> Skeleton | None:
    """The skeleton with each junction's sibling that runs backwards in the link's lumen
    past the link's middle re-rooted at the link's other end (see the module docstring).

    Parameters
    ----------
    skeleton : Skeleton
    a, b : int
        Two junctions joined by one branch (the link).
    distance : callable
        Signed distance, positive inside (the new first node is centred in its section).
    placement : int
        Which of :func:`section_placements` the new first node takes (0: the deepest point
        of its section, the others: a ring around the section's centre, ``0 <= placement <
        N_PLACEMENTS``); None where that placement lies outside the wall. From 1 on, the far junction (a plain node of the link once its sibling has
        gone) also moves onto the chord between its neighbours.

    Returns
    -------
    Skeleton or None
        None where neither junction has such a sibling (or the placement lies outside the wall).
    """
    sk = skeleton
    paths = branch_paths(sk.n_nodes, sk.edges)
    link = _link_path(sk, paths, a, b)
    if link is None:
        return None
    moves = [(end, other, got) for end, other in ((a, b), (b, a)) if (got := _backwards_sibling(sk, paths, link, end)) is not None]
    if not moves:
        return None
    points, radii = list(sk.points), list(sk.radii)
    node_tags = list(sk.node_tags)
    edges = {tuple(sorted(e)): tag for e, tag in zip(sk.edges.tolist(), sk.edge_tags)}
    drop = set()
    for end, other, (nodes, keep) in moves:
        tag = edges.pop(tuple(sorted((int(nodes[0]), int(nodes[1])))))
        for n, m in zip(nodes[1:keep], nodes[2:keep + 1]):
            edges.pop(tuple(sorted((int(n), int(m)))))
        drop.update(int(n) for n in nodes[1:keep])
        target = int(nodes[keep])
        tangent = sk.points[target] - sk.points[other]
        tangent = tangent / max(np.linalg.norm(tangent), 1e-300)
        mid = 0.5 * (sk.points[other] + sk.points[target])
        if placement == 0:
            centre, depth = deepest_in_section(distance, mid, tangent, float(sk.radii[target]))
        else:
            centre = section_placements(mid, tangent, float(sk.radii[target]))[placement - 1]
            depth = float(np.asarray(distance(centre[None]), float)[0])
            if depth <= 0:
                return None  # outside the wall: no node there (the next placement is tried)
            points[end], radii[end] = _on_chord(sk, end, int(nodes[1]), distance)
        m = len(points)
        points.append(centre)
        radii.append(depth)
        node_tags.append(())
        edges[(other, m)] = tag
        edges[(m, target)] = tag
    keep_node = np.array([i not in drop for i in range(len(points))])
    number = np.cumsum(keep_node) - 1
    pairs = np.asarray(list(edges), np.int64)
    return Skeleton(np.asarray(points)[keep_node], np.asarray(radii)[keep_node], number[pairs],
                    node_tags=[t for t, k in zip(node_tags, keep_node) if k], edge_tags=list(edges.values()))
