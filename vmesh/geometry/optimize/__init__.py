"""Fast local optimisation of hexahedral meshes: untangling folds and a light smoothing pass.

Nodes are moved one at a time by a Newton step on a regularised shape functional of their
incident hexahedra (:mod:`.kernels`: Escobar's untangling-and-smoothing measure per corner,
with the corner's *initial* edge lengths as targets so graded boundary layers keep their
thickness), Gauss–Seidel over a greedy colouring of the nodes so that every node of one
colour is updated in parallel (no two share a hexahedron). Only the neighbourhood of bad
elements is touched:

* **untangling** (elements whose scaled Jacobian is below ``untangle_below``): the nodes of
  those elements move while the functional decreases; when inverted elements remain, the
  region grows by one ring of elements at a time, up to ``max_fraction`` of the nodes;
* **smoothing** (elements below ``smooth_below``): the nodes of those elements move only
  when the minimum *and* the sum of the scaled Jacobians of their incident elements do
  not decrease, so the mesh's minimum and mean never decrease.

Wall nodes take their Newton step in the tangent plane of the wall, are projected back
onto it with ``project``, and the projected position is judged again; cap nodes move in
their cap plane; nodes on a wall/cap rim and other boundary nodes stay fixed.

High-order meshes (order p > 1): the element corners are optimised and the other nodes
follow (see :func:`optimise`).
"""

from __future__ import annotations

import time

import numpy as np

from . import kernels as K


def _first_layer(sub: np.ndarray, wall: np.ndarray) -> np.ndarray:
    """Nodes off the wall joined to a wall node by an edge of a (sub-)hexahedron."""
    out = np.zeros(len(wall), bool)
    sub = sub[wall[sub].any(axis=1)]  # only hexahedra with a wall node have such an edge
    for a in (1, 2, 4):
        for c in range(8):
            if not c & a:
                u, w = sub[:, c], sub[:, c ^ a]
                out[w[wall[u] & ~wall[w]]] = True
                out[u[wall[w] & ~wall[u]]] = True
    return out


class _Stage:
    """The hexahedra around a set of active nodes, with their targets, incidence and colouring."""

    def __init__(self, X0, sub, active_mask, n, fixed):
        touching = active_mask[sub].any(axis=1)
        self.elements = np.flatnonzero(touching)
        self.hexes = np.ascontiguousarray(sub[self.elements])
        used = np.zeros(len(X0), bool)
        used[self.hexes.ravel()] = True  # the extent of the stage's nodes, each taken once
        floor = 1e-9 * max(float(np.ptp(X0[used], axis=0).max()), 1e-300) if len(self.hexes) else 1.0
        self.scale = K.target_scales(X0, self.hexes, floor)
        self.ptr, self.inc = K.incidence(self.hexes, n)
        nodes = np.flatnonzero(active_mask & ~fixed)
        colour = K.colour_nodes(self.hexes, self.ptr, self.inc, nodes, n)
        order = np.argsort(colour, kind="stable")
        bounds = np.searchsorted(colour[order], np.arange(colour.max() + 2)) if len(nodes) else np.zeros(1, np.int64)
        self.colours = [nodes[order[bounds[c] : bounds[c + 1]]] for c in range(len(bounds) - 1)]
        self.nodes = nodes
        self.valence = int(np.diff(self.ptr).max()) if len(self.ptr) > 1 else 0


def _delta(qmin: float) -> float:
    """Regularisation of the functional: small for valid meshes, larger the worse the worst
    inverted corner (Escobar et al. 2003)."""
    return 1e-3 if qmin > 1e-3 else float(np.sqrt(1e-3 * (1e-3 - min(qmin, 0.0)) + 1e-6))


def _offset(project, trial, height):
    """Points at ``height`` from the wall, straight above the wall points closest to ``trial``."""
    foot = np.asarray(project(trial), float)
    up = trial - foot
    return foot + up * (height / np.maximum(np.linalg.norm(up, axis=1), 1e-300))[:, None]


def _sweep(X, st, cq, kind, normal, caps, delta, mode, goal, project, wall_normals, stats, height, dirty, tol=0.0, ratio_floor=-np.inf, over_relax=1.0):
    """One Gauss–Seidel sweep over every colour of the stage; returns the number of nodes moved.
    ``wall_normals`` (None: keep the current ones) gives the tangent planes of the wall and
    first-layer nodes; moves shorter than ``tol`` times a node's step cap leave its
    neighbours clean; ``ratio_floor``: the smoothing steps' Jacobian-ratio guard
    (:func:`kernels.node_eval`, ``-inf`` off)."""
    moved = 0
    if wall_normals is not None:
        w = st.nodes[(kind[st.nodes] == K.WALL) | (kind[st.nodes] == K.OFFSET)]
        if len(w):
            nrm = np.asarray(wall_normals(X[w]), float)
            normal[w] = nrm / np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-300)
    width = 4 * st.valence
    for nodes in st.colours:
        trial = np.empty((len(nodes), 3))
        buf = np.empty((len(nodes), width))  # the corner qualities of each node's last trial
        state = np.empty((len(nodes), 4))
        parallel = len(nodes) >= K.PARALLEL_FROM
        (K.sweep_colour_parallel if parallel else K.sweep_colour_serial)(X, st.hexes, st.scale, st.ptr, st.inc, cq, nodes, kind, normal, caps, delta, mode, goal, trial, state, dirty, buf, tol, ratio_floor, over_relax)
        stats["updates"] += int((state[:, 0] != -1.0).sum())
        kinds = kind[nodes]
        wall_trial = ((kinds == K.WALL) | (kinds == K.OFFSET)) & (state[:, 3] > 0)
        if wall_trial.any():
            ids = np.flatnonzero(wall_trial)
            proj = np.empty((len(ids), 3))
            on = kinds[ids] == K.WALL
            proj[on] = project(trial[ids[on]])
            if not on.all():
                off = ids[~on]
                proj[~on] = _offset(project, trial[off], height[nodes[off]])
            sub_state = np.ascontiguousarray(state[ids])
            (K.accept_trials_parallel if len(ids) >= K.PARALLEL_FROM else K.accept_trials_serial)(X, st.hexes, st.scale, st.ptr, st.inc, cq, nodes[ids], proj, delta, mode, sub_state, dirty, buf, caps, tol, ratio_floor)
            state[ids, 3] = sub_state[:, 3]
        moved += int((state[:, 3] > 0).sum())
    return moved


def _run_stage(X, st, kind, normal, delta_of, mode, project, wall_normals, stats, sweeps, goal, moved_mask, height, X0, patience=10, climb_below=None, tol=0.0, ratio_floor=-np.inf, over_relax=1.0):
    """Sweeps over a stage until its worst element reaches ``goal`` or stops improving; nodes
    whose worst incident element is below ``climb_below`` (default ``goal``) try a max-min
    step when their Newton step is refused."""
    climb = goal if climb_below is None else climb_below
    todo = st.nodes[np.isnan(height[st.nodes])]
    if len(todo):
        height[todo] = np.linalg.norm(X0[todo] - np.asarray(project(X0[todo]), float), axis=1)
    caps = K.step_caps(X, st.hexes, st.ptr, st.inc, st.nodes, len(X), 0.5)
    cq = K.corner_qualities(X, st.hexes, st.scale)  # follows every move (kernels._moved)
    q = cq.min(axis=1)
    # progress: the worst element, or the total shortfall below the goal
    best = (float(q.min()), float(np.minimum(q - goal, 0.0).sum()))
    stall = 0
    before = X[st.nodes].copy()
    dirty = np.zeros(len(X), bool)
    dirty[st.nodes] = True
    for sweep in range(sweeps):
        delta = delta_of(float(q.min()))
        # the tangent planes only steer the steps (the projection puts nodes back on the
        # wall): refreshed every few sweeps, the signed-distance queries cost more than a sweep
        normals = wall_normals if sweep % 8 == 0 else None
        if _sweep(X, st, cq, kind, normal, caps, delta, mode, climb, project, normals, stats, height, dirty, tol, ratio_floor, over_relax) == 0:
            break
        q = cq.min(axis=1)
        if q.min() >= goal:
            break
        now = (float(q.min()), float(np.minimum(q - goal, 0.0).sum()))
        if now[0] > best[0] + 1e-3 or now[1] > best[1] + 1e-3 * max(abs(best[1]), 1e-3):
            stall = 0
        else:
            stall += 1
            if stall >= patience:
                break
        best = (max(best[0], now[0]), max(best[1], now[1]))
    moved_mask[st.nodes[np.any(X[st.nodes] != before, axis=1)]] = True
    return q


def optimise(points: np.ndarray, cells: np.ndarray, order: int = 1, *, ref_nodes: np.ndarray | None = None, **kw) -> tuple[np.ndarray, dict]:
    """Untangle and smooth the neighbourhood of low-quality hexahedra (see :func:`optimise_linear`
    for the parameters).

    For order p > 1 only the elements' corner nodes are optimised (as the linear mesh of the
    element corners) and every other node of an element whose corners moved follows them by
    the trilinear interpolation of the corners' displacements (``ref_nodes``: the 1-D node
    positions on [0, 1], Gauss–Lobatto by default); moved wall nodes are projected back
    onto the wall. The elements keep their curvature, and the interpolation is conforming
    (a node shared by two elements gets the same displacement from both). Optimising the
    lattice of sub-hexahedra instead leaves valid sub-hexahedra whose Lagrange element can
    still be inverted at a node.
    """
    p = int(order)
    cells = np.asarray(cells)
    if p == 1:
        return optimise_linear(points, cells, **kw)
    corners = np.ascontiguousarray(cells[:, corner_index(p)], dtype=np.int64)
    X, info = optimise_linear(points, corners, **kw)
    moved = np.any(X != np.asarray(points, float), axis=1)
    X = follow_corners(points, cells, p, X, ref_nodes)
    wall, project = kw.get("wall"), kw.get("project")
    follow = np.any(X != np.asarray(points, float), axis=1) & ~moved
    if wall is not None and project is not None:
        w = np.flatnonzero(follow & np.asarray(wall, bool))
        if len(w):
            X[w] = project(X[w])
    info["followed_nodes"] = int(follow.sum())
    return X, info


def corner_index(order: int) -> np.ndarray:
    """Local indices ``(8,)`` of the corners (tensor corner order) of a tensor-order element of order p."""
    p, n1 = int(order), int(order) + 1
    return np.array([(c & 1) * p + n1 * (((c >> 1) & 1) * p + n1 * ((c >> 2) & 1) * p) for c in range(8)])


def follow_corners(points: np.ndarray, cells: np.ndarray, order: int, corner_points: np.ndarray, ref_nodes: np.ndarray | None = None) -> np.ndarray:
    """Move every node of the elements whose corners moved (from ``points`` to
    ``corner_points``) by the trilinear interpolation of their corners' displacements.

    Parameters
    ----------
    points : (n, 3) float
        Positions before.
    cells : (m, (p+1)^3) int, tensor order
    corner_points : (n, 3) float
        Positions with the element corners moved (other nodes as in ``points``).
    ref_nodes : (p+1,) float, optional
        1-D node positions on [0, 1] (Gauss–Lobatto by default).

    Returns
    -------
    (n, 3) float
        The new positions: corners as in ``corner_points``, the rest following them.
    """
    p = int(order)
    P = np.asarray(points, float)
    X = np.array(corner_points, float, copy=True)
    corners = np.asarray(cells)[:, corner_index(p)]
    U = X - P
    sel = np.flatnonzero(np.any(U != 0.0, axis=1)[corners].any(axis=1))
    if not len(sel):
        return X
    if ref_nodes is None:
        from ..transfinite import reference_points

        ref_nodes = reference_points(p)
    r = np.asarray(ref_nodes, float)
    k, j, i = np.meshgrid(r, r, r, indexing="ij")  # tensor order: i fastest
    a, b, c = i.ravel(), j.ravel(), k.ravel()
    W = np.stack([(a if q & 1 else 1 - a) * (b if q & 2 else 1 - b) * (c if q & 4 else 1 - c) for q in range(8)], axis=1)
    X[cells[sel]] = P[cells[sel]] + np.einsum("nc,kcd->knd", W, U[corners[sel]])
    return X


def optimise_linear(
    points: np.ndarray,
    cells: np.ndarray,
    *,
    wall: np.ndarray | None = None, wall_normals=None, project=None,
    cap_nodes: np.ndarray | None = None, cap_normals: np.ndarray | None = None,
    boundary: np.ndarray | None = None,
    untangle_below: float = 0.2, smooth_below: float = 0.5,
    max_fraction: float = 0.01,
    sweeps: int = 150, smooth_sweeps: int = 8,
    keep_first_layer: bool = True,
    untangle_mode: int = K.ESCOBAR,
    smooth_rings: int = 0,
    grow_below_threshold: bool = True,
    smooth_tol: float = 0.0,
    keep_partial_free_layer: bool = False,
    untangle_patience: int | None = None,
    ratio_floor: float = -np.inf,
    over_relax: float = 1.0,
) -> tuple[np.ndarray, dict]:
    """Untangle and smooth the neighbourhood of low-quality linear hexahedra.

    Parameters
    ----------
    points : (n, 3) float
    cells : (m, 8) int, tensor corner order (corner i + 2 j + 4 k)
    wall : (n,) bool, optional
        Nodes on the vessel wall: tangential Newton steps, then ``project``. Without
        ``project`` and ``wall_normals`` they stay fixed.
    wall_normals : callable, optional
        ``wall_normals(points) -> (k, 3)`` wall normals (e.g. the signed distance's gradient).
    project : callable, optional
        ``project(points) -> (k, 3)`` closest wall points.
    cap_nodes : (n,) bool, optional
        Nodes on flat caps: they move in the plane of normal ``cap_normals``.
    cap_normals : (n, 3) float, optional
    boundary : (n,) bool, optional
        Nodes on the mesh boundary (found from the cells when not given); those neither on
        the wall nor on a cap, and those on both (rims), stay fixed.
    untangle_below : float
        Elements (sub-hexahedra) with a scaled Jacobian below this are untangled.
    smooth_below : float
        Then elements below this are smoothed (min and sum of scaled Jacobians monotone);
        0 disables the light pass.
    max_fraction : float
        The untangling region grows (one ring at a time, while inverted elements remain)
        up to this fraction of the nodes.
    sweeps, smooth_sweeps : int
        Most Gauss–Seidel sweeps per untangling region, and of the smoothing pass.
    keep_first_layer : bool
        Interior nodes one edge from the wall slide at their initial distance from it (the
        first boundary-layer height is kept) instead of moving freely.
    untangle_mode : int
        Acceptance of untangling steps: ``kernels.ESCOBAR`` (the functional decreases; it
        passes through inverted states, many cheap sweeps) or ``kernels.UNTANGLE`` (also the
        incident elements' minimum scaled Jacobian does not drop; stalls more often).
    smooth_rings : int
        Rings of elements added around the light pass's elements.
    grow_below_threshold : bool
        Grow the untangling region also while valid elements below ``untangle_below``
        remain (not only inverted ones), within ``max_fraction``.
    smooth_tol : float
        Light pass: moves shorter than this fraction of the step cap leave the neighbours clean.
    keep_partial_free_layer : bool
        On a valid mesh, keep the free-layer try whenever it beats the held one (:func:`polish`).
    untangle_patience : int, optional
        Rings in a row with neither fewer elements below ``untangle_below`` nor a higher minimum
        that end the growth (None: up to ``max_fraction``); rings, not ``_run_stage``'s sweeps.
    ratio_floor, over_relax : float
        Smoothing steps' Jacobian-ratio guard (``-inf``: none; :func:`.kernels.node_eval`) and first trial length (x the Newton step, then 1, 1/2, ...; 1: plain).

    Returns
    -------
    points : (n, 3) float
        New node positions (a copy).
    info : dict
        ``before``/``after`` min and mean scaled Jacobian of the hexahedra,
        ``untangled_nodes`` and ``smoothed_nodes`` (nodes moved by each pass), ``rings``,
        ``updates`` (node updates) and ``seconds``.
    """
    from ..quality import hex8_scaled_jacobian

    t0 = time.perf_counter()
    X = np.array(points, dtype=np.float64, copy=True, order="C")
    n, sub = len(X), np.ascontiguousarray(cells, dtype=np.int64).reshape(-1, 8)
    q = hex8_scaled_jacobian(X, sub)
    info = _linear_info(q)
    if not len(q) or q.min() >= max(untangle_below, smooth_below):
        return X, {**info, "after": info["before"], "seconds": time.perf_counter() - t0}
    constraints = dict(wall=wall, project=project, wall_normals=wall_normals, cap_nodes=cap_nodes, cap_normals=cap_normals, boundary=boundary, keep_first_layer=keep_first_layer)
    fixed, run, untangled, smoothed = _linear_run(X, sub, n, constraints, keep_partial_free_layer and q.min() > 0, untangle_patience)
    bad = q < untangle_below
    if bad.any():
        q = _untangle(X, sub, n, fixed, bad, run, untangle_below, max_fraction, sweeps, untangle_mode, grow_below_threshold, untangled, info)
    low = q < smooth_below
    if smooth_below > 0 and low.any():
        _smooth_region(X, sub, n, fixed, low, run, smooth_below, smooth_sweeps, smooth_rings, smoothed, smooth_tol, ratio_floor, over_relax)
        q = hex8_scaled_jacobian(X, sub)
    return X, _linear_done(info, q, untangled, smoothed, run["stats"], t0)


def _linear_run(X, sub, n, constraints, keep_partial, ring_patience):
    """The fixed nodes, the state :func:`optimise_linear`'s passes share (how each node moves,
    :func:`_node_kinds` of ``constraints``, its keyword arguments; the update count; the initial points) and the
    masks of the nodes each pass moved (untangling, smoothing), empty."""
    kind, normal, height = _node_kinds(sub, n, **constraints)
    run = dict(
        kind=kind, normal=normal, project=constraints["project"], wall_normals=constraints["wall_normals"], stats={"updates": 0}, height=height,
        X0=X.copy(), keep_partial=keep_partial, ring_patience=ring_patience,
    )
    return kind == K.FIXED, run, np.zeros(n, bool), np.zeros(n, bool)


def _linear_info(q) -> dict:
    """:func:`optimise_linear`'s record before its passes: the hexahedra's scaled Jacobians
    ``q`` (min and mean; None without hexahedra) and zero counts."""
    before = {"min": float(q.min()), "mean": float(q.mean())} if len(q) else None
    return {"before": before, "untangled_nodes": 0, "smoothed_nodes": 0, "moved": 0, "rings": 0, "updates": 0}


def _linear_done(info, q, untangled, smoothed, stats, t0) -> dict:
    """``info`` completed after the passes: the scaled Jacobians ``q`` after, the nodes each
    pass moved (``untangled``, ``smoothed`` masks), node updates and seconds since ``t0``."""
    info.update(
        after={"min": float(q.min()), "mean": float(q.mean())},
        untangled_nodes=int(untangled.sum()),
        smoothed_nodes=int((smoothed & ~untangled).sum()),
        moved=int((untangled | smoothed).sum()),
        updates=stats["updates"],
        seconds=time.perf_counter() - t0,
    )
    return info


def _node_kinds(sub, n, wall, project, wall_normals, cap_nodes, cap_normals, boundary, keep_first_layer):
    """How each node may move (``kernels`` FREE, WALL, PLANE, FIXED, OFFSET), the plane normals
    of cap nodes, and the wall heights of first-layer nodes (NaN: measured when first reached)."""
    wall = np.zeros(n, bool) if wall is None else np.asarray(wall, bool)
    caps = np.zeros(n, bool) if cap_nodes is None else np.asarray(cap_nodes, bool)
    if boundary is None:
        from ..untangle import _mesh_boundary  # (untangle imports this package)

        boundary = _mesh_boundary(sub, n)
    kind = np.full(n, K.FREE, np.int64)
    kind[np.asarray(boundary, bool)] = K.FIXED
    normal = np.zeros((n, 3))
    kind[wall] = K.WALL if project is not None and wall_normals is not None else K.FIXED
    plane = caps & ~wall
    if cap_normals is not None:
        kind[plane] = K.PLANE
        normal[plane] = cap_normals[plane]
    kind[wall & caps] = K.FIXED
    height = np.zeros(n)
    if keep_first_layer and project is not None and wall_normals is not None and wall.any():
        # the first boundary layer keeps its height: interior nodes one edge from the wall
        # slide at their distance from it
        top = _first_layer(sub, wall) & (kind == K.FREE)
        kind[top] = K.OFFSET
        height[top] = np.nan  # measured on the initial mesh when a stage first reaches them
    return kind, normal, height


def _untangle_regions(X, sub, n, fixed, bad, run, below, max_fraction, sweeps, mode, grow_below_threshold, untangled):
    """Untangle the nodes of the ``bad`` elements, growing the region by one ring while
    inverted elements (or, with ``grow_below_threshold``, elements below ``below``) remain,
    up to ``max_fraction`` of the nodes; returns the rings grown."""
    active = np.zeros(n, bool)
    active[sub[bad].ravel()] = True
    # small meshes: at least twice the first region (1 % of a few thousand nodes is less than one fold's neighbourhood)
    budget = max(int(max_fraction * n), 2 * int((active & ~fixed).sum()))
    rings = 0
    best, stalled = None, 0  # the least elements below ``below`` and the best minimum so far, and rings since either improved
    for ring in range(64):
        st = _Stage(run["X0"], sub, active, n, fixed)
        qs = _run_stage(X, st, run["kind"], run["normal"], _delta, mode, run["project"], run["wall_normals"], run["stats"], sweeps, below, untangled, run["height"], run["X0"])
        rings = ring
        if qs.min() > 0 and not grow_below_threshold or qs.min() >= below:
            break
        if run.get("ring_patience") is not None:
            # a fold the rings around it do not open (two vessels fused across each other)
            # would otherwise grow the region, and re-sweep all of it, up to max_fraction; a
            # ring that lowers the count or raises the minimum is progress (a fold can open
            # by its minimum rising while as many elements stay below)
            left, worst = int((qs < below).sum()), float(qs.min())
            if best is None:
                best = (left, worst)
            elif left < best[0] or worst > best[1]:
                best, stalled = (min(left, best[0]), max(worst, best[1])), 0
            else:
                stalled += 1
            if stalled >= run["ring_patience"]:
                break
        grown = K.grow_nodes(st.hexes, st.ptr, st.inc, active)
        if int((grown & ~fixed).sum()) > budget or (grown == active).all():
            break
        active = grown
    return rings


def _untangle(X, sub, n, fixed, bad, run, below, max_fraction, sweeps, mode, grow_below_threshold, untangled, info):
    """Untangle the regions of the ``bad`` elements with the first boundary layer held, then,
    where that leaves an element below ``below``, try with it free
    (:func:`_untangle_free_layer`); returns the elements' scaled Jacobians."""
    from ..quality import hex8_scaled_jacobian

    info["rings"] = _untangle_regions(X, sub, n, fixed, bad, run, below, max_fraction, sweeps, mode, grow_below_threshold, untangled)
    q = hex8_scaled_jacobian(X, sub)
    if q.min() < below and (run["kind"] == K.OFFSET).any():
        q = _untangle_free_layer(X, sub, n, fixed, bad, run, below, max_fraction, sweeps, grow_below_threshold, untangled, q, info)
    return q


def _untangle_free_layer(X, sub, n, fixed, bad, run, below, max_fraction, sweeps, grow_below_threshold, untangled, q, info):
    """Untangling again from the initial mesh with the first boundary-layer nodes free (not
    held at their wall distance) and every step judged by its elements' worst scaled
    Jacobian; its result replaces ``X`` when it lifts every element to ``below`` (the
    returned qualities are those of ``X``).

    A fold inside a thin boundary-layer block (a block twisted along a strongly curved wall)
    cannot be undone while its top nodes keep their height: wall and top nodes then only
    slide, and the functional's steps trade one inverted corner for another. The global
    untangler, the fallback after this, does not hold the height either."""
    from ..quality import hex8_scaled_jacobian

    X1 = run["X0"].copy()
    kind = run["kind"].copy()
    kind[kind == K.OFFSET] = K.FREE
    moved = np.zeros(n, bool)
    rings = _untangle_regions(X1, sub, n, fixed, bad, {**run, "kind": kind}, below, max_fraction, sweeps, K.UNTANGLE, grow_below_threshold, moved)
    q1 = hex8_scaled_jacobian(X1, sub)
    # kept only where it untangles fully: a partial result does not predict the light pass's
    # (sv_rpa given: -0.036 here against the global untangler's -0.25, yet 19 elements stay
    # inverted after the light pass against none)
    # (a partial result from a valid mesh stays valid and the light pass cannot lower it)
    kept = (q1.min() >= below or run.get("keep_partial", False)) and q1.min() > q.min()
    info["free_layer"] = {"held_min": float(q.min()), "min": float(q1.min()), "kept": bool(kept)}
    if not kept:
        return q
    X[:] = X1
    untangled[:] = moved
    info["rings"] = rings
    return q1


def polish(points: np.ndarray, cells: np.ndarray, goals, **kw) -> tuple[np.ndarray, dict]:
    """Climb the worst elements of a valid linear mesh that another untangler left at a poor
    local optimum, once per goal in ``goals`` (increasing), each try from the best mesh so far.

    The global L-BFGS untangler stops where its functional is stationary, not where the
    worst element is best: on generated vessels it leaves boundary-layer elements at junction
    crotches at 0.08-0.29 that the monotone light pass cannot lift (each of its steps must
    keep the neighbourhood minimum *and* raise the sum). Each try here is the local
    untangling of :func:`optimise_linear` started from that mesh (its targets are that
    mesh's edge lengths) with every step judged by the worst incident element
    (``kernels.UNTANGLE``), the first boundary layer held and then free, its region grown
    while elements stay below the goal (within ``max_fraction``); a try is kept when it
    raises the mesh's minimum scaled Jacobian, so the result is never worse than the input.

    Parameters
    ----------
    points : (n, 3) float
    cells : (m, 8) int, tensor corner order
    goals : sequence of float
        Untangling targets, tried in turn (e.g. the untangling threshold, then the light
        pass's ``smooth_below``).
    **kw
        Constraints and settings of :func:`optimise_linear` (``wall``, ``project``, ...).

    Returns
    -------
    points : (n, 3) float
    info : dict
        ``before``/``after`` minimum scaled Jacobian, per try its goal, minimum reached,
        nodes moved and updates, and whether it was kept.
    """
    from ..quality import hex8_scaled_jacobian

    X = np.array(points, dtype=np.float64, copy=True)
    qmin = float(hex8_scaled_jacobian(X, np.asarray(cells).reshape(-1, 8)).min())
    info = {"before": qmin, "tries": []}
    for goal in goals:
        if qmin <= 0 or qmin >= goal:
            continue
        Y, r = optimise_linear(X, cells, untangle_below=goal, smooth_below=0.0, untangle_mode=K.UNTANGLE, keep_partial_free_layer=True, **kw)
        kept = r["after"]["min"] > qmin
        info["tries"].append({"goal": goal, "min": r["after"]["min"], "moved": r["moved"], "updates": r["updates"], "kept": kept})
        if kept:
            X, qmin = Y, r["after"]["min"]
    info["after"] = qmin
    return X, info


def _smooth_region(X, sub, n, fixed, low, run, below, sweeps, rings, smoothed, tol=0.0, ratio_floor=-np.inf, over_relax=1.0):
    """The light pass: monotone steps for the nodes of the ``low`` elements (and ``rings``
    rings of elements around them); the nodes' neighbourhood minimum and sum of scaled
    Jacobians never drop, and nodes whose worst element is below ``below`` climb it
    (``ratio_floor``: the Jacobian-ratio guard, :func:`optimise_linear`)."""
    active = np.zeros(n, bool)
    active[sub[low].ravel()] = True
    if rings:
        ptr, inc = K.incidence(sub, n)
        for _ in range(rings):
            active = K.grow_nodes(sub, ptr, inc, active)
    st = _Stage(run["X0"], sub, active, n, fixed)
    _run_stage(X, st, run["kind"], run["normal"], lambda qmin: 1e-3 if qmin > 0 else _delta(qmin), K.SMOOTH, run["project"], run["wall_normals"], run["stats"], sweeps, 1.0, smoothed, run["height"], run["X0"], climb_below=below, tol=tol, ratio_floor=ratio_floor, over_relax=over_relax)
