"""The procedural vessel generator: reproducible, true skeletons, surfaces as declared,
features at their rates, files that vmesh reads back."""

from __future__ import annotations

import numpy as np
import pytest

from data_synthetic import vessel_generator as G
from data_synthetic.generate import _components, _edges, signed_volume
from data_synthetic.vessels import tree as T

igl = pytest.importorskip("igl")

#: Small vessels: two generations, coarse grid, few faces (each a second or two).
SMALL = {"morphology": {"generations": (2, 2)}, "grid_per_radius": 2.2, "max_voxels": 1.5e6, "target_faces": (3000, 12000)}
NONE = {f: 0.0 for f in G.FEATURES}


def small(seed, preset="clean", **kw):
    return G.generate_vessel(seed, preset, **{**SMALL, **kw})


def nudged_nodes(v) -> np.ndarray:
    """Skeleton nodes, end nodes moved 10 % of their radius into the vessel (they lie on a cap)."""
    X = v.xyz.copy()
    nbr = {}
    for a, b in v.edges.tolist():
        nbr.setdefault(a, []).append(b)
        nbr.setdefault(b, []).append(a)
    for i, n in nbr.items():
        if len(n) == 1:
            X[i] += 0.1 * v.radius[i] * T.unit(X[n[0]] - X[i])
    return X


def boundary_loops(F) -> int:
    e, c = _edges(F)
    b = e[c == 1]
    if not len(b):
        return 0
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    ids, inv = np.unique(b, return_inverse=True)
    inv = inv.reshape(-1, 2)
    A = coo_matrix((np.ones(len(inv)), (inv[:, 0], inv[:, 1])), shape=(len(ids), len(ids)))
    return int(connected_components(A, directed=False)[0])


@pytest.mark.slow
def test_same_seed_same_vessel_and_units_scale_only():
    a, b = small(11, "rough"), small(11, "rough")
    assert np.array_equal(a.vertices, b.vertices) and np.array_equal(a.faces, b.faces)
    assert np.array_equal(a.xyz, b.xyz) and np.array_equal(a.edges, b.edges) and a.tags == b.tags
    assert {k: v for k, v in a.manifest.items() if k != "seconds"} == {k: v for k, v in b.manifest.items() if k != "seconds"}
    c = small(12, "rough")
    assert c.xyz.shape != a.xyz.shape or not np.allclose(c.xyz, a.xyz)
    mm, cm = small(5, units="mm"), small(5, units="cm")
    np.testing.assert_allclose(cm.xyz, 0.1 * mm.xyz)
    np.testing.assert_allclose(cm.radius, 0.1 * mm.radius)
    np.testing.assert_allclose(cm.vertices, 0.1 * mm.vertices)


@pytest.mark.parametrize("seed,end_style", [(1, "flat"), (2, "round"), pytest.param(3, "flat", marks=pytest.mark.slow),
                                             pytest.param(4, "round", marks=pytest.mark.slow)])
def test_closed_vessel_is_watertight_outward_and_holds_its_skeleton(seed, end_style):
    v = small(seed, end_style=end_style)
    V, F = v.vertices, v.faces
    _, counts = _edges(F)
    assert np.all(counts == 2), "boundary or non-manifold edges"
    directed = F[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    assert len(np.unique(directed, axis=0)) == len(directed), "inconsistent orientation"
    assert signed_volume(V, F) > 0
    assert len(np.unique(_components(len(V), F))) == 1
    assert v.manifest["closed"] and v.manifest["outward"]
    w = igl.fast_winding_number(V, F.astype(np.int64), nudged_nodes(v))
    assert np.all(w > 0.5), f"{np.sum(w <= 0.5)} skeleton nodes outside the surface"


@pytest.mark.parametrize("seed", [1, 6])
def test_radii_match_the_surface(seed):
    """Plain vessel nodes (degree 2, no feature) lie one radius from the wall."""
    v = small(seed, end_style="round")
    deg = np.bincount(v.edges.ravel(), minlength=len(v.xyz))
    plain = [i for i, t in enumerate(v.tags) if deg[i] == 2 and set(t) == {"vessel"}]
    d2, _, _ = igl.point_mesh_squared_distance(v.xyz[plain], v.vertices, v.faces.astype(np.int64))
    ratio = np.sqrt(d2) / v.radius[plain]
    assert np.quantile(ratio, 0.02) > 0.85 and np.quantile(ratio, 0.98) < 1.12, (ratio.min(), ratio.max())


def test_open_ends_are_one_boundary_loop_each():
    v = small(7, end_style="open", rates=NONE)
    ends = int(np.sum(np.bincount(v.edges.ravel(), minlength=len(v.xyz)) == 1))
    assert boundary_loops(v.faces) == ends
    assert not v.manifest["closed"]
    tags = [t for t in v.tags if "inlet" in t or "outlet" in t]
    assert sum("inlet" in t for t in tags) == 1 and len(tags) == ends


def test_defects_do_what_the_manifest_says():
    dirt = {**NONE, "inward_normals": 1.0, "hole": 1.0, "components": 1.0}
    v = small(3, "rough", rates=dirt, end_style="flat")
    f = v.manifest["features"]
    assert f["hole"] >= 1 and boundary_loops(v.faces) == f["hole"] and not v.manifest["closed"]
    assert f["components"] >= 2 and len(np.unique(_components(len(v.vertices), v.faces))) == f["components"]
    assert signed_volume(v.vertices, v.faces) < 0 and not v.manifest["outward"]
    w = small(3, "rough", rates={**NONE, "inconsistent_orientation": 1.0}, end_style="round")
    directed = w.faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    assert len(np.unique(directed, axis=0)) < len(directed) and not w.manifest["consistently_oriented"]


def _junction_angle_min(v) -> float:
    """Smallest angle (degrees) between two daughters leaving one junction."""
    nbr = {}
    for a, b in v.edges.tolist():
        nbr.setdefault(a, []).append(b)
        nbr.setdefault(b, []).append(a)
    best = 180.0
    for i, n in nbr.items():
        if len(n) >= 3:
            d = T.unit(v.xyz[n] - v.xyz[i])
            c = d @ d.T
            np.fill_diagonal(c, -1)
            best = min(best, float(np.degrees(np.arccos(np.clip(c.max(), -1, 1)))))
    return best


def test_geometric_features_are_real():
    """Trifurcation: a degree-4 node; acute: daughters < 25 degrees apart; 1:5 side branch."""
    v = G.generate_vessel(0, "clean", rates={**NONE, "trifurcation": 1.0}, **SMALL)
    assert v.manifest["features"]["trifurcation"] and np.bincount(v.edges.ravel()).max() >= 4
    rng = np.random.default_rng(4)
    tree = G.build_tree(rng, {**G.MORPHOLOGY, "generations": (2, 2)}, {"acute_angle", "large_ratio"})
    xyz, rad, tags, edges = T.skeleton_of(tree)
    sk = G.Vessel(np.zeros((0, 3)), np.zeros((0, 3), int), xyz, rad, tags, edges)
    assert tree.features["acute_angle"] and _junction_angle_min(sk) < 25
    side = [b for b in tree.branches if b.kind == "side"]
    assert side and tree.branches[side[0].parent].rad[side[0].parent_at] / side[0].rad[0] > 4.4


def test_features_present_at_their_rates():
    """Over 30 trees with every tree feature at rate 0.5: each is requested in 0.5 +- 0.3 of
    them and placed in at least 60 % of the requests."""
    rates = {f: 0.5 for f in G.JUNCTION_FEATURES + G.SHAPE_FEATURES + ("kissing", "stub")}
    requested, placed = {f: 0 for f in rates}, {f: 0 for f in rates}
    morph = {**G.MORPHOLOGY, "generations": (2, 3)}
    n = 30
    for i in range(n):
        rng = np.random.default_rng(G.vessel_seed(9, i))
        wanted = G.draw_features(rng, rates)
        tree = G.build_tree(rng, morph, wanted)
        for f in wanted:
            requested[f] += 1
            placed[f] += bool(tree.features.get(f, 0))
    for f in rates:
        assert 0.2 * n <= requested[f] <= 0.8 * n, (f, requested[f])
        assert placed[f] >= 0.6 * requested[f], (f, placed[f], requested[f])


def test_clean_trees_keep_vessels_apart():
    """No tube of a clean tree comes closer than its radii to a non-adjacent one."""
    for i in range(6):
        rng = np.random.default_rng(G.vessel_seed(2, i))
        tree = G.build_tree(rng, {**G.MORPHOLOGY, "generations": (3, 3)}, set())
        for k, b in enumerate(tree.branches):
            near = {k, b.parent, *tree.children(k)} | ({tree.branches[b.parent].parent, *tree.children(b.parent)} if b.parent >= 0 else set())
            P, R, _ = tree.points(skip=near)
            if not len(P):
                continue
            d = np.linalg.norm(b.pts[:, None] - P[None], axis=2) - b.rad[:, None] - R[None]
            assert d.min() > 0, (i, k, d.min())


def test_files_round_trip_through_vmesh_readers(tmp_path):
    from vmesh.io.skeleton import read_skeleton
    from vmesh.io.surface import read_surface

    v = small(8, "rough", rates={**NONE, "loop": 1.0}, units="cm", surface_format="vtp")
    m = G.write_vessel(v, tmp_path / "v")
    d = tmp_path / "v"
    s = read_surface(d / m["files"]["surface"])
    assert s.n_faces == len(v.faces)
    np.testing.assert_allclose(s.vertices, v.vertices, rtol=1e-6, atol=1e-6)
    swc = read_skeleton(d / m["files"]["swc"])
    assert swc.n_nodes == len(v.xyz) and len(swc.edges) == len(v.edges) - m["features"]["loop"]
    np.testing.assert_allclose(np.sort(swc.radii), np.sort(v.radius), rtol=1e-6)
    assert np.isnan(read_skeleton(d / m["files"]["swc_noradius"]).radii).all()
    js = read_skeleton(d / m["files"]["skeleton_json"])
    assert js.n_nodes == len(v.xyz) and len(js.edges) == len(v.edges)
    cl = read_skeleton(d / m["files"]["centerline_vtp"])
    assert cl.n_nodes == len(v.xyz) and len(cl.edges) == len(v.edges)
    np.testing.assert_allclose(np.sort(cl.radii), np.sort(v.radius), rtol=1e-6)
    assert np.isnan(read_skeleton(d / m["files"]["centerline_vtp_noradius"]).radii).all()


@pytest.mark.slow
def test_corpus_index_is_independent_of_size_and_cached(tmp_path):
    a = G.generate_one(tmp_path / "a", 2, seed=5, preset="mixed", **SMALL)
    b = G.generate_one(tmp_path / "b", 2, seed=5, preset="mixed", **SMALL)
    assert a["features"] == b["features"] and a["faces"] == b["faces"]
    again = G.generate_one(tmp_path / "a", 2, seed=5, preset="mixed", **SMALL)
    assert again["seconds"] == a["seconds"]  # read from the manifest, not regenerated


def test_cli_rejects_an_unknown_feature(tmp_path, capsys):
    assert G.main(["--n", "1", "--out", str(tmp_path), "--rate", "wings=0.5"]) == 2
    assert "unknown feature 'wings'" in capsys.readouterr().err
