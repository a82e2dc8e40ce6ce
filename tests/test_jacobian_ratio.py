"""The Jacobian ratio (min / max det J over an element's nodes): the taper the corner scaled
Jacobian does not see (gmsh's minSJ reads it; docs/robustness.md, h20/fold)."""

import json

import numpy as np
import pytest

from vmesh.geometry.quality import jacobian_quality, jacobian_ratio, jacobian_ratio_summary, scaled_jacobian

# unit cube corners in tensor order (corner i + 2 j + 4 k)
CUBE = np.array([[i, j, k] for k in (0, 1) for j in (0, 1) for i in (0, 1)], float)


def _nodes(corners, order):
    """The trilinear element's nodes at order p (tensor order, i fastest)."""
    t = np.linspace(0, 1, order + 1)
    w, v, u = np.meshgrid(t, t, t, indexing="ij")
    u, v, w = u.ravel(), v.ravel(), w.ravel()
    shape = np.stack([(1 - u if i == 0 else u) * (1 - v if j == 0 else v) * (1 - w if k == 0 else w) for k in (0, 1) for j in (0, 1) for i in (0, 1)], axis=1)
    return shape @ corners


def _ratio(corners, order=1):
    if order == 1:
        return jacobian_ratio(corners, np.arange(8)[None])[0], scaled_jacobian(corners, np.arange(8)[None])[0]
    pts = _nodes(corners, order)
    cells = np.arange(len(pts))[None]
    return jacobian_ratio(pts, cells, order)[0], scaled_jacobian(pts, cells, order)[0]


def test_parallelepipeds_have_ratio_one():
    shear = np.array([[1.0, 0.0, 0.0], [0.6, 1.0, 0.0], [0.2, 0.3, 2.0]])
    for order in (1, 2):
        r, sj = _ratio(CUBE @ shear.T, order)
        assert r == pytest.approx(1.0)
        assert sj < 0.9  # sheared: the scaled Jacobian sees the angles, the ratio does not


def test_taper_is_seen_where_the_scaled_jacobian_is_high():
    # the i-edges shrink to a fifth along j (a wedge-like layer element whose corners stay
    # right-angled in the i-j plane at j = 0): det J at the narrow end is a fifth
    c = CUBE.copy()
    narrow = c[:, 1] == 1
    c[narrow, 0] = 0.4 + 0.2 * c[narrow, 0]
    r, sj = _ratio(c)
    assert r == pytest.approx(0.2)
    assert sj > 0.9
    assert _ratio(c, 2)[0] == pytest.approx(0.2)


def test_inverted_element_has_ratio_at_most_zero():
    c = CUBE.copy()
    c[7] = [0.2, 0.2, 0.2]  # the far corner pushed through the element
    r, sj = _ratio(c)
    assert sj <= 0
    assert r <= 0


def test_one_pass_matches_the_separate_measures():
    # compute_quality's one pass (jacobian_quality) gives both columns' values exactly
    rng = np.random.default_rng(1)
    for order in (1, 2):
        n = (order + 1) ** 3
        pts = np.vstack([_nodes(CUBE + 0.3 * rng.standard_normal((8, 3)), order) + 0.03 * (order - 1) * rng.standard_normal((n, 3)) for _ in range(40)])
        cells = np.arange(len(pts)).reshape(-1, n)
        sj, ratio = jacobian_quality(pts, cells, order, chunk=7)
        assert np.array_equal(sj, scaled_jacobian(pts, cells, order)) and np.array_equal(ratio, jacobian_ratio(pts, cells, order))
        assert (sj <= 0).any() and (sj > 0).any()  # inverted elements and valid ones
    # p = 1 (compiled): the corners' determinants of their three edge vectors, numpy
    X = np.vstack([CUBE + 0.3 * rng.standard_normal((8, 3)) for _ in range(40)])
    Y = X.reshape(-1, 2, 2, 2, 3)  # (m, k, j, i, 3)
    det = np.stack([np.linalg.det(np.stack([Y[:, k, j, 1] - Y[:, k, j, 0], Y[:, k, 1, i] - Y[:, k, 0, i], Y[:, 1, j, i] - Y[:, 0, j, i]], axis=1))
                    for k in (0, 1) for j in (0, 1) for i in (0, 1)], axis=1)
    got = jacobian_quality(X, np.arange(len(X)).reshape(-1, 8), 1)[1]
    assert np.allclose(got, det.min(axis=1) / np.abs(det).max(axis=1), rtol=0, atol=1e-12)


def test_summary_counts_per_layer():
    ratio = np.array([1.0, 0.5, 0.1, 0.05, 0.9])
    out = jacobian_ratio_summary(ratio, np.array([0, 1, 2, 2, 2]), 0.2)
    assert out["n_below"] == 2 and out["min"] == pytest.approx(0.05)
    assert out["by_layer"]["2"] == {"n": 3, "min": pytest.approx(0.05), "n_below": 2}
    assert out["by_layer"]["0"]["n_below"] == 0


def test_compute_quality_writes_the_column(y_run):
    from vmesh.io.run_folder import read_run_mesh

    mesh = read_run_mesh(y_run)
    ratio = np.asarray(mesh.cell_data["jacobian_ratio"])
    assert ratio.shape == (mesh.n_cells,)
    assert (ratio > 0).all() and (ratio <= 1 + 1e-12).all()
    section = json.loads((y_run / "report.json").read_text())["quality"]["jacobian_ratio"]
    assert section["min"] == pytest.approx(float(ratio.min()))
    assert sum(v["n"] for v in section["by_layer"].values()) == mesh.n_cells


def test_default_chain_keeps_the_boundary_layer_untapered(y_run):
    """The taper guard is on by default (``light_pass_ratio_floor`` 0.3, session 23): on the
    Y-bifurcation, whose fill has no element below that ratio, the light pass leaves none
    below it either (without the guard it thinned boundary-layer elements at one edge)."""
    from vmesh.chain import FilterChain

    chain = FilterChain.load(y_run / "chain.toml")
    floors = [s.params.get("light_pass_ratio_floor") for s in chain.steps if s.filter == "mesh_transfinite"]
    assert floors == [0.3]
    assert json.loads((y_run / "report.json").read_text())["quality"]["jacobian_ratio"]["min"] >= 0.3 - 1e-9

