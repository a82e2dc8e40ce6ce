"""The transfinite mesher on a hand-built O-grid cylinder (independent of the block builder)."""

import numpy as np
import pytest
from scipy.spatial import cKDTree

from cylinder_blocks import cylinder_blocks, project_cylinder
from vmesh.blocks import HEX_FACES
from vmesh.geometry.quality import scaled_jacobian
from vmesh.geometry.transfinite import Refinement, coons_patch, element_boundaries, geometric_ratio, mesh_blocks, reference_points, transfinite_volume
from vmesh.mesh import HexMesh

R = 2.0


def build(**kw):
    blocks = cylinder_blocks(radius=R)
    sm = mesh_blocks(blocks, project_cylinder(R), Refinement(**kw))
    return blocks, sm, HexMesh(sm.points, sm.cells, sm.order, boundary_faces=sm.boundary_faces, boundary_ids=sm.boundary_ids, boundary_cells=sm.boundary_cells)


def test_geometric_ratio_hits_first_size():
    q = geometric_ratio(np.array([0.1, 0.01]), np.array([1.0, 1.0]), 4)
    t = element_boundaries(4, q)
    assert np.allclose(t[:, 1], [0.1, 0.01], rtol=1e-6)


def test_gauss_lobatto_points():
    assert np.allclose(reference_points(2), [0, 0.5, 1])
    assert np.allclose(reference_points(3), [0, 0.5 - np.sqrt(5) / 10, 0.5 + np.sqrt(5) / 10, 1])


def test_coons_and_tfi_reproduce_affine_maps():
    rng = np.random.default_rng(0)
    A = rng.normal(size=(3, 3)) + 3 * np.eye(3)
    u = np.linspace(0, 1, 5) ** 1.5
    g = np.stack(np.meshgrid(u, u, u, indexing="ij"), -1) @ A.T
    P = g[None].copy()
    P[:, 1:-1, 1:-1, 1:-1] = np.nan
    assert np.allclose(transfinite_volume(P)[0], g)
    f = g[:, :, 0][None].copy()
    f[:, 1:-1, 1:-1] = np.nan
    assert np.allclose(coons_patch(f)[0], g[:, :, 0])


@pytest.mark.parametrize("order", [1, 2, 3])
def test_cylinder_mesh_valid_conforming_watertight(order):
    blocks, sm, mesh = build(order=order, first_layer=0.02)
    sj = scaled_jacobian(mesh.points, mesh.cells, order, reference_points(order))
    assert (sj > 0).all() and sj.min() > 0.5
    # conformity: every element face is shared by two elements or lies on the boundary
    faces = np.sort(mesh.corner_cells()[:, HEX_FACES].reshape(-1, 4), axis=1)
    _, counts = np.unique(faces, axis=0, return_counts=True)
    assert set(counts.tolist()) <= {1, 2}
    assert (counts == 1).sum() == len(mesh.boundary_faces)
    # nodes are numbered once: no two nodes at the same place
    assert len(np.unique(np.round(mesh.points, 9), axis=0)) == mesh.n_points
    # watertight boundary: each boundary quad edge shared by exactly two boundary quads
    q = mesh.corner_boundary_faces()
    e = np.sort(np.stack([q, np.roll(q, -1, 1)], -1).reshape(-1, 2), 1)
    _, ec = np.unique(e, axis=0, return_counts=True)
    assert (ec == 2).all()
    # wall nodes on the cylinder; open ends named
    wall = np.unique(mesh.boundary_faces[mesh.boundary_ids == 0])
    assert np.abs(np.linalg.norm(mesh.points[wall, :2], axis=1) - R).max() < 1e-9
    assert set(np.unique(mesh.boundary_ids).tolist()) == {0, 1, 2}


def test_grading_keeps_element_count_and_first_layer_thickness():
    _, _, uniform = build(first_layer=None)
    _, sm, graded = build(first_layer=0.02)
    assert uniform.n_cells == graded.n_cells and uniform.n_points == graded.n_points
    wall = np.unique(graded.boundary_faces[graded.boundary_ids == 0])
    inner = np.setdiff1d(np.arange(graded.n_points), wall)
    r_inner = np.linalg.norm(graded.points[inner, :2], axis=1)
    # the first node layer off the wall
    _, nearest = cKDTree(graded.points[inner]).query(graded.points[wall])
    thickness = R - r_inner[nearest]
    assert abs(np.median(thickness) - 0.02 * R) < 0.1 * 0.02 * R


@pytest.mark.parametrize("order", [2, 3])
def test_high_order_vtu_reads_back(tmp_path, order):
    pv = pytest.importorskip("pyvista")
    from vmesh.io.mesh import write_mesh

    _, _, mesh = build(order=order)
    path = write_mesh(tmp_path / "m.vtu", mesh)
    grid = pv.read(path)
    assert grid.n_points == mesh.n_points and grid.n_cells == mesh.n_cells
    # VTK's own cell volumes are positive and add up to the cylinder (node order is VTK's)
    vol = grid.compute_cell_sizes(length=False, area=False, volume=True).cell_data["Volume"]
    assert (vol > 0).all()
    assert abs(vol.sum() - np.pi * R**2 * 10.0) < 0.01 * np.pi * R**2 * 10.0


def test_hex27_order_matches_vtk_triquadratic(tmp_path):
    meshio = pytest.importorskip("meshio")
    pv = pytest.importorskip("pyvista")
    _, _, mesh = build(order=2)
    m = mesh.to_meshio(hex27=True)
    path = tmp_path / "m.vtu"
    meshio.write(path, m)
    grid = pv.read(path)
    vol = grid.compute_cell_sizes(length=False, area=False, volume=True).cell_data["Volume"]
    assert (vol > 0).all()
    assert abs(vol.sum() - np.pi * R**2 * 10.0) < 0.01 * np.pi * R**2 * 10.0


def test_wall_face_node_keeps_its_side_when_its_ray_passes_a_saddle():
    """thoracic_aorta extracted with curved along edges: a wall face's interior node a little
    inside the wall, whose patch normal points across the vessel (the saddle beside a
    junction), found the far wall along its ray (12 units away, the radius allowed) and
    folded the boundary layer. A ray much longer than the node's distance to the wall is
    not trusted (as on wall edges): the node goes to its closest wall point instead."""
    from types import SimpleNamespace

    from vmesh.geometry.transfinite import _face_to_wall

    H = 10.0  # the wall: the planes z = 0 and z = H, the vessel between them

    def intersect_lines(p, d, reach, side):
        out, hit = p.copy(), np.zeros(len(p), bool)
        for i in range(len(p)):
            ts = [t for t in ((0.0 - p[i, 2]) / d[i, 2], (H - p[i, 2]) / d[i, 2]) if t * side[i] >= 0 and abs(t) <= reach[i]] if d[i, 2] else []
            if ts:
                t = min(ts, key=abs)
                out[i], hit[i] = p[i] + t * d[i], True
        return out, hit

    fill = SimpleNamespace(
        signed_distance=lambda p: np.minimum(p[:, 2], H - p[:, 2]),
        intersect_lines=intersect_lines,
        project=lambda p: np.c_[p[:, :2], np.where(p[:, 2] < H / 2, 0.0, H)],
    )
    s, t = np.meshgrid(np.arange(3.0), np.arange(3.0), indexing="ij")
    P = np.stack([s, t, np.full_like(s, 1.0)], axis=-1)[None].copy()  # one face at z = 1, its outward side towards z = H
    _face_to_wall(fill, P, np.array([True]), np.array([[0.0, 0.0, 1.0]]), np.array([2 * H]))
    assert P[0, 1, 1, 2] == pytest.approx(0.0)  # the near wall, not the far one at z = H
