"""Open ends whose rim takes in a window of a neighbouring vessel's wall.

A cut through a vessel's end that also runs through a vessel touching it (a kissing
pair cut by one ragged or hand-made cut) leaves one boundary loop: the end's rim and,
spliced into it, the rim of the window cut out of the neighbour's wall. A flat cap
spanning that loop crosses the neighbour's lumen. Where a centerline is given,
:func:`window_on_passing_branch` finds the rim's run on the wall of a branch that passes
the end (does not end there); :func:`split_rim` cuts the loop there into the end's rim
(capped flat) and the window's rim (closed as wall: faired into it, then put onto the
passing tube's wall, :func:`onto_tubes`). The wall of the parent a short branch grows
out of is no window (:func:`_own_lumen`). Used by ``cap_open_ends.split_windows`` (on by
default); see ``docs/robustness.md`` (h22/fold, h23/windows).
"""

from __future__ import annotations

import numpy as np

#: A rim vertex lies on a tube's wall when its distance to the tube's axis is within this
#: fraction of the tube's radius of that radius (the wall's own roughness and the
#: centerline's radii; the contact between two touching tubes is farther off both).
WALL_FIT = 0.25


def _feet(points: np.ndarray, a: np.ndarray, b: np.ndarray, ra: np.ndarray, rb: np.ndarray):
    """Each point's foot on each segment ``a -> b`` (``(p, s, 3)``,
    :func:`~vmesh.geometry.variation.closest_on_segments`), the foot's parameter in [0, 1],
    the radius there (interpolated between ``ra`` and ``rb``) and the point's distance to it."""
    from .geometry.variation import closest_on_segments

    shape = (len(points), len(a))
    foot, t, d = closest_on_segments(points, np.broadcast_to(a, (*shape, 3)), np.broadcast_to(b, (*shape, 3)), np.zeros(shape), np.ones(shape))
    return foot, t, ra[None] + t * (rb - ra)[None], d


def _segment_fit(points: np.ndarray, a: np.ndarray, b: np.ndarray, ra: np.ndarray, rb: np.ndarray):
    """Distance of each point to each segment's wall over its radius, ``|d - r| / r``
    (``(p, s)``), and the foot's parameter along the segment in [0, 1]."""
    _, t, r, d = _feet(points, a, b, ra, rb)
    return np.abs(d - r) / np.maximum(r, 1e-300), t


def _own_lumen(own: int, paths: list, branch_of_edge: np.ndarray, own_end: int, points, radii, edges, near: np.ndarray, centre: np.ndarray, reach: float) -> np.ndarray:
    """The end's own branch and the branches it grows out of just behind the end: those
    whose tube (over all their edges) holds the own branch's root, the node at its other
    end, and holds the own branch's path from the root on to within ``reach`` of the rim's
    ``centre``.

    A short branch that ends against its parent's wall (a stub cut just past the wall) has
    its root on the parent's axis and leaves the parent's lumen only just behind its end,
    however shallow its angle: the parent's wall in its rim is where the two lumens join,
    not a vessel passing the end. A vessel that passes the end is joined to the branch, if
    at all, far from the end: the branch has left its tube long before (a sibling leaving
    the same junction, a neighbour the branch left some radii back).

    Only branches with an edge among the ``near`` ones (those whose wall could be in the
    rim) are examined.
    """
    if own < 0:
        return np.array([own])
    path = np.asarray(paths[own])
    if path[0] != own_end:
        path = path[::-1]
    from_root = path[::-1]  # root first, the end last
    mine = [own]
    for b in np.unique(branch_of_edge[near & (branch_of_edge != own) & (branch_of_edge >= 0)]):
        ids = np.flatnonzero(branch_of_edge == b)
        _, _, r, d = _feet(points[from_root], points[edges[ids, 0]], points[edges[ids, 1]], radii[edges[ids, 0]], radii[edges[ids, 1]])
        gap = (d - r).min(axis=1)  # < 0 inside the tube
        if not gap[0] < 0:
            continue
        # where the path's run inside the tube that starts at the root leaves it: between
        # its last node inside and the next, interpolated (not the node itself, so a path
        # given by few nodes, a stub as one segment, is judged as a dense one)
        if (gap < 0).all():
            exit_point = points[from_root[-1]]
        else:
            k = int(np.argmax(gap >= 0))
            w = gap[k - 1] / (gap[k - 1] - gap[k])
            exit_point = (1.0 - w) * points[from_root[k - 1]] + w * points[from_root[k]]
        if np.linalg.norm(exit_point - centre) < reach:
            mine.append(int(b))
    return np.array(mine)


def window_on_passing_branch(rim: np.ndarray, points: np.ndarray, radii: np.ndarray, edges: np.ndarray, with_edges: bool = False):
    """The rim vertices on the wall of a centerline branch that passes an open end.

    The end's own branch is the one ending at the centerline end nearest the rim's
    centre; a branch whose tube holds the own branch's path from its root on to within
    ``reach`` of the rim's centre is the parent it grows out of (:func:`_own_lumen`), its wall
    no window. A rim vertex is on another
    branch's wall when it fits that branch's tube (:data:`WALL_FIT`), with its foot inside
    the branch (not beyond an end of the centerline: a vessel that ends short of the rim
    leaves no wall there). Vertices on the crease where the two walls meet fit both and
    count to the window, so that the chord that closes the end's cap runs outside the
    passing lumen.

    Parameters
    ----------
    rim : (k, 3) float array
        One boundary loop's vertices, in order.
    points, radii, edges : the centerline (radii > 0).
    with_edges : bool
        Also return the ids of the centerline edges whose walls the window's vertices fit.

    Returns
    -------
    (k,) bool array
        The longest cyclic run of such vertices (all False when there is none, or when it
        leaves fewer than 3 vertices on either side).
    """
    from .geometry.skeleton.graph import branch_paths, path_edge_ids

    k = len(rim)
    none = (np.zeros(k, bool), np.zeros(0, np.int64)) if with_edges else np.zeros(k, bool)
    degree = np.bincount(edges.ravel(), minlength=len(points))
    ends = np.flatnonzero(degree == 1)
    if not len(ends) or k < 6:
        return none
    centre = rim.mean(axis=0)
    own_end = ends[np.argmin(np.linalg.norm(points[ends] - centre, axis=1))]
    paths = branch_paths(len(points), edges)
    branch_of_edge = np.full(len(edges), -1, np.int64)
    for b, ids in enumerate(path_edge_ids(len(points), edges, paths)):
        branch_of_edge[ids] = b
    own = next((b for b, path in enumerate(paths) if own_end in (path[0], path[-1])), -1)
    reach = 2.0 * np.linalg.norm(rim - centre, axis=1).max()
    a, b = points[edges[:, 0]], points[edges[:, 1]]
    near = np.linalg.norm(0.5 * (a + b) - centre, axis=1) - 0.5 * np.linalg.norm(b - a, axis=1) < reach
    if not near.any():
        return none
    fit, t = _segment_fit(rim, a[near], b[near], radii[edges[near, 0]], radii[edges[near, 1]])
    mine = np.isin(branch_of_edge[near], _own_lumen(own, paths, branch_of_edge, own_end, points, radii, edges, near, centre, reach))
    # a foot on a centerline end (degree 1) lies beyond that vessel's end
    at_end = ((t <= 0.0) & (degree[edges[near, 0]] == 1)[None]) | ((t >= 1.0) & (degree[edges[near, 1]] == 1)[None])
    others = np.where(~mine[None] & ~at_end, fit, np.inf)
    other = others.min(axis=1)
    on_other = other < WALL_FIT
    if not on_other.any() or on_other.all():
        return none
    # the longest cyclic run
    start = int(np.flatnonzero(~on_other)[0])
    rolled = np.roll(on_other, -start)
    edges_of_runs = np.diff(np.r_[0, rolled.astype(np.int8), 0])
    lo, hi = np.flatnonzero(edges_of_runs == 1), np.flatnonzero(edges_of_runs == -1)
    longest = int(np.argmax(hi - lo))
    if hi[longest] - lo[longest] < 3 or k - (hi[longest] - lo[longest]) < 3:
        return none
    run = np.zeros(k, bool)
    run[lo[longest]:hi[longest]] = True
    run = np.roll(run, start)
    if with_edges:
        return run, np.unique(np.flatnonzero(near)[others[run].argmin(axis=1)])
    return run


def onto_tubes(p: np.ndarray, points: np.ndarray, radii: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """Points moved radially onto the wall of the nearest of the tubes along ``edges``."""
    foot, _, r, d = _feet(p, points[edges[:, 0]], points[edges[:, 1]], radii[edges[:, 0]], radii[edges[:, 1]])
    off = p[:, None, :] - foot
    j = d.argmin(axis=1)
    rows = np.arange(len(p))
    return foot[rows, j] + off[rows, j] * (r[rows, j] / np.maximum(d[rows, j], 1e-300))[:, None]


def split_rim(vertices: np.ndarray, loop: np.ndarray, window: np.ndarray):
    """Split a boundary loop into the end's rim and a window's rim by a straight chord.

    Parameters
    ----------
    vertices : (n, 3) float array
    loop : (k,) int array
        Boundary vertex ids in boundary half-edge order.
    window : (k,) bool array
        The loop's vertices on the neighbour's wall: one contiguous run (cyclically),
        neither empty nor the whole loop.

    Returns
    -------
    chord : (c, 3) float array
        New vertices along the chord between the two end-rim vertices beside the window,
        their ids ``n, n + 1, ...`` (spaced like the rim's edges).
    end_loop, window_loop : int arrays
        The two loops, each in the orientation of ``loop`` along its part of the rim (so
        that caps of either are oriented like the wall), sharing the chord.
    """
    loop = np.asarray(loop, np.int64)
    window = np.asarray(window, bool)
    k = len(loop)
    start = int(np.flatnonzero(window & ~np.roll(window, 1))[0])  # first window vertex of the run
    order = np.roll(np.arange(k), -start)  # the run first
    run = int(window[order].sum())
    a, b = loop[order[-1]], loop[order[run]]  # end-rim vertices before and after the window
    inner = loop[order[:run]]
    rest = loop[order[run:]]  # b ... a
    rim = vertices[loop]
    edge = float(np.mean(np.linalg.norm(np.roll(rim, -1, axis=0) - rim, axis=1)))
    span = vertices[b] - vertices[a]
    count = max(0, int(np.ceil(np.linalg.norm(span) / max(edge, 1e-300))) - 1)
    t = np.arange(1, count + 1) / (count + 1)
    chord = vertices[a] + t[:, None] * span
    ids = len(vertices) + np.arange(count)
    end_loop = np.concatenate([rest, ids])  # b ... a, then a -> b along the chord
    window_loop = np.concatenate([[a], inner, [b], ids[::-1]])
    return chord, end_loop, window_loop


def close_split_rim(vertices: np.ndarray, faces: np.ndarray, loop: np.ndarray, window: np.ndarray, rings: int | None = None):
    """Close one loop split by :func:`split_rim`: the window faired into the wall around it
    (:func:`vmesh.repair.fill_holes`), the end capped flat (:func:`vmesh.preprocess.cap_loop`).

    Returns
    -------
    vertices, faces : the surface with both patches (original faces first, the window's
        faces next, the cap's last)
    n_cap : int
        The number of cap faces (the last ``n_cap`` faces).
    patch : int array
        The window patch's inner vertices (not on the rim or the chord).
    """
    from .preprocess import cap_loop
    from .repair import fill_holes

    chord, end_loop, window_loop = split_rim(vertices, loop, window)
    v = np.vstack([vertices, chord])
    v, f, _ = fill_holes(v, faces, [window_loop])
    patch = np.arange(len(vertices) + len(chord), len(v))
    pts, tris = cap_loop(v, end_loop, rings)
    return np.vstack([v, pts]), np.vstack([f, tris]), len(tris), patch


def cap_loops_splitting_windows(vertices: np.ndarray, faces: np.ndarray, centerline, rings: int | None = None):
    """:func:`vmesh.preprocess.cap_boundary_loops` (method ``"rings"``) where a centerline
    is known: a loop whose rim takes in a window of a passing vessel's wall
    (:func:`window_on_passing_branch`) has the window closed as wall (on the passing
    tube's wall) and the rest capped.

    Parameters
    ----------
    vertices, faces : a consistently oriented surface with open ends
    centerline : (points, radii, edges)
    rings : int, optional
        As :func:`vmesh.preprocess.cap_loop`.

    Returns
    -------
    vertices, faces, labels : as :func:`vmesh.preprocess.cap_boundary_loops` (the same
        arrays when no loop has a window); window patches are labelled 0 (wall)
    windows : list of dict
        Per split loop: its label, rim and window vertex counts, the window's centre.
    """
    from .geometry import topology
    from .preprocess import cap_boundary_loops, cap_loop

    points, radii, edges = centerline
    loops = topology.join_touching(topology.boundary_loops(faces))
    found = [window_on_passing_branch(vertices[loop], points, radii, edges, with_edges=True) for loop in loops]
    if not any(w.any() for w, _ in found):
        return (*cap_boundary_loops(vertices, faces, rings=rings), [])
    v, f, labels, windows = vertices, faces, [np.zeros(len(faces), np.int64)], []
    for k, (loop, (window, passing)) in enumerate(zip(loops, found), start=1):
        n_faces = len(f)
        if window.any():
            v, f, n_cap, patch = close_split_rim(v, f, loop, window, rings)
            # the faired patch spans the window like a membrane: put it on the passing tube's wall
            v[patch] = onto_tubes(v[patch], points, radii, edges[passing])
            labels += [np.zeros(len(f) - n_faces - n_cap, np.int64), np.full(n_cap, k, np.int64)]
            windows.append({"label": k, "rim": int(len(loop)), "window": int(window.sum()), "center": vertices[loop[window]].mean(axis=0).round(6).tolist()})
            continue
        pts, tris = cap_loop(v, loop, rings)
        v, f = np.vstack([v, pts]), np.vstack([f, tris])
        labels.append(np.full(len(tris), k, np.int64))
    return v, f, np.concatenate(labels), windows
