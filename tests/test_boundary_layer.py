"""Boundary-layer controls: lengths with units, any three of (first height, thickness,
elements, growth), the y+ estimate, and the first-cell height measured on the mesh."""

import math

import numpy as np
import pytest

from cfd_meshes import RADIUS, cylinder_mesh
from vmesh.errors import MeshingError, ParameterError
from vmesh.geometry.boundary_layer import (
    block_layer_thickness,
    first_cell_heights,
    first_edge_lengths,
    record_first_layer,
    first_layer_from_y_plus,
    parse_length,
    ratio_for,
    resolve_boundary_layer,
    series,
)
from vmesh.geometry.quality import scaled_jacobian
from vmesh.geometry.transfinite import reference_points


def test_parse_length_units():
    assert parse_length("0.05mm", "mm", "h") == pytest.approx(0.05)
    assert parse_length("50um", "mm", "h") == pytest.approx(0.05)
    assert parse_length("0.05mm", "m", "h") == pytest.approx(5e-5)
    assert parse_length("0.1cm", "mm", "h") == pytest.approx(1.0)
    assert parse_length("0.2", "cm", "h") == pytest.approx(0.2)  # no unit: the mesh's
    for bad in ("abc", "0.05 furlong", "-1mm", "0mm"):
        with pytest.raises(ParameterError, match="h = "):
            parse_length(bad, "mm", "h")


def test_y_plus_estimate_follows_the_flat_plate_formula():
    # water-like: U = 1 m/s, L = 1 m, rho = 1000, mu = 1e-3 -> Re = 1e6
    h = first_layer_from_y_plus(1.0, 1.0, 1000.0, 1e-3, 1.0)
    cf = 0.026 * 1e6 ** (-1 / 7)
    assert h == pytest.approx(1e-3 / (1000.0 * math.sqrt(cf / 2)))
    assert first_layer_from_y_plus(2.0, 1.0, 1000.0, 1e-3, 1.0) == pytest.approx(2 * h)  # linear in y+
    assert first_layer_from_y_plus(1.0, 2.0, 1000.0, 1e-3, 1.0) < h  # faster flow, thinner layer
    with pytest.raises(ParameterError, match="velocity must be positive"):
        first_layer_from_y_plus(1.0, 0.0, 1000.0, 1e-3, 1.0)


def test_three_of_four():
    h1, n, q = 0.01, 5, 1.2
    t = h1 * series(q, n)
    assert ratio_for(h1, t, n) == pytest.approx(q, rel=1e-9)
    # h1, n, q -> T
    assert resolve_boundary_layer(h1, None, None, n, q).thickness == pytest.approx(t)
    # h1, T, q -> n (elements_layer = 0)
    assert resolve_boundary_layer(h1, None, t, 0, q).elements == n
    # h1, T, n -> q per edge in the mesher (first height kept)
    bl = resolve_boundary_layer(h1, None, t, n, None)
    assert (bl.first_height, bl.thickness, bl.elements, bl.growth) == (h1, t, n, None)
    # T, n, q -> h1 from growth
    bl = resolve_boundary_layer(None, None, t, n, q)
    assert (bl.growth, bl.thickness) == (q, t)
    # all four, consistent
    assert resolve_boundary_layer(h1, None, t, n, q).thickness == pytest.approx(t)


def test_inconsistent_and_underdetermined_sets_give_one_line():
    with pytest.raises(ParameterError, match="inconsistent") as e:
        resolve_boundary_layer(0.01, None, 1.0, 5, 1.2)
    assert "\n" not in str(e.value)
    with pytest.raises(ParameterError, match="elements_layer = 0"):
        resolve_boundary_layer(0.01, None, None, 0, None)
    with pytest.raises(ParameterError, match="do not fit"):
        resolve_boundary_layer(0.2, None, 0.3, 4, None)


def _first_heights(mesh):
    h = first_cell_heights(mesh)
    assert len(h) == int((mesh.boundary_ids == 0).sum())
    return h


def test_absolute_first_height_on_a_cylinder():
    mesh, ctx = cylinder_mesh(first_layer_height="0.02mm")
    h = _first_heights(mesh)
    assert np.allclose(h, 0.02, rtol=0.02)
    edges = first_edge_lengths(mesh)
    assert len(edges) == 4 * len(h) and np.allclose(edges, 0.02, rtol=1e-6)  # along the layer lines: exact
    record_first_layer(ctx, mesh, 0.02)
    measured = ctx.report.sections["boundary_layer"]
    assert measured["measured_first_height"]["within_5_percent"] == measured["measured_first_edge"]["within_5_percent"] == 1.0
    assert ctx.report.sections["units"]["length"] == "mm"
    # the same height asked in micrometres, on the same input in cm: 0.002 cm
    mesh_cm, _ = cylinder_mesh(units="cm", first_layer_height="20um")
    assert np.allclose(_first_heights(mesh_cm), 0.002, rtol=0.02)


def test_grading_adds_no_elements_and_stays_valid():
    plain, _ = cylinder_mesh()
    graded, _ = cylinder_mesh(first_layer_height="0.005mm", elements_layer=3)
    assert graded.n_cells == plain.n_cells
    sj = scaled_jacobian(graded.points, graded.cells, 1, reference_points(1))
    assert sj.min() > 0


def test_thickness_moves_the_layer_blocks():
    mesh, ctx = cylinder_mesh(first_layer_height="0.01mm", boundary_layer_thickness="0.3mm", elements_layer=4)
    assert np.allclose(block_layer_thickness(ctx.blocks), 0.3)
    h = _first_heights(mesh)
    assert np.allclose(h, 0.01, rtol=0.02)
    # the layer elements stack up to the thickness: the 4th ring of nodes is 0.3 from the wall
    r = np.linalg.norm(mesh.points[:, :2], axis=1)
    assert np.isclose(r, RADIUS - 0.3, atol=1e-9).sum() > 0


def test_growth_and_height_derive_thickness():
    mesh, ctx = cylinder_mesh(first_layer_height="0.01mm", grading="growth", growth=1.5, elements_layer=4)
    assert np.allclose(block_layer_thickness(ctx.blocks), 0.01 * series(1.5, 4))
    assert np.allclose(_first_heights(mesh), 0.01, rtol=0.02)


def test_elements_derived_from_height_growth_thickness():
    mesh, ctx = cylinder_mesh(first_layer_height="0.01mm", grading="growth", growth=1.2, boundary_layer_thickness="0.2mm", elements_layer=0)
    n = ctx.report.sections["boundary_layer"]["elements"]
    assert n == round(math.log(1 + 0.2 * 0.2 / 0.01) / math.log(1.2))
    assert np.allclose(_first_heights(mesh), 0.01, rtol=0.02)


def test_y_plus_sets_the_height():
    mesh, ctx = cylinder_mesh(y_plus=1.0, flow_velocity=1.0, reference_length="20mm")
    expect = first_layer_from_y_plus(1.0, 1.0, 1060.0, 3.5e-3, 20e-3) * 1e3  # mm
    assert ctx.report.sections["boundary_layer"]["first_height"] == f"{expect:.6g} mm"
    assert np.allclose(_first_heights(mesh), expect, rtol=0.02)
    with pytest.raises(ParameterError, match="not both"):
        cylinder_mesh(y_plus=1.0, first_layer_height="0.01mm")


def test_height_above_uniform_spacing_warns():
    mesh, ctx = cylinder_mesh(first_layer_height="0.3mm")  # 3 x 0.3 > the 0.4 mm layer
    assert any("exceeds the boundary-layer blocks' thickness" in w for w in ctx.report.warnings)


def test_too_thick_layer_is_refused():
    with pytest.raises(MeshingError, match="thinner boundary_layer_thickness"):
        cylinder_mesh(first_layer_height="0.01mm", boundary_layer_thickness="1.9mm")


def test_parameters_documented():
    from vmesh.registry import get_filter

    text = get_filter("mesh_transfinite").parameter_table()
    for name in ("first_layer_height", "boundary_layer_thickness", "y_plus", "flow_velocity", "flow_density", "flow_viscosity", "reference_length"):
        assert name in text
    assert "0.026 Re^(-1/7)" in text
