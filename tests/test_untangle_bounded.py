"""The global L-BFGS untangler's work is bounded by the size of the fold (issue 17 item 8).

Generated g0002 (a 4-furcation with a radius jump) ran past the 240 s timeout in
``untangle._objective``: its folds cannot be made valid, and the untangler went on through
all its rounds and a restart over regions of thousands of nodes. Work is counted in node
updates (free nodes times evaluations of the objective), never in seconds.
"""

import numpy as np

from vmesh.geometry.untangle import _dot, linear_scaled_jacobian, untangle


def _lattice(n):
    """A unit-spaced n^3 lattice of hexahedra in tensor corner order (i fastest)."""
    g = np.arange(n + 1, dtype=float)
    P = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).transpose(2, 1, 0, 3).reshape(-1, 3)
    idx = np.arange((n + 1) ** 3).reshape(n + 1, n + 1, n + 1)  # [k, j, i]
    a = np.arange(n)
    k, j, i = np.meshgrid(a, a, a, indexing="ij")
    corners = [idx[k + ck, j + cj, i + ci] for ck in (0, 1) for cj in (0, 1) for ci in (0, 1)]
    return P, np.stack([c.ravel() for c in corners], axis=1)


def _hopeless_fold(n):
    """A lattice whose face x = 0 (fixed boundary nodes) is folded: two neighbouring nodes
    of that face swap places, and no move of the free nodes can make their elements valid."""
    P, H = _lattice(n)
    a = np.flatnonzero((P[:, 0] == 0) & (P[:, 1] == 2) & (P[:, 2] == 2))[0]
    b = np.flatnonzero((P[:, 0] == 0) & (P[:, 1] == 3) & (P[:, 2] == 2))[0]
    P[[a, b]] = P[[b, a]]
    return P, H


def test_a_hopeless_fold_costs_the_same_bounded_work_in_a_small_and_a_large_mesh():
    runs = {}
    for n in (6, 10):
        P, H = _hopeless_fold(n)
        assert (linear_scaled_jacobian(P, H) <= 0).any()
        X, info = untangle(P, H, 1, threshold=0.3, restart_below=0.3, budget=200.0)
        w = info["work"]
        assert w["exhausted"] and (linear_scaled_jacobian(X, H) <= 0).any()  # it cannot: the fold is in the fixed boundary
        # one evaluation past the limit at most (the check runs before each evaluation)
        largest_region = len(P)
        assert w["limit"] == 200.0 * w["fold_nodes"] and w["node_updates"] <= w["limit"] + largest_region
        runs[n] = w
    # the fold, and so the limit, is the same in both meshes
    assert runs[6]["fold_nodes"] == runs[10]["fold_nodes"]
    # without the bound the same fold costs more (all rounds and the restart)
    P, H = _hopeless_fold(10)
    _, free = untangle(P, H, 1, threshold=0.3, restart_below=0.3)
    assert free["work"]["node_updates"] > 2 * runs[10]["limit"]


def test_the_bound_does_not_stop_an_untangling_that_succeeds_within_it():
    P, H = _lattice(5)
    centre = np.argmin(np.linalg.norm(P - 2.0, axis=1))
    P[centre] += [1.4, 1.3, 1.2]  # an interior node pushed through its neighbours
    X, info = untangle(P, H, 1, threshold=0.5, budget=2000.0)
    assert not info["work"]["exhausted"] and linear_scaled_jacobian(X, H).min() > 0.5
    X2, info2 = untangle(P, H, 1, threshold=0.5)
    assert np.array_equal(X, X2) and info2["work"]["node_updates"] == info["work"]["node_updates"]


def test_dot_is_the_dot_product():
    a, b = np.random.default_rng(0).normal(size=(2, 12345))
    assert np.isclose(_dot(a, b), float(a @ b))


def test_compiled_objective_is_the_numpy_sum_and_its_gradient_the_derivative():
    """``untangle._objective`` (the compiled ``objective.escobar_sum``) gives the numpy form's
    functional and gradient on a folded lattice, and the gradient is the functional's
    derivative (central differences)."""
    from vmesh.geometry.untangle import _objective, _objective_numpy, _Problem

    P, H = _lattice(4)
    rng = np.random.default_rng(3)
    P = P + rng.normal(scale=0.35, size=P.shape)  # some corners inverted
    assert (linear_scaled_jacobian(P, H) <= 0).any()
    scale = rng.uniform(0.5, 2.0, size=(len(H), 2, 2, 2, 3))
    prob = _Problem(H, scale, np.arange(len(P)), None, None, 0.05)
    f, g = _objective(P, prob)
    f_ref, g_ref = _objective_numpy(P, prob)
    assert abs(f - f_ref) <= 1e-12 * abs(f_ref)
    assert np.abs(g - g_ref).max() <= 1e-12 * np.abs(g_ref).max()
    h = 1e-6
    for v, d in [(31, 0), (62, 1), (70, 2)]:
        Pp, Pm = P.copy(), P.copy()
        Pp[v, d] += h
        Pm[v, d] -= h
        fd = (_objective(Pp, prob)[0] - _objective(Pm, prob)[0]) / (2 * h)
        assert abs(fd - g[v, d]) <= 1e-5 * max(1.0, abs(g[v, d]))


def _rings_of(H, seed_elements, rings, n):
    """Nodes of the elements within ``rings`` node-neighbourhoods of ``seed_elements`` (mask)."""
    sel = np.zeros(len(H), bool)
    sel[seed_elements] = True
    for _ in range(rings):
        nodes = np.zeros(n, bool)
        nodes[H[sel].ravel()] = True
        sel = nodes[H].any(axis=1)
    out = np.zeros(n, bool)
    out[H[sel].ravel()] = True
    return out


def test_untangling_a_fold_moves_only_nodes_near_it():
    """Locality: a fold of a few interior nodes in a large lattice is untangled by moving
    only nodes of the elements within the untangler's rings of the folded elements (its
    regions grow by one ring a round), and the far mesh is untouched."""
    P, H = _lattice(12)
    rng = np.random.default_rng(5)
    inner = np.flatnonzero(np.all(np.abs(P - 6.0) <= 1.0, axis=1))
    X0 = P.copy()
    X0[inner[rng.choice(len(inner), 4, replace=False)]] += rng.normal(scale=0.9, size=(4, 3))
    q0 = linear_scaled_jacobian(X0, H)
    assert (q0 <= 0).sum() >= 4
    X, info = untangle(X0, H, 1, threshold=0.3, rings=2, restart_below=None)
    assert linear_scaled_jacobian(X, H).min() > 0.3
    moved = np.any(X != X0, axis=1)
    near = _rings_of(H, np.flatnonzero(q0 < 0.3), 2 + info["rounds"] - 1, len(P))
    assert moved.any() and not (moved & ~near).any()
    assert near.mean() < 0.3  # the rings are a neighbourhood, not the lattice


def test_each_pass_works_on_the_folds_piece_with_the_whole_meshs_result():
    # BraVa BG0002: 4 M elements, folds in 13 % of them within reach of the rounds; every
    # round computed the whole mesh's scaled Jacobians and grew its region over it
    from vmesh.geometry import untangle as un

    P, H = _lattice(24)
    for c in (3.0, 20.0):  # two folds far apart: interior nodes pushed through their neighbours
        node = np.argmin(np.linalg.norm(P - c, axis=1))
        P[node] += [1.4, 1.3, 1.2]
    P[:, 0] += 0.15 * np.sin(P[:, 1]) * (P[:, 0] > 0) * (P[:, 0] < 24)  # a high goal: the regions grow for two rounds
    q = linear_scaled_jacobian(P, H)
    kw = dict(wall=None, wall_normals=None, project=None, cap_normals=None, cap_nodes=None, threshold=0.95, rings=1, iterations=50, rounds=3)
    boundary = un._mesh_boundary(H, len(P))
    whole = un._untangle_pass(P, H, q, boundary=boundary, work=un._Work(None), **kw)
    piece = un._local_pass(P, H, q, boundary=boundary, work=un._Work(None), **kw)
    assert np.array_equal(whole[0], piece[0]) and np.array_equal(whole[2], piece[2])
    assert whole[1] == piece[1] and whole[1]["rounds"] >= 2 and whole[1]["moved"] > 0


def test_a_pass_works_on_its_own_nodes_and_moves_them_as_on_the_whole_mesh():
    """``_optimise_nodes`` minimises over the free nodes' elements renumbered onto their own
    nodes (a large tree's piece of mesh has ~550,000 nodes around a fold of a few thousand:
    each evaluation wrote the gradient of all of them): the same points, to the bit, as the
    problem posed on the whole mesh, and the same work."""
    from vmesh.geometry.untangle import _minimise, _optimise_nodes, _Problem, _TargetLengths, _Work

    P, H = _lattice(12)
    rng = np.random.default_rng(1)
    ball = np.linalg.norm(P - 6.0, axis=1) < 3
    P[ball] += rng.normal(scale=0.35, size=(ball.sum(), 3))
    assert (linear_scaled_jacobian(P, H) <= 0).any()
    ids = np.flatnonzero(ball)
    none = np.zeros(len(P), bool)
    target = _TargetLengths(P.copy(), H)
    work = _Work()
    Y = _optimise_nodes(P, H, target, ids, none, none, None, None, None, 200, work)
    # the problem as it was posed before: every node of the mesh, the elements in place
    use = np.isin(H, ids).any(axis=1)
    qmin = float(linear_scaled_jacobian(P, H[use]).min())
    delta = 1e-3 if qmin > 1e-3 else float(np.sqrt(1e-3 * (1e-3 - min(qmin, 0.0)) + 1e-6))
    basis = np.broadcast_to(np.eye(3), (len(ids), 3, 3)).copy()
    whole = _Work()
    Z = _minimise(P, _Problem(H[use], (1.0 / target(use)).reshape(-1, 2, 2, 2, 3), ids, basis, P[ids].copy(), delta), 200, whole)
    assert np.array_equal(Y, Z)
    assert (work.updates, work.evaluations) == (whole.updates, whole.evaluations)
    assert linear_scaled_jacobian(Y, H).min() > qmin
