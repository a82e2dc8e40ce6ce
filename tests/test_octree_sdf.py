"""Octree index of the signed distance: answers on the surface, signs and distances as the
exact query's (to the checked tolerance), serial and parallel alike, filter wiring."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import synthetic_case
from test_sdf import icosphere, prepared
from vmesh.chain import FilterChain
from vmesh.geometry.octree_sdf import OctreeSignedDistance, surface_adjacency
from vmesh.geometry.sdf import SignedDistance, TwoStepSignedDistance, vessel_query_points


def _compare(exact, tree, p, radius, tol):
    c0, d0, _ = exact.project(p)
    c1, d1, f1 = tree.project(p)
    # every answer is a point of the surface
    assert np.abs(exact.distance(c1)).max() <= 1e-9 * exact.diagonal
    assert np.allclose(np.abs(d1), np.linalg.norm(p - c1, axis=1))
    # a wrong triangle can only make the distance longer, by a bounded amount
    err = np.abs(d1) - np.abs(d0)
    assert err.min() >= -1e-9 * exact.diagonal
    assert np.max(err / radius) <= tol
    assert np.median(err) <= 1e-12 * exact.diagonal  # most answers are the exact ones
    clear = np.abs(d0) > 1e-6 * exact.diagonal
    assert np.array_equal(d1[clear] > 0, d0[clear] > 0)
    return err


@pytest.mark.slow
def test_sphere_octree_matches_exact():
    v, f = icosphere(2.0, level=5)
    exact = SignedDistance(v, f, name="sphere")
    tree = OctreeSignedDistance(exact)
    assert tree.n_leaves > 0 and tree.n_faces == exact.n_faces and tree.diagonal == exact.diagonal
    rng = np.random.default_rng(1)
    p = rng.uniform(-2.8, 2.8, (50_000, 3))
    _compare(exact, tree, p, 2.0, 0.01)
    g = tree.gradient(p[:2000])
    assert np.allclose(np.linalg.norm(g, axis=1), 1.0)
    assert np.array_equal(tree.inside(p[:2000]), exact.inside(p[:2000]))


@pytest.mark.slow
def test_vessel_octree_distances_within_tolerance():
    surface = prepared("synthetic", "y_bifurcation")
    exact = SignedDistance.from_surface(surface)
    tree = OctreeSignedDistance(exact, max_error=0.002)
    p, radius = vessel_query_points(exact, 60_000, seed=3)
    err = _compare(exact, tree, p, radius, 0.02)
    assert np.mean(err / radius) < 1e-4
    assert "leaves" in repr(tree)


def test_real_octree_signs_inward_oriented_case(real_path):
    # the AneuRisk surface comes with inward normals: signs must still agree
    surface = prepared("real", "aneurysm", real_path)
    exact = SignedDistance.from_surface(surface)
    tree = OctreeSignedDistance(exact)
    p, radius = vessel_query_points(exact, 40_000, seed=4)
    _compare(exact, tree, p, radius, 0.04)


def test_serial_and_parallel_batches_agree_and_odd_points():
    surface = prepared("synthetic", "straight_tube")
    exact = SignedDistance.from_surface(surface)
    tree = OctreeSignedDistance(exact)
    p, _ = vessel_query_points(exact, 20_000, seed=2)
    big = tree.project(p)  # parallel kernels, Morton order
    small = [tree.project(p[i : i + 500]) for i in range(0, 2000, 500)]  # serial kernels
    # the same answers (up to rounding: a point on an edge may report either face)
    for k in range(2):
        assert np.allclose(big[k][:2000], np.concatenate([s[k] for s in small]), rtol=0, atol=1e-12 * exact.diagonal)
    assert np.mean(big[2][:2000] == np.concatenate([s[2] for s in small])) > 0.99
    # outside the octree (and in its exact leaves) the BVH answers
    far = exact.bounds[1] + 5 * exact.diagonal
    q = np.array([far, -far, [np.nan, 0, 0]])
    c, d, f = tree.project(q)
    c0, d0, f0 = exact.project(q)
    assert np.allclose(d[:2], d0[:2]) and np.array_equal(f[:2], f0[:2])
    assert np.isnan(d[2]) and f[2] == -1 and not tree.inside(q[2:])[0]


@pytest.mark.slow
def test_octree_under_two_step_and_line_casts():
    surface = prepared("synthetic", "y_bifurcation")
    ctx = FilterChain([("decimate_surface", {"target_faces": 3000}), ("build_sdf", {"source": "coarse", "refine_on_fine": True, "index": "octree"})]).run(surface=surface)
    assert isinstance(ctx.sdf, TwoStepSignedDistance) and isinstance(ctx.sdf.coarse, OctreeSignedDistance)
    info = ctx.report.sections["sdf"]
    assert info["index"] == "octree" and info["octree_leaves"] > 0 and info["sign_disagreements"] == 0
    fine = SignedDistance.from_surface(surface)
    p, _ = vessel_query_points(fine, 5000, seed=1)
    closest, _, _ = ctx.sdf.project(p)
    assert np.abs(fine.distance(closest)).max() <= 1e-6 * fine.diagonal
    ctx = FilterChain([("build_sdf", {"index": "octree", "octree_error": 0.005})]).run(surface=surface)
    tree = ctx.sdf
    assert isinstance(tree, OctreeSignedDistance) and tree.max_error == 0.005
    moved, hit = tree.intersect_lines(p[:100], np.tile([1.0, 0, 0], (100, 1)), 100.0)
    assert hit.any() and np.abs(fine.distance(moved[hit])).max() <= 1e-6 * fine.diagonal


def test_bad_arguments():
    surface = synthetic_case("straight_tube")[0]
    exact = SignedDistance.from_surface(FilterChain(["repair_surface"]).run(surface=surface).surface)
    with pytest.raises(TypeError, match="SignedDistance"):
        OctreeSignedDistance(TwoStepSignedDistance(exact, exact))
    with pytest.raises(ValueError, match="max_error"):
        OctreeSignedDistance(exact, max_error=0)
    with pytest.raises(ValueError, match="face_radius"):
        OctreeSignedDistance(exact, face_radius=np.ones(3))


def test_surface_adjacency_of_a_closed_surface():
    v, f = icosphere(1.0, level=2)
    nb, ptr, faces_of = surface_adjacency(f, len(v))
    assert (nb >= 0).all()
    # the neighbour across local edge k shares its two corners
    for t in range(0, len(f), 7):
        for k in range(3):
            assert {f[t, k], f[t, (k + 1) % 3]} <= set(f[nb[t, k]])
    assert ptr[-1] == 3 * len(f)
    for vert in range(0, len(v), 5):
        assert all(vert in f[t] for t in faces_of[ptr[vert] : ptr[vert + 1]])
