"""The max-min pass after the light pass (vmesh.geometry.optimize.worst, mesh_transfinite's
``worst_pass_sweeps``): it lifts the worst elements the monotone light pass leaves."""

import types

import numpy as np
import pytest

from test_optimize import check_boundary, cylinder, first_layer_nodes
from vmesh.geometry.optimize import _node_kinds, optimise
from vmesh.geometry.optimize.worst import lift_worst
from vmesh.geometry.quality import hex8_scaled_jacobian


def _kinds(sm, kw):
    return _node_kinds(sm.cells, len(sm.points), kw["wall"], kw["project"], kw["wall_normals"], kw["cap_nodes"], kw["cap_normals"], kw["boundary"], True)


@pytest.fixture(scope="module")
def light_passed():
    """The O-grid cylinder (radius 2) with its interior nodes jittered by 0.05, after the
    light pass alone."""
    sm, kw = cylinder()
    X0 = sm.points.copy()
    inner = ~kw["boundary"]
    X0[inner] += np.random.default_rng(3).normal(size=(inner.sum(), 3)) * 0.05
    X1, _ = optimise(X0, sm.cells, 1, untangle_below=0.0, smooth_below=0.95, **kw)
    return sm, kw, X1


def test_worst_pass_lifts_what_the_light_pass_leaves(light_passed):
    """The light pass leaves the jittered cylinder's worst elements at 0.41 (0.36 before its
    over-relaxed steps; a step that lifts the worst element but lowers the node's sum of
    qualities is refused, and its climb follows one corner); the max-min pass lifts them past
    0.45 (0.52) at no cost to the mean, walls
    and cap planes kept, the first boundary-layer height kept."""
    sm, kw, X1 = light_passed
    q1 = hex8_scaled_jacobian(X1, sm.cells)
    assert 0 < q1.min() < 0.43
    kind, normal, height = _kinds(sm, kw)
    X2 = X1.copy()
    moved, _ = lift_worst(X2, sm.cells, 0.5, kind, normal, height, kw["project"], kw["wall_normals"], sweeps=20)
    q2 = hex8_scaled_jacobian(X2, sm.cells)
    assert moved > 0 and q2.min() > 0.45 and q2.mean() > q1.mean() - 1e-3
    check_boundary(sm, kw, X1, X2)
    top = first_layer_nodes(sm) & ~kw["cap_nodes"]  # cap nodes slide in their plane (no height kept there)
    assert np.abs(np.linalg.norm(X2[top, :2], axis=1) - np.linalg.norm(X1[top, :2], axis=1)).max() < 1e-9


def test_worst_pass_never_lowers_the_minimum_and_leaves_inverted_meshes_alone(light_passed):
    sm, kw, X1 = light_passed
    kind, normal, height = _kinds(sm, kw)
    q1 = hex8_scaled_jacobian(X1, sm.cells).min()
    X2 = X1.copy()
    lift_worst(X2, sm.cells, 0.9, kind, normal, height, kw["project"], kw["wall_normals"], sweeps=3)
    assert hex8_scaled_jacobian(X2, sm.cells).min() >= q1
    check_boundary(sm, kw, X1, X2)
    X0 = X1.copy()
    inner = ~kw["boundary"]
    X0[inner] += np.random.default_rng(4).normal(size=(inner.sum(), 3)) * 0.12
    assert hex8_scaled_jacobian(X0, sm.cells).min() < 0
    X = X0.copy()
    assert lift_worst(X, sm.cells, 0.5, kind, normal, height, kw["project"], kw["wall_normals"]) == (0, 0)
    assert np.array_equal(X, X0)


@pytest.mark.slow
def test_worst_pass_lifts_a_trifurcation_crotch():
    """The generated trifurcation (60 degrees, daughters half the parent's radius) fills
    validly but poorly at its crotch; the light pass alone leaves its minimum below 0.2.
    ``mesh_transfinite``'s worst pass and the light pass after it lift the minimum by more
    than 0.1 without lowering the mean; wall nodes stay on the wall, first-layer nodes at
    their height above it, rims fixed."""
    from junction_cases import trifurcation
    from test_junctions import DEFAULT

    from vmesh.filters.mesh_filters import _constraints, _light_pass, _worst_pass
    from vmesh.geometry.blocks import BlockOptions, build_blocks
    from vmesh.geometry.optimize import kernels as K
    from vmesh.geometry.transfinite import mesh_blocks

    case = trifurcation(60, 2)
    blocks = build_blocks(case.skeleton, case.distance, None, BlockOptions(), project=case.project)
    sm = mesh_blocks(blocks, case.project, DEFAULT, signed_distance=case.distance)
    assert hex8_scaled_jacobian(sm.points, sm.cells).min() > 0
    ctx = types.SimpleNamespace(tick=lambda *a, **k: None, count=lambda **k: None, report=types.SimpleNamespace(sections={}))
    sdf = types.SimpleNamespace(gradient=case.gradient)
    _light_pass(ctx, sm, case.project, sdf, 0.95, "gauss_lobatto")
    q1 = hex8_scaled_jacobian(sm.points, sm.cells)
    assert q1.min() < 0.2
    X1 = sm.points.copy()
    cap_nodes, cap_normals, wall, boundary = _constraints(sm)
    kind, _, _ = _node_kinds(sm.cells, len(X1), wall, case.project, case.gradient, cap_nodes, cap_normals, boundary, True)
    assert _worst_pass(ctx, sm, case.project, sdf, 0.5, 20)
    X2 = sm.points.copy()
    _light_pass(ctx, sm, case.project, sdf, 0.95, "gauss_lobatto")
    q2 = hex8_scaled_jacobian(sm.points, sm.cells)
    assert q2.min() > q1.min() + 0.1 and q2.mean() >= q1.mean() - 1e-3
    moved = np.any(sm.points != X1, axis=1)
    assert np.abs(case.distance(sm.points[moved & sm.on_wall])).max(initial=0.0) < 1e-6
    assert np.array_equal(sm.points[kind == K.FIXED], X1[kind == K.FIXED])
    # the worst pass keeps each first-layer node's height above the wall
    top = np.flatnonzero((kind == K.OFFSET) & np.any(X2 != X1, axis=1))
    assert len(top)
    h1 = np.linalg.norm(X1[top] - case.project(X1[top]), axis=1)
    h2 = np.linalg.norm(X2[top] - case.project(X2[top]), axis=1)
    np.testing.assert_allclose(h2, h1, rtol=0, atol=1e-7)  # the projection's tolerance


def test_mesh_transfinite_reports_the_worst_pass():
    """The straight tube at a coarse length with ``smooth_below`` 0.95 (so its O-grid's
    corners, about 0.8, are below it): the worst pass runs between the two light passes and
    each reports its own section and count; with ``worst_pass_sweeps`` 0, or with the light
    pass off (nothing would restore the mean), it does not run."""
    import copy

    import vmesh
    from conftest import synthetic_case
    from vmesh.context import Context
    from vmesh.io.skeleton import read_skeleton
    from vmesh.io.surface import read_surface
    from vmesh.registry import get_filter

    surface, skeleton = synthetic_case("straight_tube")
    chain = vmesh.FilterChain.load("default")
    names = [s.filter for s in chain.steps]
    step = chain.steps[names.index("mesh_transfinite")]
    chain.steps = chain.steps[: names.index("mesh_transfinite")]
    ctx0 = Context()
    chain.run(surface=read_surface(surface), skeleton=read_skeleton(skeleton), out_dir=None, context=ctx0)

    def run(**kw):
        ctx = copy.deepcopy(ctx0)
        get_filter("mesh_transfinite")(ctx, **{**step.params, "element_length": 1.0, "smooth_below": 0.95, "worst_pass_sweeps": 2, **kw})
        return ctx.report

    report = run()
    assert {"light_pass", "worst_pass", "light_pass_after_worst"} <= set(report.sections)
    assert report.sections["worst_pass"]["moved"] > 0 and report.sections["worst_pass"]["after"]["min"] > report.sections["worst_pass"]["before"]["min"]
    assert report.counts["worst_pass_nodes"] == report.sections["worst_pass"]["moved"]
    assert report.counts["light_pass_nodes"] == report.sections["light_pass"]["smoothed_nodes"]
    assert report.counts["light_pass_after_worst_nodes"] == report.sections["light_pass_after_worst"]["smoothed_nodes"]
    for kw in ({"worst_pass_sweeps": 0}, {"light_pass_below": 0.0}):
        report = run(**kw)
        assert "worst_pass" not in report.sections and "light_pass_after_worst" not in report.sections


def _node_corners_bruteforce(X, hexes, v):
    """Scaled Jacobians of node ``v``'s corners (the corners of its hexahedra whose three
    edges it is an end of), straight from the definition."""
    out = []
    for e in np.flatnonzero((hexes == v).any(axis=1)):
        loc = int(np.flatnonzero(hexes[e] == v)[0])
        for c in range(8):
            if bin(c ^ loc).count("1") > 1:
                continue
            i, j, k = c & 1, (c >> 1) & 1, (c >> 2) & 1
            P = X[hexes[e]]
            u, w_, t = P[2 * j + 4 * k + 1] - P[2 * j + 4 * k], P[i + 2 + 4 * k] - P[i + 4 * k], P[i + 2 * j + 4] - P[i + 2 * j]
            out.append(np.dot(u, np.cross(w_, t)) / (np.linalg.norm(u) * np.linalg.norm(w_) * np.linalg.norm(t)))
    return np.sort(out)


def _jittered_block():
    """A jittered 3x3x3 block of unit cubes: lattice points, nodes, hexahedra, incidence and
    five nodes to test (a corner, edge, face and interior nodes)."""
    from vmesh.geometry.optimize import kernels as K

    g = np.stack(np.meshgrid(*[np.arange(4.0)] * 3, indexing="ij"), -1).transpose(2, 1, 0, 3).reshape(-1, 3)
    X = g + np.random.default_rng(5).normal(size=g.shape) * 0.12
    ids = np.arange(64).reshape(4, 4, 4)  # [k, j, i]
    hexes = np.array([[ids[k + (c >> 2), j + ((c >> 1) & 1), i + (c & 1)] for c in range(8)]
                      for k in range(3) for j in range(3) for i in range(3)], np.int64)
    ptr, inc = K.incidence(hexes, len(X))
    return g, X, hexes, ptr, inc, np.array([0, 5, 21, 42, 63], np.int64)


def test_worst_pass_kernels_match_the_definition():
    """The compiled corner kernels of the max-min pass on a jittered 3x3x3 block of cubes:
    each node's three worst corners and its longest/shortest edge, the gradients (against
    central differences) and the trial minima (against the corners recomputed with the node
    moved)."""
    from vmesh.geometry.optimize.kernels_worst import trial_minima, worst_corners

    g, X, hexes, ptr, inc, nodes = _jittered_block()
    q, G, longest, shortest = worst_corners(X, hexes, ptr, inc, nodes)
    for a, v in enumerate(nodes):
        ref = _node_corners_bruteforce(X, hexes, v)
        np.testing.assert_allclose(q[a, : min(3, len(ref))], ref[:3], atol=1e-12)
        edges = [np.linalg.norm(X[w] - X[v]) for w in np.unique(hexes[(hexes == v).any(axis=1)]) if
                 np.isclose(np.abs(g[w] - g[v]).sum(), 1)]
        assert np.isclose(longest[a], max(edges)) and np.isclose(shortest[a], min(edges))
        for r in range(min(3, len(ref))):  # each worst corner's gradient, by central differences
            fd = np.zeros(3)
            for d in range(3):
                Y = X.copy()
                Y[v, d] += 1e-6
                up = worst_corners(Y, hexes, ptr, inc, nodes[a : a + 1])[0][0]
                Y[v, d] -= 2e-6
                down = worst_corners(Y, hexes, ptr, inc, nodes[a : a + 1])[0][0]
                fd[d] = (up[r] - down[r]) / 2e-6
            np.testing.assert_allclose(G[a, r], fd, atol=1e-5)
    T = X[nodes][:, None] + np.random.default_rng(6).normal(size=(len(nodes), 4, 3)) * 0.2
    qt = trial_minima(X, hexes, ptr, inc, nodes, np.ascontiguousarray(T))
    for a, v in enumerate(nodes):
        for t in range(4):
            Y = X.copy()
            Y[v] = T[a, t]
            assert np.isclose(qt[a, t], _node_corners_bruteforce(Y, hexes, v)[0], atol=1e-12)


@pytest.mark.slow
def test_worst_pass_parallel_kernels_match_the_serial_ones():
    """The parallel variants (for large colours) give the serial ones' answers bit for bit,
    and a NaN trial is no candidate (-inf). Slow: it compiles the parallel variants where
    ``vmesh compile`` has not."""
    from vmesh.geometry.optimize import kernels_worst as W

    _, X, hexes, ptr, inc, nodes = _jittered_block()
    for a, b in zip(W._worst_corners_parallel(X, hexes, ptr, inc, nodes), W._worst_corners_serial(X, hexes, ptr, inc, nodes)):
        np.testing.assert_array_equal(a, b)
    T = X[nodes][:, None] + np.random.default_rng(6).normal(size=(len(nodes), 4, 3)) * 0.2
    T[2, 1] = np.nan
    qp = W._trial_minima_parallel(X, hexes, ptr, inc, nodes, T, -np.inf)
    np.testing.assert_array_equal(qp, W._trial_minima_serial(X, hexes, ptr, inc, nodes, T, -np.inf))
    assert qp[2, 1] == -np.inf and np.isfinite(np.delete(qp.ravel(), 2 * 4 + 1)).all()
    for a, b in zip(W._ratio_rows_parallel(X, hexes, ptr, inc, nodes, 0.3), W._ratio_rows_serial(X, hexes, ptr, inc, nodes, 0.3)):
        np.testing.assert_array_equal(a, b)
