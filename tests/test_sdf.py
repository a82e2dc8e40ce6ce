"""Signed distance: sign convention, exact projection, gradient, two-step projection."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import SYNTHETIC_CASES, synthetic_case
from vmesh.chain import FilterChain
from vmesh.errors import InputError
from vmesh.geometry.sdf import SignedDistance, TwoStepSignedDistance, morton_order, vessel_query_points
from vmesh.geometry.topology import boundary_loops
from vmesh.realdata import REAL_CASES

SYNTHETIC = list(SYNTHETIC_CASES)


def icosphere(radius=1.0, level=4):
    """A closed triangulated sphere (subdivided icosahedron), outward oriented."""
    import pymeshlab

    ms = pymeshlab.MeshSet()
    ms.create_sphere(radius=radius, subdiv=level)
    m = ms.current_mesh()
    return m.vertex_matrix().astype(float), m.face_matrix().astype(np.int64)


_PREPARED = {}


def prepared(kind, name, real_path=None):
    """Repaired surface, capped when open (cached across tests)."""
    key = (kind, name)
    if key not in _PREPARED:
        path = real_path(REAL_CASES[name][0]) if kind == "real" else synthetic_case(name)[0]
        if kind == "synthetic" and not path.exists():
            pytest.skip(f"synthetic case {name} not generated yet")
        ctx = FilterChain(["repair_surface"]).run(surface=path)
        if boundary_loops(ctx.surface.faces):
            ctx = FilterChain(["cap_open_ends"]).run(surface=ctx.surface)
        _PREPARED[key] = ctx.surface
    return _PREPARED[key]


def test_sphere_distance_sign_and_gradient():
    v, f = icosphere(2.0)
    sdf = SignedDistance(v, f, name="sphere")
    rng = np.random.default_rng(0)
    p = rng.uniform(-3, 3, (5000, 3))
    closest, d, face = sdf.project(p)
    r = np.linalg.norm(p, axis=1)
    # inscribed polyhedron: distances agree with the sphere's to the chord sagitta
    assert np.all(np.abs(d - (2.0 - r)) < 0.01)
    assert np.all((d > 0) == (r < 2.0 - 0.01)) or np.mean((d > 0) == (r < 2.0)) > 0.999
    far = np.abs(r - 2.0) > 0.02
    assert np.array_equal(d[far] > 0, r[far] < 2.0)
    g = sdf.gradient(p[far])
    assert np.allclose(np.linalg.norm(g, axis=1), 1.0)
    # increasing SDF means towards the centre, everywhere (inside and outside)
    assert np.all(np.einsum("ij,ij->i", g, -p[far] / r[far, None]) > 0.99)
    assert np.allclose(sdf.closest_points(p), closest)
    assert face.dtype == np.int64 and face.min() >= 0 and face.max() < sdf.n_faces
    assert sdf.sign_method == "pseudonormal" and not sdf.flipped


def test_inward_oriented_surface_gets_the_same_signs():
    v, f = icosphere(1.0, 3)
    outward = SignedDistance(v, f)
    inward = SignedDistance(v, f[:, ::-1])
    p = np.random.default_rng(1).uniform(-1.5, 1.5, (3000, 3))
    assert inward.flipped
    assert np.allclose(outward.distance(p), inward.distance(p))
    assert np.allclose(outward.gradient(p), inward.gradient(p))


def test_gradient_on_surface_is_inward_normal():
    v, f = icosphere(1.0, 3)
    sdf = SignedDistance(v, f)
    g = sdf.gradient(v)
    assert np.all(np.einsum("ij,ij->i", g, -v / np.linalg.norm(v, axis=1)[:, None]) > 0.95)


def test_single_point_and_bad_shapes():
    v, f = icosphere(1.0, 2)
    sdf = SignedDistance(v, f)
    assert sdf.distance([0.0, 0.0, 0.0]).shape == (1,)
    assert sdf.distance(np.zeros((0, 3))).shape == (0,)
    with pytest.raises(ValueError):
        sdf.distance(np.zeros((4, 2)))


def test_non_finite_points_give_nan_not_inside():
    v, f = icosphere(1.0, 2)
    sdf = SignedDistance(v, f)
    p = np.array([[np.nan, 0, 0], [0.0, 0, 0], [np.inf, 1, 1], [2.0, 0, 0]])
    closest, d, face = sdf.project(p)
    assert np.isnan(d[[0, 2]]).all() and np.isnan(closest[[0, 2]]).all() and list(face[[0, 2]]) == [-1, -1]
    assert d[1] > 0.9 and d[3] < -0.9 and face[1] >= 0
    assert list(sdf.inside(p)) == [False, True, False, False]
    assert np.isnan(sdf.gradient(p)[0]).all() and np.allclose(np.linalg.norm(sdf.gradient(p)[[1, 3]], axis=1), 1)
    two = TwoStepSignedDistance(sdf, sdf)
    assert np.array_equal(two.distance(p), d, equal_nan=True)


def test_open_surface_needs_winding_number_sign():
    v, f = icosphere(1.0, 2)
    open_f = f[1:]
    with pytest.raises(InputError, match="open"):
        SignedDistance(v, open_f, sign="pseudonormal")
    sdf = SignedDistance(v, open_f)  # auto: winding number
    assert sdf.sign_method == "winding_number"
    assert sdf.distance([[0, 0, 0]])[0] > 0 and sdf.distance([[2, 0, 0]])[0] < 0


def test_empty_surface_is_an_input_error():
    with pytest.raises(InputError, match="no triangles"):
        SignedDistance(np.zeros((3, 3)), np.zeros((0, 3), np.int64), name="empty.stl")


def test_morton_order_is_a_permutation():
    p = np.random.default_rng(2).random((10000, 3))
    order = morton_order(p)
    assert np.array_equal(np.sort(order), np.arange(len(p)))
    # consecutive points in Morton order are much closer than in random order
    step = np.linalg.norm(np.diff(p[order], axis=0), axis=1).mean()
    assert step < 0.25 * np.linalg.norm(np.diff(p, axis=0), axis=1).mean()


def _check_sign_and_projection(surface, n=20000):
    sdf = SignedDistance.from_surface(surface)
    lo, hi = sdf.bounds
    rng = np.random.default_rng(3)
    box = rng.uniform(lo, hi, (n, 3))
    near, _ = vessel_query_points(sdf, n // 2, seed=4)
    p = np.vstack([box, near])
    closest, d, _ = sdf.project(p)
    wn = sdf.winding_number(p)
    decided = np.abs(d) > 1e-9 * sdf.diagonal
    assert np.array_equal((d > 0)[decided], (wn > 0.5)[decided]), f"{surface.name}: sign disagrees with the winding number"
    if sdf.sign_method == "pseudonormal":  # build_sdf's sign check counts crossings instead of asking libigl
        assert np.array_equal((d > 0)[decided], (sdf.ray_winding_number(p) > 0.5)[decided]), f"{surface.name}: sign disagrees with the rays' crossings"
    # projected points lie on the surface
    assert np.abs(sdf.distance(closest)).max() <= 1e-6 * sdf.diagonal
    assert np.allclose(np.abs(d), np.linalg.norm(p - closest, axis=1))


@pytest.mark.parametrize("name", list(REAL_CASES))
@pytest.mark.slow
def test_real_signs_agree_with_winding_number(real_path, name):
    _check_sign_and_projection(prepared("real", name, real_path), n=8000)


@pytest.mark.parametrize("name", SYNTHETIC)
@pytest.mark.slow
def test_synthetic_signs_agree_with_winding_number(name):
    _check_sign_and_projection(prepared("synthetic", name), n=4000)


def test_ray_winding_number_counts_overlapping_closed_pieces():
    """The rays' signed crossings are the winding number of a closed oriented surface: 1
    inside a sphere, 0 outside, 2 where two spheres (one surface of two pieces) overlap, for
    either orientation of the input (flipped to outward first), and libigl's rounded answer
    agrees away from the surface."""
    V, F = icosphere(1.0, 4)
    V2 = np.vstack([V, V + [1.0, 0.0, 0.0]])
    F2 = np.vstack([F, F + len(V)])
    rng = np.random.default_rng(7)
    p = rng.uniform([-1.5, -1.5, -1.5], [2.5, 1.5, 1.5], (4000, 3))
    want = (np.linalg.norm(p, axis=1) < 1.0).astype(int) + (np.linalg.norm(p - [1.0, 0.0, 0.0], axis=1) < 1.0)
    r = np.minimum(np.abs(np.linalg.norm(p, axis=1) - 1.0), np.abs(np.linalg.norm(p - [1.0, 0.0, 0.0], axis=1) - 1.0))
    clear = r > 0.01  # farther from either sphere than the polygon's chords
    for faces in (F2, F2[:, ::-1]):
        sdf = SignedDistance(V2, faces)
        wn = sdf.ray_winding_number(p)
        assert np.array_equal(wn[clear], want[clear])
        assert set(np.unique(wn)) == {0, 1, 2}
    one = SignedDistance(V, F)
    assert np.array_equal(one.ray_winding_number(p) > 0.5, one.winding_number(p) > 0.5)


def test_two_step_projection_lies_on_fine_surface(real_path):
    fine_surface = prepared("real", "coarctation", real_path)
    ctx = FilterChain([("decimate_surface", {"target_faces": 5000, "backend": "fast_simplification"})]).run(surface=fine_surface)
    fine = SignedDistance.from_surface(fine_surface)
    coarse = SignedDistance.from_surface(ctx.coarse_surface)
    two = TwoStepSignedDistance(coarse, fine)
    p, radius = vessel_query_points(fine, 20000, seed=5)
    closest, d, face = two.project(p)
    assert np.abs(fine.distance(closest)).max() <= 1e-6 * fine.diagonal
    _, d_fine, _ = fine.project(p)
    _, d_coarse, _ = coarse.project(p)
    # refining never does worse than the coarse surface, and usually matches the fine one
    assert np.mean(np.abs(d - d_fine) / radius) < 0.5 * np.mean(np.abs(d_coarse - d_fine) / radius)
    assert np.array_equal(d > 0, d_fine > 0) or np.mean((d > 0) == (d_fine > 0)) > 0.999
    g = two.gradient(p[:100])
    assert np.allclose(np.linalg.norm(g, axis=1), 1.0)
    assert two.n_faces == fine.n_faces and two.diagonal == fine.diagonal


def test_build_sdf_filter_variants(real_path):
    surface = prepared("real", "aneurysm", real_path)
    ctx = FilterChain(
        [("decimate_surface", {"target_faces": 3000}), ("build_sdf", {"source": "coarse", "refine_on_fine": True, "check_points": 3000})]
    ).run(surface=surface)
    assert isinstance(ctx.sdf, TwoStepSignedDistance)
    assert ctx.report.sections["sdf"]["sign_disagreements"] == 0
    ctx = FilterChain([("build_sdf", {"source": "fine"})]).run(surface=surface)
    assert isinstance(ctx.sdf, SignedDistance) and ctx.sdf.n_faces == surface.n_faces
    with pytest.raises(InputError, match="decimate_surface"):
        FilterChain([("build_sdf", {"source": "coarse"})]).run(surface=surface)


def test_build_sdf_refuses_open_surface(real_path):
    with pytest.raises(InputError, match="cap_open_ends"):
        FilterChain(["build_sdf"]).run(surface=real_path("aneurysm_ica_aneurisk_c0015_open.vtp"))


def test_measure_sdf_chain_preset(real_path, tmp_path):
    chain = FilterChain.load("sdf_benchmark").with_overrides({"measure_sdf.points": [2000], "decimate_surface.target_faces": 3000, "decimate_surface.max_error": "auto"})
    ctx = chain.run(surface=real_path("aneurysm_ica_aneurisk_c0015_open.vtp"), out_dir=tmp_path / "out")
    import json

    rows = json.loads((tmp_path / "out" / "sdf_coarse_vs_fine.json").read_text())
    keys = {"case", "triangles_fine", "triangles_coarse", "points", "build_s_fine", "build_s_coarse", "qps_fine", "qps_coarse", "speedup", "err_max_rel", "err_mean_rel"}
    assert [r["coarse_level"] for r in rows] == ["3000 faces", "3000 faces, octree", "fine surface, octree"]
    assert all(keys <= set(r) for r in rows)
    assert rows[0]["triangles_coarse"] == 3000 and rows[0]["points"] == 2000 and rows[0]["coarse_index"] == "bvh"
    assert 0 <= rows[0]["err_mean_rel"] <= rows[0]["err_max_rel"] < 0.2
    # the octree answers on the same surface: the same off-surface error, none on the fine one
    assert abs(rows[1]["err_max_rel"] - rows[0]["err_max_rel"]) < 0.01 and rows[2]["err_max_rel"] < 1e-6
    assert len(ctx.caps) == 3




def test_every_signed_distance_is_a_surface_query():
    """The three signed distances answer every member of the SurfaceQuery protocol, with
    ``fine`` the query without a coarse search in front; the surface's cached tree is
    shared with its projectors and its SignedDistance."""
    import typing

    from vmesh.geometry.octree_sdf import OctreeSignedDistance
    from vmesh.geometry.projection import surface_tree, wall_projector
    from vmesh.geometry.surface_query import SurfaceQuery
    from vmesh.surface import SurfaceMesh

    v, f = icosphere(1.0, 3)
    fine_surface = SurfaceMesh(*icosphere(1.0, 4))
    fine = SignedDistance.from_surface(fine_surface)
    coarse = SignedDistance(v, f)
    objects = [fine, TwoStepSignedDistance(coarse, fine), OctreeSignedDistance(coarse)]
    members = {m for m in dir(SurfaceQuery) if not m.startswith("_")} | set(typing.get_type_hints(SurfaceQuery))
    p = np.random.default_rng(0).normal(scale=0.6, size=(50, 3))
    for sdf in objects:
        assert all(hasattr(sdf, m) for m in members), type(sdf).__name__
        assert sdf.fine.n_faces == sdf.n_faces and np.allclose(sdf.distance(p), sdf.project(p)[1])
    assert objects[1].fine is fine and objects[1].coarse is coarse and objects[2].fine is objects[2]
    assert fine._tree is surface_tree(fine_surface) is wall_projector(fine_surface).tree
    assert wall_projector(fine_surface) is wall_projector(fine_surface, [])


def _recording(monkeypatch, cls, name, calls):
    """Wrap ``cls.name`` so that each call appends ``name`` to ``calls``."""
    original = getattr(cls, name)

    def wrapped(self, *args, **kwargs):
        calls.append(name)
        return original(self, *args, **kwargs)

    monkeypatch.setattr(cls, name, wrapped)


@pytest.mark.parametrize("sign, asked", [("pseudonormal", "ray_winding_number"), ("winding_number", "winding_number")])
def test_build_sdf_checks_the_sign_with_rays_or_libigl_as_documented(monkeypatch, sign, asked):
    """build_sdf's sign check counts ray crossings on the pseudonormal sign's (closed,
    oriented) surface and asks libigl's winding number otherwise; both agree on a sphere."""
    from vmesh.surface import SurfaceMesh

    calls = []
    for name in ("ray_winding_number", "winding_number"):
        _recording(monkeypatch, SignedDistance, name, calls)
    ctx = FilterChain([("build_sdf", {"sign": sign, "check_points": 500})]).run(surface=SurfaceMesh(*icosphere(1.0, 3)))
    other = ({"ray_winding_number", "winding_number"} - {asked}).pop()
    assert asked in calls and other not in calls  # (the winding-number sign's distances ask it too)
    assert ctx.report.sections["sdf"]["sign"] == sign and ctx.report.sections["sdf"]["sign_disagreements"] == 0


def test_octree_and_two_step_distances_delegate_the_ray_winding_number(monkeypatch):
    """OctreeSignedDistance asks its exact distance, TwoStepSignedDistance its fine one."""
    from vmesh.geometry.octree_sdf import OctreeSignedDistance

    fine, coarse = SignedDistance(*icosphere(1.0, 4)), SignedDistance(*icosphere(1.0, 2))
    octree, two_step = OctreeSignedDistance(coarse), TwoStepSignedDistance(coarse, fine)
    p = np.random.default_rng(1).uniform(-1.3, 1.3, (300, 3))
    seen = []
    original = SignedDistance.ray_winding_number
    monkeypatch.setattr(SignedDistance, "ray_winding_number", lambda self, q: seen.append(self) or original(self, q))
    assert np.array_equal(octree.ray_winding_number(p), original(coarse, p))
    assert np.array_equal(two_step.ray_winding_number(p), original(fine, p))
    assert seen[0] is coarse and seen[1] is fine


def test_ray_winding_number_through_vertices_and_edge_midpoints():
    """Points whose first ray runs exactly through a vertex or an edge's midpoint of an
    icosphere (a crossing counted twice or not at all by that ray alone): the median over
    the three rays still says inside (1) or outside (0)."""
    from vmesh.geometry.sdf import _WINDING_RAYS

    V, F = icosphere(1.0, 3)
    sdf = SignedDistance(V, F)
    edges = np.unique(np.sort(np.vstack([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1), axis=0)
    targets = np.vstack([V, 0.5 * (V[edges[:, 0]] + V[edges[:, 1]])])
    p = np.vstack([targets - t * d for d in _WINDING_RAYS for t in (0.05, 0.4, 1.2, 2.5)])
    r = np.linalg.norm(p, axis=1)
    inside, outside = r < 0.97, r > 1.0  # the faces lie within [0.99, 1] of the centre at level 3
    assert inside.sum() > 1000 and outside.sum() > 1000
    wn = sdf.ray_winding_number(p)
    assert np.all(wn[inside] == 1) and np.all(wn[outside] == 0)
    # each point's own ray alone miscounts (a vertex's 5-6 triangles or an edge's 2 all count)
    from vmesh.geometry.ray_crossings import crossings

    n = 4 * len(targets)
    own = np.concatenate([crossings(sdf._tree, p[i * n:(i + 1) * n], np.broadcast_to(d, (n, 3))) for i, d in enumerate(_WINDING_RAYS)])
    clear = inside | outside
    assert np.mean(own[clear] != inside[clear]) > 0.5
