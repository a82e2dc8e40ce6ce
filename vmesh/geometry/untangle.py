"""Local untangling and shape improvement of hexahedral meshes.

Transfinite maps of a valid block can still fold where the wall is strongly curved
(the crotch of a junction, the saddle between two close junctions). This module moves
the nodes around such elements to make them valid again, leaving the rest of the mesh
untouched:

* the objective is the *simultaneous untangling and smoothing* functional of Escobar,
  Rodríguez, Montenegro et al. (2003), evaluated at the 8 corners of every linear
  (sub-)hexahedron: ``|M|^2 / (3 h(det M)^(2/3))`` with ``h(s) = (s + sqrt(s^2 + 4 d^2)) / 2``,
  which is smooth and finite for inverted corners, so a gradient method can pass
  through them;
* ``M = A W^-1`` with ``A`` the corner's edge matrix and ``W`` the diagonal of the
  corner's initial edge lengths (a target-matrix choice), so thin graded boundary-layer
  elements stay thin instead of being pulled towards cubes;
* nodes on the wall slide in their tangent plane and are projected back onto the wall
  afterwards (then interior nodes are optimised once more with the wall fixed); nodes on
  flat caps slide in the cap plane; nodes on a wall/cap rim stay fixed.

High-order meshes are optimised through their lattice of sub-hexahedra (every node).
All work is vectorised over corners; the minimisation is a limited-memory BFGS.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: corners of a linear hexahedron in tensor order (i fastest) and their neighbours along i, j, k
_CORNER_BITS = np.array([[c & 1, (c >> 1) & 1, (c >> 2) & 1] for c in range(8)])
_NBR = np.array([[c ^ (1 << a) for a in range(3)] for c in range(8)])
_SGN = np.where(_CORNER_BITS == 0, 1.0, -1.0)  # (8, 3): sign of the step to each neighbour
#: the six faces of a tensor-order hexahedron (corner indices)
_HEX_FACES = np.array([[0, 2, 4, 6], [1, 3, 5, 7], [0, 1, 4, 5], [2, 3, 6, 7], [0, 1, 2, 3], [4, 5, 6, 7]])


def sub_hexahedra(cells: np.ndarray, order: int) -> tuple[np.ndarray, np.ndarray]:
    """Split tensor-order cells ``(m, (p+1)^3)`` into linear sub-hexahedra ``(m p^3, 8)``
    (tensor corner order) and the parent cell of each."""
    p = int(order)
    cells = np.asarray(cells)
    if p == 1:
        return cells, np.arange(len(cells))
    n = p + 1
    a = np.arange(p)
    i, j, k = np.meshgrid(a, a, a, indexing="ij")
    base = (i + n * (j + n * k)).ravel()  # (p^3,)
    off = np.array([ci + n * (cj + n * ck) for ci, cj, ck in _CORNER_BITS])
    local = base[:, None] + off[None, :]  # (p^3, 8)
    sub = cells[:, local].reshape(-1, 8)
    return sub, np.repeat(np.arange(len(cells)), p**3)


def corner_edges(points: np.ndarray, hexes: np.ndarray) -> np.ndarray:
    """Edge vectors ``(m, 8, 3 axes, 3)`` leaving each corner along +i, +j, +k."""
    X = points[hexes]  # (m, 8, 3)
    return (X[:, _NBR, :] - X[:, :, None, :]) * _SGN[None, :, :, None]


def linear_scaled_jacobian(points: np.ndarray, hexes: np.ndarray) -> np.ndarray:
    """Minimum corner scaled Jacobian of linear hexahedra in tensor corner order
    (:func:`vmesh.geometry.quality.hex8_scaled_jacobian`)."""
    from .quality import hex8_scaled_jacobian

    return hex8_scaled_jacobian(points, hexes)


@dataclass
class _Problem:
    hexes: np.ndarray  # (m, 8) sub-hexahedra in the objective
    scale: np.ndarray  # (m, 2, 2, 2, 3): 1 / target edge lengths at each corner (k, j, i) per axis
    free: np.ndarray  # (nf,) node ids moved
    basis: np.ndarray  # (nf, 3, k) per free node: columns spanning its allowed moves
    x0: np.ndarray  # (nf, 3) start positions
    delta: float


def _cross(a, b):
    """Cross product of (..., 3) arrays (faster than np.cross for many small vectors)."""
    return np.stack([a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1], a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2], a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]], axis=-1)


def _objective(points: np.ndarray, prob: _Problem, want_grad: bool = True):
    """Sum of the corner functional and its gradient with respect to every node (the
    compiled :func:`vmesh.geometry.optimize.objective.escobar_sum`; :func:`_objective_numpy`
    is the same sum in numpy, ~10 times slower)."""
    from .optimize.objective import escobar_sum

    grad = np.empty_like(points)
    f = escobar_sum(points, prob.hexes, prob.scale.reshape(len(prob.hexes), 8, 3), float(prob.delta), grad)
    return float(f), (grad if want_grad else None)


def _objective_numpy(points: np.ndarray, prob: _Problem, want_grad: bool = True):
    """Sum of the corner functional and its gradient with respect to every node.

    With corners in tensor order, the signed edge leaving corner (i, j, k) along +i is the
    hexahedron's i-edge at (j, k) whatever i is, so the 24 corner edges are the 12 edges
    broadcast: plain slicing instead of gathers.
    """
    m = len(prob.hexes)
    X = points[prob.hexes].reshape(m, 2, 2, 2, 3)  # (m, k, j, i, 3)
    s = prob.scale  # (m, k, j, i, 3 axes): 1 / target edge lengths
    e0 = (X[:, :, :, 1:2] - X[:, :, :, 0:1]) * s[..., 0:1]
    e1 = (X[:, :, 1:2, :] - X[:, :, 0:1, :]) * s[..., 1:2]
    e2 = (X[:, 1:2, :, :] - X[:, 0:1, :, :]) * s[..., 2:3]
    c0 = _cross(e1, e2)
    det = (e0 * c0).sum(-1)
    F = (e0 * e0).sum(-1) + (e1 * e1).sum(-1) + (e2 * e2).sum(-1)
    r = np.sqrt(det * det + 4.0 * prob.delta**2)
    h = 0.5 * (det + r)
    h23 = np.maximum(h, 1e-300) ** (2.0 / 3.0)
    f = F / (3.0 * h23)
    if not want_grad:
        return float(f.sum()), None
    a = (2.0 / (3.0 * h23))[..., None]
    b = (2.0 * F / (9.0 * h23 * r))[..., None]
    g0 = ((a * e0 - b * c0) * s[..., 0:1]).sum(axis=3)  # (m, 2, 2, 3): per i-edge
    g1 = ((a * e1 - b * _cross(e2, e0)) * s[..., 1:2]).sum(axis=2)  # (m, 2, 2, 3): per j-edge
    g2 = ((a * e2 - b * _cross(e0, e1)) * s[..., 2:3]).sum(axis=1)  # (m, 2, 2, 3): per k-edge
    G = np.zeros_like(X)
    G[:, :, :, 1] += g0
    G[:, :, :, 0] -= g0
    G[:, :, 1, :] += g1
    G[:, :, 0, :] -= g1
    G[:, 1, :, :] += g2
    G[:, 0, :, :] -= g2
    G = G.reshape(-1, 3)
    ids = prob.hexes.ravel()
    grad = np.empty_like(points)
    for d in range(3):
        grad[:, d] = np.bincount(ids, G[:, d], minlength=len(points))
    return float(f.sum()), grad


def _dot(a: np.ndarray, b: np.ndarray) -> float:
    """Dot product of two vectors without BLAS: OpenBLAS splits a dot product longer than
    10,000 entries over threads, which on a loaded machine costs 20-100 times the product
    (the untangler's vectors are 3 entries a free node)."""
    return float(np.einsum("i,i->", a, b))


def lbfgs(fun, x0: np.ndarray, iterations: int = 200, memory: int = 8, first_step: float = 1.0, rtol: float = 1e-7, spent=None) -> np.ndarray:
    """Minimise ``fun(x) -> (f, grad)`` by limited-memory BFGS with a backtracking (Armijo)
    line search. Plain numpy: for these problems scipy's L-BFGS-B spends more time in its
    bound handling than in the objective. ``spent() -> bool``, when given, stops the
    minimisation (at its last accepted point) once the caller's work budget is spent."""
    x = np.array(x0, float)
    f, g = fun(x)
    S, Y = [], []
    for _ in range(iterations):
        if spent is not None and spent():
            break
        q = g.copy()
        alphas = []
        for s_, y_ in zip(reversed(S), reversed(Y)):
            rho = 1.0 / _dot(y_, s_)
            a = rho * _dot(s_, q)
            q -= a * y_
            alphas.append((rho, a))
        if S:
            q *= _dot(S[-1], Y[-1]) / max(_dot(Y[-1], Y[-1]), 1e-300)
        else:
            q *= first_step / max(float(np.abs(g).max()), 1e-300)
        for (s_, y_), (rho, a) in zip(zip(S, Y), reversed(alphas)):
            q += s_ * (a - rho * _dot(y_, q))
        d = -q
        slope = _dot(g, d)
        if slope >= 0:  # not a descent direction: restart from steepest descent
            S, Y = [], []
            d = -g * (first_step / max(float(np.abs(g).max()), 1e-300))
            slope = _dot(g, d)
        t = 1.0
        while True:
            fn, gn = fun(x + t * d)
            if fn <= f + 1e-4 * t * slope or t < 1e-8 or (spent is not None and spent()):
                break
            t *= 0.5
        if fn > f:
            break
        step, dg = t * d, gn - g
        if _dot(dg, step) > 1e-300:
            S.append(step)
            Y.append(dg)
            if len(S) > memory:
                S.pop(0)
                Y.pop(0)
        x += step
        done = f - fn <= rtol * abs(f)
        f, g = fn, gn
        if done:
            break
    return x


class _Work:
    """Work of one :func:`untangle` call in *node updates*: every evaluation of the objective
    counts the free nodes it moves. ``limit`` (None: unbounded) stops the minimisations."""

    def __init__(self, limit: float | None = None):
        self.limit, self.updates, self.evaluations = limit, 0, 0

    def spend(self, nodes: int) -> None:
        self.updates += int(nodes)
        self.evaluations += 1

    def spent(self) -> bool:
        return self.limit is not None and self.updates >= self.limit


def _minimise(points: np.ndarray, prob: _Problem, iterations: int, work: _Work | None = None) -> np.ndarray:
    k = prob.basis.shape[2]
    X = points.copy()
    work = work or _Work()

    def fun(u):
        work.spend(len(prob.free))
        X[prob.free] = prob.x0 + np.einsum("nik,nk->ni", prob.basis, u.reshape(-1, k))
        f, g = _objective(X, prob)
        return f, np.einsum("nik,ni->nk", prob.basis, g[prob.free]).ravel()

    # first step: move the node with the steepest gradient by a tenth of a target edge
    h = 0.1 / float(np.median(prob.scale))
    u = lbfgs(fun, np.zeros(len(prob.free) * k), iterations, first_step=h, spent=work.spent)
    X[prob.free] = prob.x0 + np.einsum("nik,nk->ni", prob.basis, u.reshape(-1, k))
    return X


def _grow(sub: np.ndarray, seed: np.ndarray, rings: int, n: int) -> np.ndarray:
    """Elements of ``sub`` (over ``n`` nodes) within ``rings`` node-neighbourhoods of the
    seed elements (mask)."""
    sel = seed.copy()
    nodes = np.zeros(n, bool)
    for _ in range(rings):
        nodes[sub[sel].ravel()] = True
        sel = nodes[sub].any(axis=1)
    return sel


def _optimise_nodes(X, sub, target, ids, wall, cap_nodes, wall_normals, cap_normals, project, iterations, work=None):
    """One L-BFGS pass over the nodes ``ids``; wall and cap nodes move in their tangent planes."""
    n = len(X)
    B = np.broadcast_to(np.eye(3), (len(ids), 3, 3)).copy()
    tangent = wall[ids] | cap_nodes[ids]
    if tangent.any() and (wall_normals is not None or cap_normals is not None):
        nrm = np.zeros((len(ids), 3))
        w = wall[ids]
        if w.any() and wall_normals is not None:
            nrm[w] = wall_normals(X[ids[w]])
        c = cap_nodes[ids] & ~w
        if c.any() and cap_normals is not None:
            nrm[c] = cap_normals[ids[c]]
        nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-300)
        t1 = np.cross(nrm, np.where(np.abs(nrm[:, :1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]]))
        t1 /= np.maximum(np.linalg.norm(t1, axis=1, keepdims=True), 1e-300)
        t2 = np.cross(nrm, t1)
        B[tangent, :, 0] = t1[tangent]
        B[tangent, :, 1] = t2[tangent]
        B[tangent, :, 2] = 0.0
    touched = np.zeros(n, bool)
    touched[ids] = True
    use = touched[sub].any(axis=1)
    qmin = float(linear_scaled_jacobian(X, sub[use]).min())
    delta = 1e-3 if qmin > 1e-3 else float(np.sqrt(1e-3 * (1e-3 - min(qmin, 0.0)) + 1e-6))
    scale = (1.0 / target(use)).reshape(-1, 2, 2, 2, 3)
    # the problem on its own nodes, renumbered in order (the same sums in the same order): each
    # evaluation then writes the gradient of those nodes, not of the whole piece of mesh
    nodes, local = np.unique(sub[use], return_inverse=True)
    prob = _Problem(local.reshape(-1, 8), scale, np.searchsorted(nodes, ids), B, X[ids].copy(), delta)
    Y = X.copy()
    Y[nodes] = _minimise(X[nodes], prob, iterations, work)
    if project is not None:
        w = ids[wall[ids]]
        if len(w):
            Y[w] = project(Y[w])
    return Y


class _TargetLengths:
    """Initial corner edge lengths of the sub-hexahedra, computed only for those asked for
    (all of them would take 72 floats per element)."""

    def __init__(self, X0: np.ndarray, sub: np.ndarray, extent: float | None = None):
        self.X0, self.sub = X0, sub
        extent = float(np.ptp(X0, axis=0).max()) if extent is None else extent  # the whole mesh's, for a piece of it
        self.floor = 1e-12 * max(extent, 1e-300)

    def __call__(self, mask: np.ndarray) -> np.ndarray:
        return np.maximum(np.linalg.norm(corner_edges(self.X0, self.sub[mask]), axis=-1), self.floor)


def _score(q: np.ndarray, threshold: float) -> tuple:
    """Larger is better: fewer inverted elements, then fewer below the threshold, then a larger minimum."""
    return (-int((q <= 0).sum()), -int((q < threshold).sum()), float(q.min()))


def untangle(
    # duplicates: a keyword signature like optimize.optimise_linear's (the same constraints, two optimisers)
    points: np.ndarray,
    cells: np.ndarray,
    order: int = 1,
    *,
    wall: np.ndarray | None = None,
    wall_normals=None,
    project=None,
    cap_normals: np.ndarray | None = None,
    cap_nodes: np.ndarray | None = None,
    threshold: float = 0.2,
    rings: int = 2,
    iterations: int = 200,
    rounds: int = 5,
    boundary: np.ndarray | None = None,
    restart_below: float | None = None,
    budget: float | None = 20000.0,
    keep_valid: bool = True,
) -> tuple[np.ndarray, dict]:
    """Move the nodes around elements of low scaled Jacobian to make them valid.

    Parameters
    ----------
    points : (n, 3) float
    cells : (m, (p+1)^3) int, tensor order
    order : int
        Mesh order p (the lattice of sub-hexahedra is optimised).
    wall : (n,) bool, optional
        Nodes on the vessel wall: they slide in their tangent plane and are projected
        back with ``project``.
    wall_normals : callable, optional
        ``wall_normals(points) -> (n, 3)`` unit normals of the wall (e.g. the SDF gradient).
    project : callable, optional
        ``project(points) -> closest wall points``.
    cap_normals : (n, 3) float, optional
        For nodes on flat caps (``cap_nodes``), the cap's normal: they slide in the plane.
    cap_nodes : (n,) bool, optional
    threshold : float
        Elements whose (sub-hexahedron) scaled Jacobian is below this are optimised,
        with ``rings`` rings of neighbours.
    iterations, rounds : int
        L-BFGS iterations per round; rounds of (wall + interior, project, interior only).
    boundary : (n,) bool, optional
        Nodes on the mesh boundary (found from the cells when not given); those that are
        neither wall nor cap nodes stay fixed.
    restart_below : float, optional
        When the result still has an element below this, untangle once more from it, with
        targets taken from the improved mesh, and keep the better of the two. The
        functional is not convex: which local optimum a fold ends in depends on small
        differences of the start, and a restart leaves a poor one.
    budget : float, optional
        Work bound in node updates (one free node in one evaluation of the objective) per
        node of the fold (the nodes of the elements below ``threshold`` at the start): the
        minimisations stop, keeping their best point so far, once ``budget`` times the fold's
        node count is spent (``keep_valid``'s reruns included), so the work grows with the fold and never with the mesh or the
        number of rounds (the default is about twice what the generated g0002 and g0018
        folds take to their end, docs/optimiser.md). ``None``: unbounded.
    keep_valid : bool
        When the result has elements at or below 0 that were valid in ``points`` (the
        functional's sum over a region is minimised, not its minimum, so a wide fold can be
        eased by folding a valid neighbour), untangle again from ``points`` with every node of
        those elements held, up to :data:`KEEP_VALID_RERUNS` times (each rerun holds the nodes
        of the elements the last one folded too), and keep the first rerun that folds no
        valid element and has no more inverted elements and no lower minimum than the plain
        result (``info["keep_valid"]``). A result that folds no valid element is returned as
        it is: the reruns never run.

    Returns
    -------
    points : (n, 3) float
        The new node positions (a copy).
    info : dict
        ``moved`` nodes, ``before``/``after`` minimum sub-element scaled Jacobian, rounds,
        ``work`` (node updates, objective evaluations, the fold's nodes, the limit and
        whether it stopped the untangler).
    """
    sub, _parent = sub_hexahedra(cells, order)
    q = linear_scaled_jacobian(np.asarray(points, float), sub)
    fold = np.unique(sub[q < threshold]) if len(sub) else np.zeros(0, np.int64)
    if boundary is None:  # the mesh's own boundary: a pass sees only a piece of the mesh
        boundary = _mesh_boundary(sub, len(points))
    kw = dict(wall=wall, wall_normals=wall_normals, project=project, cap_normals=cap_normals, cap_nodes=cap_nodes, threshold=threshold, rings=rings, iterations=iterations, rounds=rounds, boundary=boundary)
    work = _Work(None if budget is None else float(budget) * len(fold))  # one bound for the plain run and its reruns
    X, info = _untangle_run(points, sub, q, restart_below, work, None, kw)
    if keep_valid:
        X, info = _keep_valid(points, sub, q, X, info, lambda held: _untangle_run(points, sub, q, restart_below, work, held, kw), work)
    info["work"] = {"node_updates": work.updates, "evaluations": work.evaluations, "limit": work.limit, "exhausted": work.spent(),
                    "fold_nodes": int(len(fold))}
    return X, info


def _untangle_run(points, sub, q, restart_below, work, held, kw):
    """One untangling from ``points`` (sub-hexahedra ``sub``, their scaled Jacobians ``q``):
    the local pass, and its restart when it ends below ``restart_below``; ``held``: nodes
    that do not move (None: none); ``work``: the :class:`_Work` it spends (shared by
    :func:`untangle`'s reruns, so their sum keeps to the bound)."""
    kw = dict(kw, work=work, held=held)
    X, info, moved = _local_pass(points, sub, q, **kw)
    if restart_below is not None and info["rounds"] and info["after"] < restart_below and not work.spent():
        X2, info2, moved2 = _local_pass(X, sub, linear_scaled_jacobian(X, sub), **kw)
        info["restart"] = {"after": info2["after"], "moved": info2["moved"], "rounds": info2["rounds"]}
        if info2["after"] > info["after"]:
            X = X2
            info = {**info2, "before": info["before"], "moved": int((moved | moved2).sum()), "rounds": info["rounds"] + info2["rounds"], "restart": info["restart"]}
    return X, info


#: Reruns of the untangler, per ladder, with nodes of the valid elements it folded held
#: (:func:`_keep_valid`). Each rerun holds the nodes of every element folded so far, so the
#: held set only grows; the reruns run only where a result folds a valid element (s0 g0015
#: extracted of the generated corpus), never on a result that ends valid.
KEEP_VALID_RERUNS = 3


def _keep_valid(points, sub, q0, X, info, rerun, work):
    """Rerun the untangling (``rerun(held) -> (X, info)``) with nodes of the elements it
    folded that were valid at the start (``q0 > 0``) held at their start positions, while a
    result folds such elements; keep the first rerun that folds none and is no worse than
    ``X`` (no more inverted elements, no lower minimum). Two ladders of up to
    :data:`KEEP_VALID_RERUNS` reruns each: first those nodes that no element inverted at the
    start has (held, such nodes would keep that element folded: s0 g0015 extracted, 47
    inverted elements at the start's minimum instead of 35), then all their nodes (which
    keeps the element as it was). Nodes that no run of the ladder moved (fixed, or left where
    they started) are not held: holding them changes nothing but spends a rerun. No rerun starts
    once ``work`` (the untangling's shared :class:`_Work`) is spent. ``info["keep_valid"]``
    reports the reruns; ``(X, info)`` is returned unchanged when ``X`` folds no valid
    element."""
    q = linear_scaled_jacobian(X, sub)
    first = (q0 > 0) & (q <= 0)
    if not first.any():
        return X, info
    report = {"folded_valid": int(first.sum()), "inverted": int((q <= 0).sum()), "min": float(q.min()), "reruns": [], "kept": False}
    unfolding = np.zeros(len(X), bool)
    unfolding[sub[q0 <= 0].ravel()] = True
    for free in (unfolding, np.zeros(len(X), bool)):
        held, folded, moved = np.zeros(len(X), bool), first, np.any(X != points, axis=1)
        for _ in range(KEEP_VALID_RERUNS):
            grown = held.copy()
            grown[sub[folded].ravel()] = True
            grown &= ~free & (held | moved)  # a node no run of this ladder moved (fixed, or left in place): holding it changes nothing
            if (grown == held).all() or work.spent():
                break  # nothing more to hold on this ladder, or no work left for a rerun
            held = grown
            spent = work.updates
            Y, info_y = rerun(held)
            moved |= np.any(Y != points, axis=1)
            qy = linear_scaled_jacobian(Y, sub)
            folded = (q0 > 0) & (qy <= 0)
            run = {"held": int(held.sum()), "all_nodes": not free.any(), "folded_valid": int(folded.sum()), "inverted": int((qy <= 0).sum()), "min": float(qy.min()),
                   "moved": info_y["moved"], "node_updates": work.updates - spent}
            report["reruns"].append(run)
            if not folded.any():
                if run["inverted"] <= report["inverted"] and run["min"] >= report["min"]:
                    report["kept"] = True
                    return Y, {**info_y, "keep_valid": report, "keep_valid_reruns": len(report["reruns"]), "keep_valid_kept": True}
                break
    return X, {**info, "keep_valid": report, "keep_valid_reruns": len(report["reruns"]), "keep_valid_kept": False}


def _mesh_boundary(sub: np.ndarray, n: int) -> np.ndarray:
    """Nodes on faces used by one (sub-)hexahedron only."""
    faces = np.sort(sub[:, _HEX_FACES].reshape(-1, 4), axis=1)
    uniq, counts = np.unique(faces, axis=0, return_counts=True)
    boundary = np.zeros(n, bool)
    boundary[uniq[counts == 1].ravel()] = True
    return boundary


def _local_pass(points, sub, q, *, wall, cap_normals, cap_nodes, threshold, rings, rounds, boundary, held=None, **kw):
    """:func:`_untangle_pass` on the piece of the mesh it can change. Round ``r`` grows a
    region ``rings + r`` node rings around the elements then below ``threshold``, which lie
    in the earlier rounds' regions: all regions lie within ``D = rounds rings + rounds
    (rounds - 1) / 2`` rings of the first ones, and the piece is ``D + 1`` rings, so every
    node of a region has all its elements in the piece: the free nodes, the steps and the
    result are those of the whole mesh, while the per-round work (scaled Jacobians, region
    growth) scales with the folds, not with a mesh of millions of elements. Elements
    outside the piece do not move: the minimum reported counts them once."""
    X = np.array(points, float, copy=True)
    n = len(X)
    bad = q < threshold
    if not bad.any():
        low = float(q.min()) if len(q) else 1.0
        return X, {"before": low, "moved": 0, "rounds": 0, "after": low}, np.zeros(n, bool)
    piece = _grow(sub, bad, rounds * rings + rounds * (rounds - 1) // 2 + 1, n)
    ids = np.unique(sub[piece])
    kw["extent"] = float(np.ptp(X, axis=0).max())
    local = np.full(n, -1, np.int64)
    local[ids] = np.arange(len(ids))
    rest = q[~piece]
    pick = (lambda a: None if a is None else np.asarray(a)[ids])
    Y, info, moved = _untangle_pass(
        X[ids], local[sub[piece]], q[piece], wall=pick(wall), cap_normals=pick(cap_normals), cap_nodes=pick(cap_nodes),
        threshold=threshold, rings=rings, rounds=rounds, boundary=pick(boundary), held=pick(held), **kw,
    )
    X[ids] = Y
    if len(rest):
        info["after"] = min(info["after"], float(rest.min()))
    out = np.zeros(n, bool)
    out[ids] = moved
    return X, info, out


def _untangle_pass(points, sub, q, *, wall, wall_normals, project, cap_normals, cap_nodes, threshold, rings, iterations, rounds, boundary, work, extent=None, held=None):
    """One run of :func:`untangle` (its rounds) from ``points`` over the sub-hexahedra
    ``sub`` (their scaled Jacobians ``q`` at ``points``, None: computed here): new points,
    info and the mask of the nodes it moved (``held``: nodes that stay where they are)."""
    X = np.array(points, float, copy=True)
    n = len(X)
    wall = np.zeros(n, bool) if wall is None else np.asarray(wall, bool)
    cap_nodes = np.zeros(n, bool) if cap_nodes is None else np.asarray(cap_nodes, bool)
    q = linear_scaled_jacobian(X, sub) if q is None else q
    info = {"before": float(q.min()) if len(q) else 1.0, "moved": 0, "rounds": 0}
    if not len(q) or q.min() >= threshold:
        info["after"] = info["before"]
        return X, info, np.zeros(n, bool)  # nothing to do: skip the set-up below, which costs on large meshes
    # nodes on the mesh boundary that are neither wall nor cap nodes never move (without a
    # fixed boundary the regularised functional could shrink the region towards a point)
    if boundary is None:
        boundary = _mesh_boundary(sub, n)
    rim = (wall & cap_nodes) | (np.asarray(boundary, bool) & ~wall & ~cap_nodes)
    if held is not None:
        rim |= np.asarray(held, bool)
    # targets: initial edge lengths at every corner (keeps graded layers graded)
    target = _TargetLengths(X.copy(), sub, extent)
    moved = np.zeros(n, bool)
    for rnd in range(rounds):
        bad = q < threshold
        if not bad.any() or work.spent():
            break
        info["rounds"] = rnd + 1
        region = _grow(sub, bad, rings + rnd, n)
        # free nodes: nodes of the region not shared with elements outside it
        inside = np.zeros(n, bool)
        inside[sub[region].ravel()] = True
        outside = np.zeros(n, bool)
        outside[sub[~region].ravel()] = True
        free_all = inside & ~outside & ~rim
        best = None
        for phases in (("with_wall", "interior"), ("interior",)):
            Y = X.copy()
            changed = np.zeros(n, bool)
            for phase in phases:
                free = free_all & ~wall if phase == "interior" else free_all
                ids = np.flatnonzero(free)
                if len(ids) == 0 or work.spent():
                    continue
                Y = _optimise_nodes(Y, sub, target, ids, wall, cap_nodes, wall_normals, cap_normals, project if phase == "with_wall" else None, iterations, work)
                changed[ids] = True
            qy = linear_scaled_jacobian(Y, sub)
            if best is None or _score(qy, threshold) > _score(best[1], threshold):
                best = (Y, qy, changed)
            if qy.min() >= threshold or _score(qy, threshold) > _score(q, threshold):
                break  # the interior-only variant is the fallback when sliding on the wall does not help
        if _score(best[1], threshold) <= _score(q, threshold):
            break  # a larger region rarely rescues a round that gained nothing: stop early
        X, q = best[0], best[1]
        moved |= best[2]
    info["after"] = float(q.min()) if len(q) else 1.0
    info["moved"] = int(moved.sum())
    return X, info, moved
