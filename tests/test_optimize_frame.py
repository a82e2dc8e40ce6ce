"""The optimiser's local frame (vmesh.geometry.optimize.kernels.frame): a node's trial
qualities and functional come from its frame, not from the mesh; they must equal the mesh's."""

import numpy as np

from cylinder_blocks import cylinder_blocks, project_cylinder
from vmesh.geometry.optimize import kernels as K
from vmesh.geometry.optimize import trials
from vmesh.geometry.transfinite import Refinement, mesh_blocks


def _jittered_mesh():
    sm = mesh_blocks(cylinder_blocks(radius=2.0), project_cylinder(2.0), Refinement(around=2, core=2, ring=2, layer=3, element_length=0.5, first_layer=0.05, curved_sections=True))
    X = sm.points + np.random.default_rng(0).normal(size=sm.points.shape) * 0.02
    hexes = np.ascontiguousarray(sm.cells, np.int64)
    scale = K.target_scales(X, hexes, 1e-9)
    ptr, inc = K.incidence(hexes, len(X))
    return X, hexes, scale, ptr, inc


def test_frame_trials_equal_the_displaced_mesh():
    """For nodes of every valence and random displacements: the scaled Jacobians a trial
    computes from the frame equal those of the mesh with the node moved (every corner of
    every incident hexahedron), and so do their minimum and sum per node."""
    X, hexes, scale, ptr, inc = _jittered_mesh()
    cq = K.corner_qualities(X, hexes, scale)
    valence = np.diff(ptr)
    rng = np.random.default_rng(1)
    nodes = np.concatenate([rng.choice(np.flatnonzero(valence == k), 3) for k in np.unique(valence)])
    L = np.empty((valence.max(), K.NL))
    buf = np.empty((1, 4 * valence.max()))
    for v in nodes:
        z = rng.normal(size=3) * 0.05
        K.frame(X, hexes, scale, ptr, inc, cq, v, L)
        r = K.node_eval(L, ptr, inc, cq, v, z[0], z[1], z[2], 1e-3, False, False, True, buf, np.int64(0), False, -np.inf, -np.inf)
        Y = X.copy()
        Y[v] += z
        moved = K.corner_qualities(Y, hexes, scale)
        elements = inc[ptr[v] : ptr[v + 1]] >> 3
        h = moved[elements].min(axis=1)
        assert np.isclose(r[10], h.min(), rtol=0, atol=1e-12) and np.isclose(r[11], h.sum(), rtol=0, atol=1e-11)
        for t, e in enumerate(elements):
            lc = inc[ptr[v] + t] & 7
            for q in range(4):
                c = lc if q == 0 else lc ^ (1 << (q - 1))
                assert abs(buf[0, 4 * t + q] - moved[e, c]) < 1e-12


def test_frame_gradient_and_hessian_match_finite_differences():
    """The functional's gradient and Hessian from the frame match central differences of
    its value (the determinants are affine in the node, so the frame is exact)."""
    X, hexes, scale, ptr, inc = _jittered_mesh()
    cq = K.corner_qualities(X, hexes, scale)
    L = np.empty((int(np.diff(ptr).max()), K.NL))
    buf = np.empty((1, L.shape[0] * 4))
    v = int(np.argmax(np.diff(ptr)))
    K.frame(X, hexes, scale, ptr, inc, cq, v, L)

    def f(z):
        return K.node_eval(L, ptr, inc, cq, v, z[0], z[1], z[2], 1e-3, True, True, False, buf, np.int64(-1), False, -np.inf, -np.inf)

    r = f(np.zeros(3))
    g, H = np.array(r[1:4]), np.array([[r[4], r[5], r[6]], [r[5], r[7], r[8]], [r[6], r[8], r[9]]])
    eps = 1e-5
    for a in range(3):
        d = np.zeros(3)
        d[a] = eps
        fp, fm = f(d), f(-d)
        assert np.isclose((fp[0] - fm[0]) / (2 * eps), g[a], rtol=1e-5, atol=1e-8)
        assert np.allclose((np.array(fp[1:4]) - np.array(fm[1:4])) / (2 * eps), H[a], rtol=1e-4, atol=1e-6)


def frame_setup():
    """The jittered mesh, its corner qualities, valences and a frame's buffers (``L``, ``buf``)
    sized for its busiest node: what a test of ``kernels.node_eval`` starts from."""
    X, hexes, scale, ptr, inc = _jittered_mesh()
    valence = np.diff(ptr)
    return X, hexes, scale, ptr, inc, K.corner_qualities(X, hexes, scale), valence, np.empty((valence.max(), K.NL)), np.empty((1, 4 * valence.max()))


def test_frame_functional_equals_the_displaced_mesh():
    """The functional's value from the frame (summed in a loop of its own after the
    qualities) equals Escobar's measure of the displaced mesh's moved corners, computed
    directly in numpy from their scaled edges: |E|^2 / (3 h(det E)^(2/3))."""
    X, hexes, scale, ptr, inc, cq, valence, L, buf = frame_setup()
    rng = np.random.default_rng(2)
    delta = 1e-3
    for v in rng.choice(np.flatnonzero(valence == valence.max()), 3, replace=False):
        z = rng.normal(size=3) * 0.05
        K.frame(X, hexes, scale, ptr, inc, cq, v, L)
        f = K.node_eval(L, ptr, inc, cq, v, z[0], z[1], z[2], delta, True, True, True, buf, np.int64(0), False, -np.inf, -np.inf)[0]
        Y = X.copy()
        Y[v] += z
        want = 0.0
        for t in range(ptr[v], ptr[v + 1]):
            e, lc = inc[t] >> 3, inc[t] & 7
            for c in [lc] + [lc ^ (1 << a) for a in range(3)]:
                E = np.array([(1.0 if (c >> a) & 1 == 0 else -1.0) * scale[e, a] * (Y[hexes[e, c ^ (1 << a)]] - Y[hexes[e, c]]) for a in range(3)])
                D = np.linalg.det(E)
                h = 0.5 * (D + np.sqrt(D * D + 4 * delta * delta))
                want += (E * E).sum() / (3 * h ** (2 / 3))
        assert np.isclose(f, want, rtol=1e-12, atol=0)


def test_colour_pass_with_prefetch_equals_its_steps_in_order():
    """A colour pass (which asks for the next nodes' data ahead, optimize/prefetch.py) moves
    its nodes exactly as their steps taken one by one in order, also for colours shorter
    than the look-ahead and chunks of one node (the look-ahead stops at a chunk's end)."""
    X0, hexes, scale, ptr, inc = _jittered_mesh()
    n = len(X0)
    colour = K.colour_nodes(hexes, ptr, inc, np.arange(n), n)
    first = np.flatnonzero(colour == 0)
    kind, normal = np.full(n, K.FREE, np.int64), np.zeros((n, 3))
    width = 4 * int(np.diff(ptr).max())
    for nodes in (first[:1], first[:2], first[:3], first[:70], first):
        runs = []
        for kernel in (K.sweep_colour_serial, K.sweep_colour_parallel, None):
            X, cq = X0.copy(), K.corner_qualities(X0, hexes, scale)
            caps = K.step_caps(X, hexes, ptr, inc, nodes, n, 0.5)
            trial, state, buf = np.empty((len(nodes), 3)), np.empty((len(nodes), 4)), np.empty((len(nodes), width))
            dirty = np.ones(n, np.bool_)
            args = (K.SMOOTH, 0.95, trial, state, dirty, buf, 0.01, -np.inf, 1.0)
            if kernel is not None:
                kernel(X, hexes, scale, ptr, inc, cq, nodes, kind, normal, caps, 1e-3, *args)
            else:
                L = np.empty((width // 4, K.NL))
                for j, v in enumerate(nodes):
                    state[j, 3] = 0.0
                    trial[j] = X[v]
                    dirty[v] = False
                    K._step_node(X, hexes, scale, ptr, inc, cq, j, v, kind, normal, caps, 1e-3, *args[:2], trial, state, dirty, buf, 0.01, L, -np.inf, 1.0)
            runs.append((X, cq, state[:, 3].copy(), dirty))
        assert runs[0][2].any() or len(nodes) < 70  # the larger colours move nodes
        for other in runs[1:]:
            for a, b in zip(runs[0], other):
                assert np.array_equal(a, b)


def test_trial_quality_equals_node_eval_bit_for_bit():
    """A trial judged by the scaled Jacobians alone (``trials.trial_quality``, the light
    pass's trials) gives exactly node_eval's minimum, sum, refusing row and stored corner
    values, with and without a floor; ``trials.row_below`` refuses exactly where a floor check of
    that row's corners would."""
    X, hexes, scale, ptr, inc, cq, valence, L, buf = frame_setup()
    other = np.empty_like(buf)
    rng = np.random.default_rng(3)
    refused = accepted = 0
    for v in np.concatenate([rng.choice(np.flatnonzero(valence == k), 3) for k in np.unique(valence)]):
        K.frame(X, hexes, scale, ptr, inc, cq, v, L, False)
        start = K.node_eval(L, ptr, inc, cq, v, 0.0, 0.0, 0.0, 1e-3, False, False, True, buf, np.int64(-1), False, -np.inf, -np.inf)
        for size in (0.01, 0.05, 0.2):
            z = rng.normal(size=3) * size
            for floor in (-np.inf, start[10], np.nextafter(start[10], np.inf)):
                want = K.node_eval(L, ptr, inc, cq, v, z[0], z[1], z[2], 1e-3, False, False, True, buf, np.int64(0), False, floor, -np.inf)
                got = trials.trial_quality(L, ptr, v, z[0], z[1], z[2], other, np.int64(0), floor)
                assert got[0] == want[10] and got[1] == want[11] and got[2] == want[12]
                if want[12] >= 0:  # refused at that row: it holds a corner below the floor
                    refused += 1
                    assert trials.row_below(L, np.int64(want[12]), z[0], z[1], z[2], floor)
                    continue
                accepted += 1
                n = 4 * (ptr[v + 1] - ptr[v])
                assert np.array_equal(buf[0, :n], other[0, :n])
                for r in range(n // 4):
                    assert trials.row_below(L, np.int64(r), z[0], z[1], z[2], floor) == bool((other[0, 4 * r : 4 * r + 4] < floor).any())
    assert refused and accepted


def test_guarded_trial_quality_equals_node_eval_bit_for_bit():
    """With the taper guard (the default light pass), ``trials.trial_quality_guarded`` gives
    exactly node_eval's minimum, sum, refusing row and stored corner values: refusals by a
    corner below the floor and by a hexahedron's Jacobian ratio below the guard's least ratio
    (``trials.least_ratio``) both occur."""
    X, hexes, scale, ptr, inc, cq, valence, L, buf = frame_setup()
    other = np.empty_like(buf)
    rng = np.random.default_rng(5)
    by_ratio = by_corner = accepted = 0
    for v in np.concatenate([rng.choice(np.flatnonzero(valence == k), 3) for k in np.unique(valence)]):
        K.frame(X, hexes, scale, ptr, inc, cq, v, L, True)
        start = K.node_eval(L, ptr, inc, cq, v, 0.0, 0.0, 0.0, 1e-3, False, False, True, buf, np.int64(-1), False, -np.inf, -np.inf)
        for ratio_floor in (0.3, 0.8, 0.95):
            least = trials.least_ratio(L, np.int64(valence[v]), ratio_floor)
            for size in (0.01, 0.05, 0.2):
                z = rng.normal(size=3) * size
                for floor in (-np.inf, start[10], np.nextafter(start[10], np.inf)):
                    want = K.node_eval(L, ptr, inc, cq, v, z[0], z[1], z[2], 1e-3, False, False, True, buf, np.int64(0), False, floor, ratio_floor)
                    got = trials.trial_quality_guarded(L, ptr, v, z[0], z[1], z[2], other, np.int64(0), floor, least)
                    assert got[0] == want[10] and got[1] == want[11] and got[2] == want[12]
                    if want[12] >= 0:
                        by_corner += 1
                    elif want[10] == -np.inf:
                        by_ratio += 1
                    else:
                        accepted += 1
                        n = 4 * (ptr[v + 1] - ptr[v])
                        assert np.array_equal(buf[0, :n], other[0, :n])
    assert by_ratio and by_corner and accepted


def test_ordered_trial_quality_decides_and_keeps_as_the_row_order():
    """A light-pass trial with its rows in ``trials.order_rows``'s order, refused once its sum of
    minima cannot reach the start's (``trials.trial_quality_ordered``), takes the same decision
    as the row-order evaluation for a Newton trial (minimum kept, sum raised) and a climb
    (minimum raised, sum kept), with and without the taper guard, and an accepted trial has the
    same minimum, sum and stored corners bit for bit; refusals by the sum bound occur."""
    X, hexes, scale, ptr, inc, cq, valence, L, buf = frame_setup()
    other, start = np.empty_like(buf), np.empty_like(buf)
    rng = np.random.default_rng(7)
    early = kept = refused = 0
    for v in np.concatenate([rng.choice(np.flatnonzero(valence == k), 4) for k in np.unique(valence)]):
        K.frame(X, hexes, scale, ptr, inc, cq, v, L, True)
        s = K.node_eval(L, ptr, inc, cq, v, 0.0, 0.0, 0.0, 1e-3, False, False, True, start, np.int64(0), False, -np.inf, -np.inf)
        qmin0, qsum0 = s[10], s[11]
        gap_floor = trials.order_rows(L, np.int64(valence[v]), start[0], qsum0)
        assert sorted(L[: valence[v], trials.ORDER].astype(int)) == list(range(valence[v]))
        for guarded, ratio_floor in ((False, -np.inf), (True, 0.3)):
            least = trials.least_ratio(L, np.int64(valence[v]), ratio_floor) if guarded else -np.inf
            for size in (0.002, 0.01, 0.05):
                z = rng.normal(size=3) * size
                for climb, floor in ((False, qmin0), (True, np.nextafter(qmin0, np.inf))):
                    if guarded:
                        want = trials.trial_quality_guarded(L, ptr, v, z[0], z[1], z[2], buf, np.int64(0), floor, least)
                    else:
                        want = trials.trial_quality(L, ptr, v, z[0], z[1], z[2], buf, np.int64(0), floor)
                    got = trials.trial_quality_ordered(L, ptr, v, z[0], z[1], z[2], other, np.int64(0), floor, least, guarded, gap_floor)
                    f0 = np.inf if climb else 0.0
                    ok = K._acceptable(K.SMOOTH, 0.0, want[0], want[1], f0, qmin0, qsum0)
                    assert K._acceptable(K.SMOOTH, 0.0, got[0], got[1], f0, qmin0, qsum0) == ok
                    if ok:
                        kept += 1
                        n = 4 * valence[v]
                        assert got[0] == want[0] and got[1] == want[1] and np.array_equal(buf[0, :n], other[0, :n])
                    else:
                        refused += 1
                        early += want[0] > -np.inf and got[0] == -np.inf
    assert kept and refused and early


def test_untangling_trial_floor_takes_the_same_decision():
    """An untangling trial judged by its minimum (``kernels.UNTANGLE``, non-wall nodes) is
    evaluated with the start's minimum as ``node_eval``'s floor: a trial it cuts short is one
    the whole evaluation refuses too, and one it evaluates whole has the same functional,
    minimum and sum."""
    X, hexes, scale, ptr, inc, cq, valence, L, buf = frame_setup()
    # duplicates: the sampling loop of the light-pass trial test above, for the untangling mode
    rng = np.random.default_rng(11)
    cut = whole = 0
    for v in np.concatenate([rng.choice(np.flatnonzero(valence == k), 3) for k in np.unique(valence)]):
        K.frame(X, hexes, scale, ptr, inc, cq, v, L, False)
        s = K.node_eval(L, ptr, inc, cq, v, 0.0, 0.0, 0.0, 1e-3, True, True, True, buf, np.int64(-1), False, -np.inf, -np.inf)
        for size in (0.005, 0.02, 0.1):
            z = rng.normal(size=3) * size
            full = K.node_eval(L, ptr, inc, cq, v, z[0], z[1], z[2], 1e-3, False, True, True, buf, np.int64(0), False, -np.inf, -np.inf)
            got = K.node_eval(L, ptr, inc, cq, v, z[0], z[1], z[2], 1e-3, False, True, True, buf, np.int64(0), False, s[10], -np.inf)
            want_ok = full[0] < s[0] and K._acceptable(K.UNTANGLE, full[0], full[10], full[11], s[0], s[10], s[11])
            assert (got[0] < s[0] and K._acceptable(K.UNTANGLE, got[0], got[10], got[11], s[0], s[10], s[11])) == want_ok
            if got[10] == -np.inf:
                cut += 1
            else:
                whole += 1
                assert got[0] == full[0] and got[10] == full[10] and got[11] == full[11]
    assert cut and whole
