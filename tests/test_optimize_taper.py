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
