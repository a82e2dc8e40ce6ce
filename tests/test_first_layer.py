"""The exact first-layer height: boundary-layer node lines, wall normals, re-placing every
line so that its first element has the asked wall-normal height, and the local fallback."""

import numpy as np
import pytest

from cylinder_blocks import cylinder_blocks, project_cylinder
from vmesh.blocks import LAYER_BOUNDARY, LAYER_RING
from vmesh.geometry.boundary_layer import first_cell_heights, first_node_heights
from vmesh.geometry.layer_placement import layer_lines, offset_layer, place_first_layer, wall_normals
from vmesh.geometry.quality import scaled_jacobian
from vmesh.geometry.transfinite import Refinement, mesh_blocks, reference_points
from vmesh.mesh import HexMesh

H1 = 0.02


def bent_tapered_mesh(order=1, layer=3, bend=0.03, taper=0.06):
    """A cylinder of radius 2 along z meshed with a first layer of ``H1`` along its radial
    lines, then tapered (radius 2 -> 0.8) and bent in x (slope up to 0.6): the layer lines
    stay in the z planes and are oblique to the wall (as at a stenosis or a bend)."""
    blocks = cylinder_blocks(radius=2.0, length=10.0, sections=4)
    ref = Refinement(around=2, core=2, ring=2, layer=layer, element_length=1.0, first_layer=H1, first_layer_absolute=True, order=order)
    sm = mesh_blocks(blocks, project_cylinder(2.0), ref)
    X = sm.points.copy()
    z = X[:, 2]
    X[:, :2] *= (1.0 - taper * z)[:, None]
    X[:, 0] += bend * z**2
    b = sm.cell_block
    mesh = HexMesh(points=X, cells=sm.cells, order=order, cell_data={"block_id": b.astype(np.int64), "layer": blocks.block_layer[b]},
                   boundary_faces=sm.boundary_faces, boundary_ids=sm.boundary_ids, boundary_cells=sm.boundary_cells,
                   boundary_names=dict(blocks.boundary_names))
    return mesh


def _place(mesh, height=H1, floor=0.3):
    in_layer = mesh.cell_data["layer"] == LAYER_BOUNDARY
    return place_first_layer(mesh.points, mesh.cells, mesh.order, mesh.boundary_faces, mesh.boundary_ids, mesh.boundary_cells, in_layer, height, floor=floor)


@pytest.mark.parametrize("order", [1, 2, 3])
def test_layer_lines_cover_the_layer_once(order):
    mesh = bent_tapered_mesh(order)
    in_layer = mesh.cell_data["layer"] == LAYER_BOUNDARY
    lines, elements = layer_lines(mesh.cells, order, mesh.boundary_faces, mesh.boundary_ids, mesh.boundary_cells, in_layer)
    assert (elements == 3).all()
    assert lines.shape[1] == 3 * order + 1 and (lines >= 0).all()
    wall_nodes = np.unique(mesh.boundary_faces[mesh.boundary_ids == 0])
    assert np.array_equal(np.sort(lines[:, 0]), wall_nodes)  # one line per wall node
    layer_nodes = np.unique(mesh.cells[in_layer])
    assert np.array_equal(np.sort(lines.ravel()), layer_nodes)  # every layer node on exactly one line


@pytest.mark.parametrize("order", [1, 2, 3, 4])
def test_first_layer_exact_along_the_wall_normal(order):
    mesh = bent_tapered_mesh(order)
    before, _ = first_node_heights(mesh)
    assert np.mean(np.abs(before / H1 - 1) <= 0.05) < 0.9  # oblique lines: the height drifts
    X, info = _place(mesh)
    assert info["placed"] == info["lines"] and info["reverted"] == info["own_direction"] == info["first_element_only"] == 0
    mesh.points = X
    after, lines = first_node_heights(mesh)
    assert np.allclose(after, H1, rtol=1e-9)  # every wall node, the cap rims included
    assert np.mean(np.abs(first_cell_heights(mesh) / H1 - 1) <= 0.05) == 1.0  # per wall face too
    # the first node lies on the wall normal except on the caps (kept in the cap plane)
    n = wall_normals(X, mesh.boundary_faces, mesh.boundary_ids, order)[lines[:, 0]]
    off_cap = ~np.isin(lines[:, 0], mesh.boundary_faces[mesh.boundary_ids > 0])
    step = X[lines[off_cap, order]] - X[lines[off_cap, 0]]
    assert np.allclose(np.cross(step, n[off_cap]), 0.0, atol=1e-12)
    cap_nodes = mesh.boundary_faces[mesh.boundary_ids == 1].ravel()
    assert np.allclose(X[cap_nodes, 2], 0.0, atol=1e-12)  # the inlet stays plane
    sj = scaled_jacobian(X, mesh.cells, order, reference_points(order))
    assert sj.min() > 0.3
    # the rest of the line grows away from the wall and ends at the layer's inner node
    length = np.linalg.norm(np.diff(X[lines[:, ::order]], axis=1), axis=2)
    assert (length[:, 1:] > length[:, :-1]).all()


def test_a_fold_is_given_back_locally():
    mesh = bent_tapered_mesh(1)
    sj0 = scaled_jacobian(mesh.points, mesh.cells, 1)
    X, info = _place(mesh, floor=0.8)  # lines that would take an element below 0.8 step back
    assert info["placed"] > 0 and info["first_element_only"] + info["own_direction"] + info["reverted"] > 0
    sj = scaled_jacobian(X, mesh.cells, 1)
    assert sj.min() >= min(sj0.min(), 0.8) - 1e-12  # no element below the worst before, or 0.8
    heights, _ = first_node_heights(HexMesh(**{**mesh.__dict__, "points": X}))
    assert np.mean(np.isclose(heights, H1, rtol=1e-9)) > 0.5  # the fallbacks keep the normal height
    too_thick, info = _place(mesh, height=5.0)  # no room: every line keeps its spacing
    assert info["placed"] == 0 and np.array_equal(too_thick, mesh.points)


def _fold_wall(mesh, depth=0.45):
    """Push the wall in between the block corners (8 lobes) by up to ``depth``, more than
    the 0.4 thick layer, fading inwards: the wall crosses the layer's inner face (its
    concave radius of curvature stays above 0.2)."""
    X = mesh.points.copy()
    r = np.linalg.norm(X[:, :2], axis=1)
    theta = np.arctan2(X[:, 1], X[:, 0])
    push = depth * np.sin(4 * theta) ** 2 * np.clip((r - 1.55) / 0.45, 0, 1) ** 2
    X[:, :2] *= ((r - push) / np.maximum(r, 1e-300))[:, None]
    return HexMesh(**{**mesh.__dict__, "points": X})


def _offset(mesh, thickness, height=H1):
    layer = mesh.cell_data["layer"]
    return offset_layer(mesh.points, mesh.cells, mesh.order, mesh.boundary_faces, mesh.boundary_ids, mesh.boundary_cells,
                        layer == LAYER_BOUNDARY, layer == LAYER_RING, thickness, height)


@pytest.mark.parametrize("order", [1, 2, 3])
def test_offset_layer_gives_the_thickness_from_the_wall(order):
    mesh = _fold_wall(bent_tapered_mesh(order, bend=0.0, taper=0.0))
    ref = reference_points(order)
    assert (scaled_jacobian(mesh.points, mesh.cells, order, ref) <= 0).sum() > 0  # the wall crosses the layer
    X, info = _offset(mesh, 0.2)
    assert info["kept"] == 0
    moved = HexMesh(**{**mesh.__dict__, "points": X})
    heights, lines = first_node_heights(moved)
    assert np.allclose(heights, H1, rtol=1e-9)
    n = wall_normals(X, mesh.boundary_faces, mesh.boundary_ids, order)[lines[:, 0]]
    inner = X[lines[:, -1]] - X[lines[:, 0]]
    assert np.allclose(np.einsum("ij,ij->i", inner, n), 0.2, rtol=1e-9)  # the thickness along the normal
    assert scaled_jacobian(X, mesh.cells, order, ref).min() > 0.4  # unfolded
    core = mesh.cell_data["layer"] == 0
    assert np.array_equal(X[mesh.cells[core]], mesh.points[mesh.cells[core]])  # the core stays


@pytest.mark.parametrize("order", [1, 2])
def test_first_elements_give_the_whole_lines_heights(order):
    """record_first_layer's heights come from the lines' first elements only (no tracing
    across the layer): the same rows, heights and order as from the whole lines."""
    mesh = bent_tapered_mesh(order)
    h, lines = first_node_heights(mesh)
    h1, first = first_node_heights(mesh, whole_lines=False)
    assert np.array_equal(h, h1) and np.array_equal(first, lines[:, : order + 1])


def test_first_elements_at_a_junction():
    """The same on a meshed Y-bifurcation (junction blocks, cap rims)."""
    import vmesh
    from conftest import synthetic_case

    chain = vmesh.FilterChain.load("default").with_overrides({"mesh_transfinite.element_length": 0.75})
    names = [s.filter for s in chain.steps]
    chain.steps = chain.steps[: names.index("mesh_transfinite") + 1]
    mesh = chain.run(*synthetic_case("y_bifurcation")).mesh
    h, lines = first_node_heights(mesh)
    h1, first = first_node_heights(mesh, whole_lines=False)
    assert len(h) > 500 and np.array_equal(h, h1) and np.array_equal(first, lines[:, : mesh.order + 1])
