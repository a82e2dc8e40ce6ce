"""Which close junction pairs the block builder can block.

Two junctions joined by a branch shorter than the near junction's half-section reach
along it: the near junction's half-sections reach past the far one. The builder's blocks
on the link stay valid when every daughter of the far junction stays in the link's sector
of the near junction, and cut across the far junction's crotch when one runs across the
near junction's half-plane between the link and a sibling (docs/junctions.md: of the
synthetic crowded pairs, those with a margin of 10 degrees or more built valid blocks, 9
of 9, those under 10 did not, 18 of 18).

The skeleton cleaning (:func:`.clean.separate_parallel_branches`) asks this of the
junction pairs its moves made (:func:`_unblockable_moves`).
"""

from __future__ import annotations

import numpy as np

from ...skeleton import Skeleton
from .graph import arc_length, branch_paths, branches_at, vector_angle

#: least crossing margin (degrees) of a blockable pair. From the synthetic two-junction
#: sweep (``benchmarks/junction_pairs.py --pair``: daughters 10 degrees inside the link's
#: sector built in the first try, 10 degrees across did not), not from a corpus run; the
#: cleaning undoes the same moves at 5 and 15 on every vessel measured (docs/junctions.md).
CROSSING_MARGIN = 10.0

#: how far (x the near junction's radius) its half-sections reach along a branch at most
#: (the block builder's ``REACH_RADII`` is this value); a longer link leaves the pair room.
PAIR_REACH = 3.0


def branch_direction(points: np.ndarray, path, ahead: float) -> np.ndarray:
    """Unit direction of a branch seen from its first node.

    Parameters
    ----------
    points : (n, 3) float
        Node positions of the skeleton.
    path : sequence of int
        The branch's nodes, from the node it is seen from.
    ahead : float
        Arc length along the branch (the skeleton's length units; the callers take one
        junction radius) of the node the direction points at; the last node on a shorter
        branch.

    Returns
    -------
    (3,) float
        Unit direction from the first node to that node.
    """
    P = points[np.asarray(path)]
    arc = arc_length(P)
    k = int(min(np.searchsorted(arc, ahead), len(P) - 1))
    d = P[k] - P[0]
    return d / max(float(np.linalg.norm(d)), 1e-300)


def crossing_margin(link: np.ndarray, siblings: np.ndarray, daughters: np.ndarray) -> float:
    """How far the far junction's daughters stay inside the link's sector of the near junction.

    A daughter with a margin under about :data:`CROSSING_MARGIN` runs across the near
    junction's half-plane between the link and its nearest sibling.

    Parameters
    ----------
    link : (3,) float
        Unit direction from the near junction along the link to the far one.
    siblings : (s, 3) float
        Unit directions of the near junction's other branches.
    daughters : (d, 3) float
        Unit directions of the far junction's branches but the link.

    Returns
    -------
    float
        The least ``angle(daughter, nearest sibling) - angle(daughter, link)`` over the
        daughters, in degrees; infinite when either set is empty (no half-plane to cross).
    """
    siblings, daughters = np.reshape(siblings, (-1, 3)), np.reshape(daughters, (-1, 3))
    if not len(siblings) or not len(daughters):
        return float("inf")
    angle = lambda u, v: np.degrees(vector_angle(u, v))
    to_sibling = angle(daughters[:, None, :], siblings[None, :, :]).min(axis=1)
    return float((to_sibling - angle(daughters, np.asarray(link)[None])).min())


def pair_margin(skeleton: Skeleton, near: int, far: int, paths=None) -> float:
    """:func:`crossing_margin` of the junction pair ``near`` - ``far``, joined by a branch.

    Parameters
    ----------
    skeleton : Skeleton
    near, far : int
        The two junctions (node indices).
    paths : list of ndarray, optional
        ``branch_paths`` of the skeleton (computed when not given).

    Returns
    -------
    float
        The margin in degrees, the directions taken one radius (each junction's own) along
        the branches; infinite when no branch joins the two.
    """
    paths = branch_paths(skeleton.n_nodes, skeleton.edges) if paths is None else paths
    at_near = branches_at(paths, near)
    link = next((q for q in at_near if int(q[-1]) == far), None)
    if link is None:
        return float("inf")
    P, rn, rf = skeleton.points, float(skeleton.radii[near]), float(skeleton.radii[far])
    sib = [branch_direction(P, q, rn) for q in at_near if int(q[-1]) != far]
    dau = [branch_direction(P, q, rf) for q in branches_at(paths, far) if int(q[-1]) != near]
    return crossing_margin(branch_direction(P, link, rn), np.reshape(sib, (-1, 3)), np.reshape(dau, (-1, 3)))


def link_length(skeleton: Skeleton, a: int, b: int, paths=None) -> float:
    """Arc length of the branch joining nodes ``a`` and ``b``.

    Parameters
    ----------
    skeleton : Skeleton
    a, b : int
        Node indices.
    paths : list of ndarray, optional
        ``branch_paths`` of the skeleton (computed when not given).

    Returns
    -------
    float
        The length in the skeleton's length units; infinite when no branch joins the two.
    """
    paths = branch_paths(skeleton.n_nodes, skeleton.edges) if paths is None else paths
    for q in paths:
        if {int(q[0]), int(q[-1])} == {a, b} and a != b:
            return float(arc_length(skeleton.points[q])[-1])
    return float("inf")


def blockable_pair(skeleton: Skeleton, near: int, far: int, paths=None, margin: float | None = None) -> bool:
    """Whether the builder can block the junction pair ``near`` - ``far``.

    It can when the link is at least :data:`PAIR_REACH` radii of ``near`` long (room for
    its half-sections), or when every daughter of ``far`` points at least ``margin``
    degrees nearer the link than any other branch of ``near`` (:func:`crossing_margin`).

    Parameters
    ----------
    skeleton : Skeleton
    near, far : int
        The two junctions (node indices); ``near``'s radius sets the reach.
    paths : list of ndarray, optional
        ``branch_paths`` of the skeleton (computed when not given).
    margin : float, optional
        Least crossing margin in degrees; :data:`CROSSING_MARGIN` when not given.

    Returns
    -------
    bool
    """
    margin = CROSSING_MARGIN if margin is None else margin
    paths = branch_paths(skeleton.n_nodes, skeleton.edges) if paths is None else paths
    if link_length(skeleton, near, far, paths) >= PAIR_REACH * float(skeleton.radii[near]):
        return True
    return pair_margin(skeleton, near, far, paths) >= margin


def _point_key(p, unit: float = 1.0) -> tuple:
    """A node's identity across runs of the same moves: its position in units of ``unit``
    (a length scale of the skeleton, so that the rounding cuts at the same share of a
    vessel whatever the length unit)."""
    return tuple(np.round(np.asarray(p, float) / unit, 9).tolist())


def _move_key(skel: Skeleton, job: tuple, unit: float = 1.0) -> tuple:
    """A move's identity across runs: its junction's position and the far ends of its two
    branches (:func:`_point_key` in units of ``unit``)."""
    c, pi, pj = job[0], job[1], job[3]
    ends = sorted((_point_key(skel.points[pi[-1]], unit), _point_key(skel.points[pj[-1]], unit)))
    return (_point_key(skel.points[c], unit),) + tuple(ends)


def _unblockable_moves(skel: Skeleton, made: list) -> frozenset:
    """Keys of the moves in ``made`` (``(junction, new junction, move key, junction key)``,
    nodes of ``skel``) to undo: those whose pair the block builder cannot block
    (:func:`blockable_pair`, near: the junction that stayed), at a junction that undoing
    them leaves in no other close pair and gives back a junction of five or more branches.

    A junction still in another close pair is merged with it by the builder anyway, and
    undone moves only widen that merge. Why five: the builder merges a junction of four
    branches split into a close pair and re-splits it by pairings itself, while undoing
    the split of a trifurcation (or of a fan of four with one pair kept) hands it back a
    four-branch junction with an unblockable pair in it."""
    if not made:  # no move left a junction behind: no pair to judge
        return frozenset()
    deg = skel.degrees
    paths = branch_paths(skel.n_nodes, skel.edges)
    out = set()
    for ckey in {m[3] for m in made}:
        at = [m for m in made if m[3] == ckey]
        moves = [(c, n, key) for c, n, key, _ in at if deg[c] >= 3 and deg[n] >= 3]
        if not moves:
            continue
        c = moves[0][0]
        bad = {n: key for _, n, key in moves if not blockable_pair(skel, c, n, paths)}
        # undoing a move gives its branch back to the junction; under five the builder's
        # own merge and re-split of a four-branch junction does better than the undo
        if deg[c] + len(bad) < 5:
            continue
        ends = {int(q[-1]) for q in branches_at(paths, c)}
        close = {x for x in ends if deg[x] >= 3 and link_length(skel, c, x, paths) < PAIR_REACH * float(skel.radii[c])}
        if bad and close <= set(bad):
            out |= set(bad.values())
    return frozenset(out)
