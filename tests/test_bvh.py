"""The closest-point engine: exact against libigl's AABB tree, features, sorting, soups."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import synthetic_case
from vmesh.chain import FilterChain
from vmesh.geometry.bvh import TriangleBVH, morton_order
from vmesh.io.surface import read_surface


def _igl_closest(v, f, p):
    import igl

    tree = igl.AABB()
    tree.init(v, f)
    sq, face, closest = tree.squared_distance(v, f, p)
    return np.asarray(sq), np.asarray(face), np.asarray(closest)


@pytest.mark.parametrize("name", ["y_bifurcation", "cerebral_tree"])
def test_bvh_matches_igl_on_synthetic_surfaces(name):
    path = synthetic_case(name)[0]
    if not path.exists():
        pytest.skip(f"synthetic case {name} not generated")
    s = read_surface(path)
    v, f = s.vertices, s.faces
    rng = np.random.default_rng(0)
    lo, hi = v.min(axis=0), v.max(axis=0)
    # points in the box and points just off the surface (where features matter)
    near = v[rng.integers(0, len(v), 20_000)] + rng.normal(scale=1e-3 * np.linalg.norm(hi - lo), size=(20_000, 3))
    p = np.concatenate([lo + rng.random((20_000, 3)) * (hi - lo), near, v[:500]])
    sq, face, closest, feature = TriangleBVH(v, f).closest(p)
    sq0, _, _ = _igl_closest(v, f, p)
    scale = np.linalg.norm(hi - lo)
    assert np.abs(np.sqrt(sq) - np.sqrt(sq0)).max() <= 1e-12 * scale
    assert np.allclose(np.einsum("ij,ij->i", p - closest, p - closest), sq, atol=1e-12 * scale**2)
    # the closest point lies on the reported face, at the reported feature
    tri = v[f[face]]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    assert np.abs(np.einsum("ij,ij->i", closest - tri[:, 0], n)).max() <= 1e-9 * scale
    corner = feature >= 4
    k = feature[corner] - 4
    assert np.allclose(closest[corner], tri[corner, k], atol=1e-12 * scale)
    assert set(np.unique(feature)) <= set(range(7))


def test_bvh_sorted_and_unsorted_queries_agree_and_soups_work():
    rng = np.random.default_rng(1)
    tri = rng.random((300, 3, 3))  # a soup of random triangles, some nearly degenerate
    tri[:10, 2] = tri[:10, 0] + 1e-14
    v, f = tri.reshape(-1, 3), np.arange(900).reshape(300, 3)
    p = rng.random((5000, 3)) * 1.5 - 0.25
    bvh = TriangleBVH(v, f)
    a = bvh.closest(p, sort=True)
    b = bvh.closest(p, sort=False)
    assert np.allclose(a[0], b[0], rtol=0, atol=1e-15)
    sq0, _, _ = _igl_closest(v, f, p)
    assert np.allclose(a[0], sq0, rtol=1e-12, atol=1e-15)
    assert len(bvh.closest(np.zeros((0, 3)))[0]) == 0
    one = TriangleBVH(v[:3], f[:1]).closest(p[:5])
    assert np.all(one[1] == 0)


def test_morton_order_is_a_permutation_that_groups_neighbours():
    rng = np.random.default_rng(2)
    p = rng.random((10_000, 3))
    order = morton_order(p)
    assert np.array_equal(np.sort(order), np.arange(len(p)))
    step = np.linalg.norm(np.diff(p[order], axis=0), axis=1).mean()
    assert step < 0.25 * np.linalg.norm(np.diff(p, axis=0), axis=1).mean()


@pytest.mark.slow
def test_decimation_to_tolerance_reaches_it(real_path):
    """decimate_surface max_error: every fine vertex within the tolerance of the coarse surface."""
    from vmesh.preprocess import wall_radius_deviation

    surface = read_surface(real_path("thoracic_aorta_open.vtp"))
    ctx = FilterChain(["repair_surface", "cap_open_ends", ("decimate_surface", {"backend": "fast_simplification", "target_faces": 20000, "max_error": 0.015})]).run(surface=surface)
    tries = ctx.report.sections["decimation"]["tries"]
    assert tries[0]["faces"] == 20000 and tries[0]["max_error_rel"] > 0.015  # 20k faces are not enough here
    assert tries[-1]["max_error_rel"] <= 0.015
    fine, coarse = ctx.surface, ctx.coarse_surface
    assert coarse.n_faces == tries[-1]["faces"] < fine.n_faces
    wall = np.asarray(fine.face_data["cap_id"]) == 0
    assert wall_radius_deviation(fine.vertices, fine.faces, coarse.vertices, coarse.faces, wall).max() <= 0.015


def _brute_force_lines(v, f, o, d, reach):
    """Nearest two-sided line crossing by testing every triangle (Möller–Trumbore in numpy).

    Only the (line, triangle) pairs whose bounding boxes overlap are solved: a crossing within
    ``reach`` lies in both boxes, so the others cannot cross. The full (lines, triangles, 3)
    temporaries of every pair cost ~6 s CPU for 2000 lines on 10,000 triangles."""
    tri = v[f]
    lo_t, hi_t = tri.min(axis=1), tri.max(axis=1)
    pad = 1e-9 * np.abs(v).max()  # boxes touching within rounding still count
    lo_l, hi_l = np.minimum(o - reach[:, None] * d, o + reach[:, None] * d) - pad, np.maximum(o - reach[:, None] * d, o + reach[:, None] * d) + pad
    overlap = np.ones((len(o), len(f)), bool)
    for k in range(3):
        overlap &= (lo_l[:, None, k] <= hi_t[None, :, k]) & (hi_l[:, None, k] >= lo_t[None, :, k])
    line, face = np.nonzero(overlap)
    a, e1, e2 = tri[face, 0], tri[face, 1] - tri[face, 0], tri[face, 2] - tri[face, 0]
    dl = d[line]
    p = np.cross(dl, e2)
    det = np.einsum("ik,ik->i", e1, p)
    s = o[line] - a
    u = np.einsum("ik,ik->i", s, p) / det
    q = np.cross(s, e1)
    w = np.einsum("ik,ik->i", dl, q) / det
    t = np.einsum("ik,ik->i", e2, q) / det
    ok = (u >= 0) & (u <= 1) & (w >= 0) & (u + w <= 1) & (np.abs(t) <= reach[line])
    out = np.full((len(o), len(f)), np.nan)
    out[line[ok], face[ok]] = t[ok]
    return out


@pytest.mark.slow
def test_line_crossings_match_brute_force_both_and_one_sided():
    """intersect_lines: the crossing nearest to the origin within reach, both sides or one."""
    path = synthetic_case("y_bifurcation")[0]
    if not path.exists():
        pytest.skip("synthetic case y_bifurcation not generated")
    s = read_surface(path)
    v, f = s.vertices, s.faces
    rng = np.random.default_rng(3)
    n = 2000
    o = v[rng.integers(0, len(v), n)] + rng.normal(scale=0.3, size=(n, 3))
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    reach = rng.uniform(0.1, 3.0, n)
    all_t = _brute_force_lines(v, f, o, d, reach)
    bvh = TriangleBVH(v, f)
    for side in (0, 1, -1):
        cand = all_t if side == 0 else np.where(all_t * side >= 0, all_t, np.nan)
        has = ~np.isnan(cand).all(axis=1)
        ref = np.full(n, np.nan)
        ref[has] = np.abs(cand[has][np.arange(has.sum()), np.nanargmin(np.abs(cand[has]), axis=1)])
        t, face = bvh.intersect_lines(o, d, reach, side=None if side == 0 else np.full(n, side))
        assert np.array_equal(np.isnan(t), ~has) and np.array_equal(face < 0, ~has)
        assert np.abs(np.abs(t[has]) - ref[has]).max() < 1e-12
        if side:
            assert np.all(t[has] * side >= 0)
        # the crossing lies on the reported triangle's plane
        x = o[has] + t[has, None] * d[has]
        tri = v[f[face[has]]]
        nrm = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        assert np.abs(np.einsum("ij,ij->i", x - tri[:, 0], nrm)).max() < 1e-9 * np.abs(nrm).max()


def test_tree_boxes_contain_their_triangles():
    """The median-split order is a permutation and every node's box holds its subtree."""
    rng = np.random.default_rng(4)
    tri = rng.random((1001, 3, 3))
    v, f = tri.reshape(-1, 3), np.arange(3003).reshape(1001, 3)
    bvh = TriangleBVH(v, f)
    assert np.array_equal(np.sort(bvh.order), np.arange(1001))
    t = tri[bvh.order]
    first = bvh._first_leaf
    for leaf in range(-(-1001 // bvh.leaf_size)):
        node = first + leaf
        pts = t[leaf * bvh.leaf_size : (leaf + 1) * bvh.leaf_size].reshape(-1, 3)
        while True:
            assert np.all(bvh._lo[node] <= pts.min(axis=0)) and np.all(bvh._hi[node] >= pts.max(axis=0))
            if node == 0:
                break
            node = (node - 1) // 2


def test_node_slabs_enclose_their_triangles_and_bound_the_distance():
    """Every node's slab (mean-normal planes) holds its triangles' corners, so the node bound
    (the larger of box and slab distance) never exceeds the distance to any of its triangles."""
    path = synthetic_case("y_bifurcation")[0]
    if not path.exists():
        pytest.skip("synthetic case y_bifurcation not generated")
    s = read_surface(path)
    bvh = TriangleBVH(s.vertices, s.faces)
    t = s.vertices[s.faces[bvh.order]]  # (m, 3, 3) in slot order
    nodes = bvh._nodes
    normal, smin, smax = nodes[:, 6:9], nodes[:, 9], nodes[:, 10]
    finite = np.isfinite(smin)
    n_leaves = -(-len(t) // bvh.leaf_size)
    assert finite[bvh._first_leaf : bvh._first_leaf + n_leaves].mean() > 0.9  # wall patches: nearly all get a slab
    assert np.allclose(np.linalg.norm(normal[finite], axis=1), 1.0)
    rng = np.random.default_rng(5)
    lo, hi = s.vertices.min(axis=0), s.vertices.max(axis=0)
    p = lo + rng.random((64, 3)) * (hi - lo)
    m, size, depth = len(t), bvh.leaf_size, bvh.depth
    for level in range(depth + 1):
        span = (1 << (depth - level)) * size
        for k in range(0, 1 << level, max(1, (1 << level) // 16)):  # a sample of each level
            node = (1 << level) - 1 + k
            corners = t[k * span : min((k + 1) * span, m)].reshape(-1, 3)
            if len(corners) == 0 or not finite[node]:
                continue
            off = corners @ normal[node]
            assert off.min() >= smin[node] - 1e-12 and off.max() <= smax[node] + 1e-12
            # the slab gap is a lower bound of every corner's (hence every point's) distance
            s_p = p @ normal[node]
            gap = np.maximum(np.maximum(smin[node] - s_p, s_p - smax[node]), 0.0)
            tri_sq = TriangleBVH(corners, np.arange(len(corners)).reshape(-1, 3)).closest(p)[0]
            assert np.all(gap**2 <= tri_sq + 1e-12)


def test_radix_morton_order_matches_argsort_of_the_codes():
    from vmesh.geometry.bvh import morton_codes

    rng = np.random.default_rng(6)
    p = rng.normal(size=(50_000, 3))
    p[:100] = p[0]  # ties keep their input order (stable)
    codes = morton_codes(p, bits=10)
    assert np.array_equal(morton_order(p, bits=10), np.argsort(codes, kind="stable"))


def test_serial_and_parallel_kernels_agree(monkeypatch):
    """Small batches run the serial twins of the query kernels: same results as the parallel ones."""
    from vmesh.geometry import bvh as bvh_module
    from vmesh.geometry.sdf import SignedDistance

    path = synthetic_case("y_bifurcation")[0]
    if not path.exists():
        pytest.skip("synthetic case y_bifurcation not generated")
    s = read_surface(path)
    rng = np.random.default_rng(5)
    lo, hi = s.vertices.min(axis=0), s.vertices.max(axis=0)
    p = lo + rng.random((3000, 3)) * (hi - lo)
    d = rng.normal(size=(3000, 3))
    sdf = SignedDistance.from_surface(s)
    runs = []
    for threshold in (10**9, 1):  # everything serial, then everything parallel
        monkeypatch.setattr(bvh_module, "PARALLEL_MIN", threshold)
        closest, signed, _ = sdf.project(p)
        t, _ = sdf._tree.intersect_lines(p, d, 5.0)
        runs.append((closest, signed, t, bvh_module.morton_codes(p)))
    for serial, parallel in zip(*runs):
        assert np.array_equal(serial, parallel, equal_nan=True)
