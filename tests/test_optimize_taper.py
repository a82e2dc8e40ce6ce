"""The light pass's Jacobian-ratio guard (``optimise_linear(ratio_floor=)``, mesh_transfinite's
``light_pass_ratio_floor``): the corner scaled Jacobians it climbs do not see an element
tapering (one edge shrinking while the angles stay), the ratio min / max det J does."""

import numpy as np

from test_optimize_frame import frame_setup
from test_optimize import R, cylinder, first_layer_nodes
from vmesh.geometry.optimize import kernels as K
from vmesh.geometry.optimize import optimise
from vmesh.geometry.quality import hex8_scaled_jacobian, jacobian_ratio


def _least_ratio_around(X, hexes, v):
    return jacobian_ratio(X, hexes[np.any(hexes == v, axis=1)], 1).min()


def test_the_guard_refuses_exactly_the_trials_that_lower_the_least_ratio_below_the_floor():
    """A node's trials from its frame (``kernels.node_eval``): with the guard, a trial is
    refused (``qmin = -inf``) exactly where the least Jacobian ratio of the node's elements,
    computed on the displaced mesh, falls below the lesser of the floor and that least ratio
    before; without it, never (the scaled Jacobians' floor off)."""
    X, hexes, scale, ptr, inc, cq, valence, L, buf = frame_setup()
    rng = np.random.default_rng(5)
    refused = kept = 0
    for v in rng.choice(np.flatnonzero(valence == 8), 12, replace=False):
        K.frame(X, hexes, scale, ptr, inc, cq, v, L)
        before = _least_ratio_around(X, hexes, v)
        for z in rng.normal(size=(8, 3)) * 0.04:
            Y = X.copy()
            Y[v] += z
            after = _least_ratio_around(Y, hexes, v)
            for floor in (0.3, 0.9):
                q = K.node_eval(L, ptr, inc, cq, v, z[0], z[1], z[2], 1e-3, False, False, True, buf, np.int64(0), False, -np.inf, floor)[10]
                if abs(after - min(before, floor)) > 1e-9:  # not on the edge of the rule
                    assert (q == -np.inf) == (after < min(before, floor))
                refused += q == -np.inf
                kept += q > -np.inf
            assert K.node_eval(L, ptr, inc, cq, v, z[0], z[1], z[2], 1e-3, False, False, True, buf, np.int64(0), False, -np.inf, -np.inf)[10] > -np.inf
    assert refused and kept


def _tapered_cylinder(seed=2, amp=0.8):
    """The O-grid cylinder with the boundary layer's second row of nodes moved at random along
    their radius, between the first row and well above it (the second layer tapers: Jacobian
    ratio down to ~0.1), then untangled as ``mesh_transfinite`` does before its light pass."""
    sm, kw = cylinder()
    X = sm.points.copy()
    first, wall, cells = first_layer_nodes(sm), kw["wall"], sm.cells
    second = np.zeros(len(X), bool)
    for c in range(8):
        for a in range(3):
            u, w = cells[:, c], cells[:, c ^ (1 << a)]
            second[w[first[u] & ~first[w] & ~wall[w]]] = True
    pick = second & ~kw["boundary"]
    r, top = np.linalg.norm(X[:, :2], axis=1), R * (1 - 0.02)
    s = np.random.default_rng(seed).uniform(1 - amp, 1 + amp, pick.sum())
    X[pick, :2] *= ((top - s * (top - r[pick])) / r[pick])[:, None]
    X, _ = optimise(X, cells, 1, **kw, untangle_below=0.3, smooth_below=0.5)
    return sm, kw, X


def test_light_pass_keeps_a_tapered_layer_from_tapering_more_and_the_first_height():
    """The light pass with the guard on a tapered boundary layer: the mesh's least Jacobian
    ratio does not drop below the lesser of the floor and its value before, no element falls
    below that, the first boundary-layer height (nodes one edge off the wall, cap planes
    aside) is kept exactly, and the scaled Jacobians' minimum does not drop while the mean
    rises."""
    sm, kw, X = _tapered_cylinder()
    ratio0, q0 = jacobian_ratio(X, sm.cells, 1), hex8_scaled_jacobian(X, sm.cells)
    assert ratio0.min() < 0.2 and q0.min() >= 0.3
    Y, info = optimise(X, sm.cells, 1, **kw, untangle_below=0.0, smooth_below=0.95, smooth_sweeps=6, smooth_tol=0.01, ratio_floor=0.3, over_relax=1.5)
    ratio, q = jacobian_ratio(Y, sm.cells, 1), hex8_scaled_jacobian(Y, sm.cells)
    assert info["smoothed_nodes"] > 0
    assert ratio.min() >= min(ratio0.min(), 0.3) - 1e-12
    assert q.min() >= q0.min() and q.mean() > q0.mean()
    top = first_layer_nodes(sm) & ~kw["cap_nodes"]
    height = lambda P: R - np.linalg.norm(P[top, :2], axis=1)  # noqa: E731
    assert np.abs(height(Y) - height(X)).max() < 1e-9
    assert np.abs(np.linalg.norm(Y[kw["wall"], :2], axis=1) - R).max() < 1e-9


def test_max_min_direction_keeps_a_constraint_row_from_falling():
    """``worst._least_norm(cone=True)``: the last row is a constraint (its rate may not be
    negative), the others objectives; against a brute-force search over unit directions, the
    direction found keeps the constraint and raises the objectives' least rate as far as the
    best feasible direction does (or there is none)."""
    from vmesh.geometry.optimize.worst import _least_norm

    rng = np.random.default_rng(1)
    P = rng.normal(size=(40000, 3))
    P /= np.linalg.norm(P, axis=1)[:, None]
    G = rng.normal(size=(60, 4, 3))
    ok = np.column_stack([np.ones(60, bool), rng.random(60) < 0.7, rng.random(60) < 0.5, np.ones(60, bool)])
    p, pn = _least_norm(G, ok, cone=True)
    for c in range(60):
        rows = G[c, :3][ok[c, :3]]
        rate = np.where(P @ G[c, 3] >= 0, (P @ rows.T).min(axis=1), -np.inf)
        if np.isfinite(pn[c]) and pn[c] > 1e-20:
            d = p[c] / np.sqrt(pn[c])
            assert d @ G[c, 3] >= -1e-9
            assert (rows @ d).min() >= rate.max() - 1e-12 and np.isclose((rows @ d).min(), np.sqrt(pn[c]))
        else:
            assert rate.max() < 1e-2


def test_guarded_worst_pass_climbs_without_lowering_the_ratio():
    """The max-min pass with the guard on a jittered 3x3x3 block (boundary fixed; floor 1: every
    node's least ratio is at the guard's limit). The session-21 form (its direction blind to the
    ratio, ``RATIO_ACTIVE = -1``) has its steps refused wherever they lower that ratio and
    stops at 0.721; with the ratio a constraint of the direction it reaches 0.77, the ratio
    rising too (0.30 -> 0.42); unguarded it reaches 0.80 with the ratio down to 0.24."""
    import vmesh.geometry.optimize.worst as W

    from test_worst_pass import _jittered_block

    g, _, hexes, _, _, _ = _jittered_block()
    X = g + np.random.default_rng(1).normal(size=g.shape) * 0.12
    kind = np.where(((g == 0) | (g == 3)).any(axis=1), K.FIXED, K.FREE).astype(np.int64)
    q0, r0 = hex8_scaled_jacobian(X, hexes).min(), jacobian_ratio(X, hexes, 1).min()

    def lifted(ratio_floor, active=W.RATIO_ACTIVE):
        Y, keep = X.copy(), W.RATIO_ACTIVE
        W.RATIO_ACTIVE = active
        try:
            W.lift_worst(Y, hexes, 0.99, kind, np.zeros((64, 3)), np.zeros(64), sweeps=30, ratio_floor=ratio_floor)
        finally:
            W.RATIO_ACTIVE = keep
        return hex8_scaled_jacobian(Y, hexes).min(), jacobian_ratio(Y, hexes, 1).min()

    blind, guarded, free = lifted(1.0, -1.0), lifted(1.0), lifted(-np.inf)
    assert min(blind[1], guarded[1]) >= r0 - 1e-12 and free[1] < r0
    assert q0 < blind[0] < guarded[0] - 0.03 and guarded[0] < free[0]


def test_ratio_rows_give_the_least_ratio_around_a_node_and_its_gradient():
    """``kernels_worst.ratio_rows`` on a jittered 3x3x3 block: the least Jacobian ratio of each
    node's hexahedra less the guard's limit (0 below the floor), and that hexahedron's ratio
    gradient against central differences of ``jacobian_ratio``."""
    from vmesh.geometry.optimize.kernels_worst import ratio_rows

    from test_worst_pass import _jittered_block

    _, X, hexes, ptr, inc, nodes = _jittered_block()
    margin, G = ratio_rows(X, hexes, ptr, inc, nodes, 0.3)
    for a, v in enumerate(nodes):
        around = hexes[np.any(hexes == v, axis=1)]
        least = jacobian_ratio(X, around, 1).min()
        assert np.isclose(margin[a], least - min(0.3, least), atol=1e-12)
        fd = np.zeros(3)
        for d in range(3):
            Y = X.copy()
            Y[v, d] += 1e-6
            up = jacobian_ratio(Y, around, 1).min()
            Y[v, d] -= 2e-6
            fd[d] = (up - jacobian_ratio(Y, around, 1).min()) / 2e-6
        np.testing.assert_allclose(G[a], fd, atol=1e-6)
