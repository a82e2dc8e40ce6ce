"""A mesh with inverted elements is never made worse by the light pass and never written
silently (issue 17/18, session 24, h24/inverted; docs/optimiser.md, *Runs that end with
inverted elements*).

On an inverted input the light pass also untangles (Newton steps on the regularised
functional, not judged by the minimum): seed-1 g0016 extracted came out of it with 7
inverted elements at -0.467 from 5 at -0.419. Its result is now refused there when the
minimum drops. ``compute_quality.fail_on_invalid = false`` writes such a mesh, and its
warnings now say that it is invalid.
"""

from __future__ import annotations

import types

import numpy as np
import pytest

import vmesh.filters.mesh_filters as mf
from test_untangle_patience import _grid
from vmesh.errors import MeshingError
from vmesh.geometry.optimize import optimise_linear
from vmesh.geometry.quality import hex8_scaled_jacobian


def _held_folds(seed: int = 11, n: int = 8):
    """An n^3 grid of unit hexahedra, its boundary and three interior nodes held, the three
    pushed ~0.9 off their places and the other interior nodes jittered by 0.15: folds no
    move of the free nodes fully opens (seed 11: 10 inverted elements at -0.543, which the
    light pass's untangling turns into 8 at -0.924)."""
    points, cells = _grid(n)
    held = (points == 0).any(axis=1) | (points == n).any(axis=1)
    rng = np.random.default_rng(seed)
    pick = rng.choice(np.flatnonzero(~held), 3, replace=False)
    points[pick] += rng.normal(size=(3, 3)) * 0.9
    held[pick] = True
    points[~held] += rng.normal(size=(int((~held).sum()), 3)) * 0.15
    return points, cells, held


def _light_pass_on(points, cells, held, monkeypatch):
    """``mesh_filters._light_pass`` on the grid (p = 1, no wall), the held nodes fixed."""
    n = len(points)
    monkeypatch.setattr(mf, "_constraints", lambda sm: (np.zeros(n, bool), np.zeros((n, 3)), np.zeros(n, bool), held.copy()))
    sm = types.SimpleNamespace(points=points.copy(), cells=cells, order=1)
    ctx = types.SimpleNamespace(tick=lambda *a, **k: None, count=lambda **k: None, report=types.SimpleNamespace(sections={}))
    sdf = types.SimpleNamespace(gradient=lambda x: np.zeros_like(x))
    mf._light_pass(ctx, sm, lambda x: x, sdf, 0.95, "gauss_lobatto")
    return sm.points, ctx.report.sections["light_pass"]


def test_the_light_pass_never_lowers_the_minimum_of_an_inverted_mesh(monkeypatch):
    points, cells, held = _held_folds()
    q0 = hex8_scaled_jacobian(points, cells)
    assert q0.min() < 0
    # the optimiser's pass alone folds it further (what the light pass used to keep)
    X, info = optimise_linear(points, cells, boundary=held, untangle_below=0.0, smooth_below=0.95, untangle_patience=mf.LIGHT_PASS_PATIENCE)
    assert hex8_scaled_jacobian(X, cells).min() < q0.min() - 0.1
    Y, section = _light_pass_on(points, cells, held, monkeypatch)
    assert not section["kept"] and "inverted" in section["refused"]
    assert np.array_equal(Y, points)
    assert hex8_scaled_jacobian(Y, cells).min() >= q0.min()
    # the report says what the mesh is (the input), the refused pass's result apart
    assert section["after"] == section["before"] and section["after"]["min"] == pytest.approx(q0.min())
    assert section["refused_after"]["min"] < q0.min() - 0.1
    assert section["smoothed_nodes"] == section["moved"] == section["untangled_nodes"] == 0
    assert section["refused_moved"] > 0


def test_a_refused_order_p_light_pass_is_reported_as_refused():
    """p > 1: a pass whose order-p minimum drops is refused and reported like the p = 1 one."""
    info = {"before": {"min": 0.5, "mean": 0.9}, "after": {"min": 0.6, "mean": 0.92}, "untangled_nodes": 0, "smoothed_nodes": 7, "moved": 7,
            "order_p": {"before": {"min": 0.4, "mean": 0.88}, "after": {"min": 0.3, "mean": 0.89}}}
    out = mf._refused(info, "order-p minimum dropped or mean did not rise")
    assert out["order_p"]["after"] == out["order_p"]["before"] == {"min": 0.4, "mean": 0.88}
    assert out["refused_order_p"]["after"] == {"min": 0.3, "mean": 0.89}
    assert out["kept"] is False and "order-p" in out["refused"]
    assert out["after"] == out["before"] == {"min": 0.5, "mean": 0.9}
    assert out["refused_after"] == {"min": 0.6, "mean": 0.92} and out["refused_smoothed_nodes"] == 7 and out["moved"] == 0


def test_the_light_pass_keeps_what_lifts_an_inverted_mesh(monkeypatch):
    """Where its untangling lifts the minimum (here the grid with one free node pushed
    through its neighbours: it opens), the result is kept as before."""
    points, cells = _grid(6)
    held = (points == 0).any(axis=1) | (points == 6).any(axis=1)
    points[3 + 7 * (3 + 7 * 3)] += [0.9, 0.8, 0.85]
    assert hex8_scaled_jacobian(points, cells).min() < 0
    Y, section = _light_pass_on(points, cells, held, monkeypatch)
    assert section["kept"] and hex8_scaled_jacobian(Y, cells).min() > 0


def test_an_invalid_mesh_written_on_request_is_named_in_the_warnings():
    """``fail_on_invalid = false`` writes the mesh but warns that it is invalid (and the
    default raises): a run never ends with inverted elements without saying so."""
    from conftest import synthetic_case
    from test_mesh_cases import run_default
    from vmesh.registry import get_filter

    surface, skeleton = synthetic_case("straight_tube")
    ctx = run_default(surface, skeleton)
    assert not any("INVALID" in w for w in ctx.report.warnings)
    mesh = ctx.mesh
    inner = np.flatnonzero(~np.isin(np.arange(len(mesh.points)), mesh.boundary_faces))
    c = mesh.cells[np.flatnonzero(np.isin(mesh.cells, inner).any(axis=1))[0]]
    node = c[np.isin(c, inner)][0]
    # through the element's opposite corner: that element and its neighbours invert
    far = c[7 - int(np.flatnonzero(c == node)[0])]
    mesh.points[node] = mesh.points[node] + 2.5 * (mesh.points[far] - mesh.points[node])
    get_filter("compute_quality")(ctx, histogram="", fail_on_invalid=False)
    n_bad = int((mesh.cell_data["scaled_jacobian"] <= 0).sum())
    assert n_bad > 0
    assert any("INVALID" in w and f"{n_bad} elements" in w for w in ctx.report.warnings)
    with pytest.raises(MeshingError, match="scaled Jacobian <= 0"):
        get_filter("compute_quality")(ctx, histogram="", fail_on_invalid=True)


def test_the_invalid_message_needs_no_block_ids():
    """A mesh without ``block_id`` / ``node_id`` cell data (read from a file) is still named."""
    mesh = types.SimpleNamespace(cell_data={})
    sj = np.array([0.5, -0.2, 0.9])
    message = mf._invalid_message(mesh, sj, {"n_invalid": 1, "min": -0.2}, None)
    assert "1 elements" in message and "blocks []" in message
