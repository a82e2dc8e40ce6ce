"""The raw appended VTK XML writers: files read back identically by VTK (pyvista) and meshio,
for linear (both readers) and Lagrange hexahedra (VTK), cell and field data of every numeric type, quads (.vtp, VTK; meshio has no .vtp reader)."""

import numpy as np
import pytest

from vmesh.io.mesh import names_from_field_data, write_boundary, write_mesh
from vmesh.io.vtk_xml import write_vtp_polygons, write_vtu
from vmesh.mesh import HexMesh, tensor_to_vtk


def grid_mesh(n=3, order=1, seed=0):
    """An n x n x n block of hexahedra of order p, nodes jittered, with labels and boundaries."""
    rng = np.random.default_rng(seed)
    m = n * order + 1
    ijk = np.stack(np.meshgrid(*(np.arange(m),) * 3, indexing="ij"), -1).reshape(-1, 3)
    points = ijk.astype(float) / order + rng.uniform(-0.05, 0.05, (len(ijk), 3))
    node = lambda i, j, k: (i * m + j) * m + k  # noqa: E731
    cells = []
    for ci in range(n):
        for cj in range(n):
            for ck in range(n):
                o = (ci * order, cj * order, ck * order)
                cells.append([node(o[0] + a, o[1] + b, o[2] + c) for c in range(order + 1) for b in range(order + 1) for a in range(order + 1)])
    cells = np.asarray(cells, np.int64)
    k = len(cells)
    cell_data = {
        "label": np.arange(k) % 2,
        "scaled_jacobian": rng.uniform(0.5, 1, k),
        "layer": (np.arange(k) % 3).astype(np.int32),
        "weight32": rng.uniform(size=k).astype(np.float32),
        "flag": np.arange(k) % 2 == 0,
        "vector": rng.uniform(size=(k, 3)),
    }
    q = (order + 1) ** 2
    faces = cells[:, :q]  # k = 0 face of each cell, as a boundary stand-in
    return HexMesh(points=points, cells=cells, order=order, cell_data=cell_data, boundary_faces=faces,
                   boundary_ids=np.arange(k) % 3, boundary_cells=np.arange(k),
                   boundary_names={0: "wall", 1: "inlet", 2: "outlet_1"}, label_names={0: "trunk", 1: "left branch"})


@pytest.mark.parametrize("order", [1, 2])
def test_vtu_reads_back_in_pyvista_and_meshio(tmp_path, order):
    import meshio
    import pyvista as pv

    mesh = grid_mesh(order=order)
    path = write_mesh(tmp_path / "m.vtu", mesh)
    vtk_cells, ctype = mesh.vtk_cells()
    r = pv.read(path)
    assert r.n_points == mesh.n_points and r.n_cells == mesh.n_cells
    assert np.array_equal(np.asarray(r.celltypes), np.full(mesh.n_cells, ctype))
    assert np.array_equal(np.asarray(r.cell_connectivity).reshape(mesh.n_cells, -1), vtk_cells)
    assert np.array_equal(np.asarray(r.points), mesh.points)
    for key, v in mesh.cell_data.items():
        assert np.array_equal(np.asarray(r.cell_data[key]).astype(np.asarray(v).dtype), v), key
    assert names_from_field_data(r.field_data, "label") == mesh.label_names
    assert names_from_field_data(r.field_data, "boundary") == mesh.boundary_names

    if order > 1:  # VTK's node order of Lagrange hexahedra; meshio refuses their file version (as VTK's own)
        assert np.array_equal(vtk_cells, mesh.cells[:, tensor_to_vtk(order)])
        return
    m = meshio.read(path)
    assert np.array_equal(m.points, mesh.points)
    assert len(m.cells) == 1 and np.array_equal(m.cells[0].data, vtk_cells)
    for key, v in mesh.cell_data.items():
        assert np.array_equal(np.asarray(m.cell_data[key][0]).astype(np.asarray(v).dtype), v), key
    assert names_from_field_data(m.field_data, "label") == mesh.label_names
    assert names_from_field_data(m.field_data, "boundary") == mesh.boundary_names


def test_boundary_vtp_reads_back(tmp_path):
    import pyvista as pv

    mesh = grid_mesh()
    path = write_boundary(tmp_path / "b.vtp", mesh)
    r = pv.read(path)
    quads = mesh.corner_boundary_faces()
    assert r.n_cells == len(quads) and r.n_points == mesh.n_points
    assert np.array_equal(np.asarray(r.faces).reshape(-1, 5)[:, 1:], quads)
    assert np.array_equal(np.asarray(r.cell_data["boundary_id"]), mesh.boundary_ids)
    assert np.array_equal(np.asarray(r.cell_data["label"]), mesh.cell_data["label"][mesh.boundary_cells])
    assert names_from_field_data(r.field_data, "boundary") == mesh.boundary_names


def test_int64_ids_beyond_int32(tmp_path):
    """Connectivity switches to Int64 when node ids do not fit Int32 (checked on the header only)."""
    from vmesh.io.vtk_xml import _index_array

    assert _index_array(np.array([1, 2]), 2**31 - 1).dtype == np.dtype("<i4")
    assert _index_array(np.array([1, 2]), 2**31).dtype == np.dtype("<i8")


def test_empty_data_and_quads(tmp_path):
    import pyvista as pv

    pts = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)
    write_vtp_polygons(tmp_path / "q.vtp", pts, np.array([[0, 1, 2, 3]]))
    r = pv.read(tmp_path / "q.vtp")
    assert r.n_cells == 1 and np.isclose(r.area, 1.0)
    write_vtu(tmp_path / "h.vtu", np.vstack([pts, pts + [0, 0, 1]]), np.array([np.arange(8)]), 12)
    r = pv.read(tmp_path / "h.vtu")
    assert r.n_cells == 1 and np.isclose(r.volume, 1.0)


def test_point_data(tmp_path):
    import pyvista as pv

    mesh = grid_mesh()
    flags = (np.arange(mesh.n_points) % 3 == 0).astype(np.uint8)
    write_vtu(tmp_path / "p.vtu", mesh.points, mesh.corner_cells(), 12, {"label": mesh.cell_data["label"]},
              point_data={"on_surface": flags, "normal": np.tile([0.0, 0.0, 1.0], (mesh.n_points, 1))})
    r = pv.read(tmp_path / "p.vtu")
    assert np.array_equal(np.asarray(r.point_data["on_surface"]), flags)
    assert np.asarray(r.point_data["normal"]).shape == (mesh.n_points, 3)
    assert np.array_equal(np.asarray(r.cell_data["label"]), mesh.cell_data["label"])


def _sphere_with_data():
    import pyvista as pv

    s = pv.Sphere(theta_resolution=24, phi_resolution=16).triangulate()
    s.cell_data["region"] = (np.arange(s.n_cells) % 5).astype(np.int32)
    s.cell_data["area"] = np.linspace(0, 1, s.n_cells)
    return s


@pytest.mark.parametrize("mode", ["ascii", "binary", "appended_raw", "appended_base64"])
@pytest.mark.parametrize("compress", [False, True])
@pytest.mark.parametrize("header64", [False, True])
def test_vtp_reader_matches_vtk(tmp_path, mode, compress, header64):
    """Every encoding VTK writes (inline ascii/base64, appended raw/base64, zlib or not,
    32/64-bit headers) reads back as VTK reads it."""
    import vtk

    from vmesh.io.surface import _read_pyvista
    from vmesh.io.vtk_xml import read_vtp_triangles

    s = _sphere_with_data()
    w = vtk.vtkXMLPolyDataWriter()
    w.SetFileName(str(tmp_path / "s.vtp"))
    w.SetInputData(s)
    w.SetHeaderTypeToUInt64() if header64 else w.SetHeaderTypeToUInt32()
    w.SetCompressorTypeToZLib() if compress else w.SetCompressorTypeToNone()
    if mode == "ascii":
        w.SetDataModeToAscii()
    elif mode == "binary":
        w.SetDataModeToBinary()
    else:
        w.SetDataModeToAppended()
        w.SetEncodeAppendedData(mode == "appended_base64")
    w.Write()
    pts, tri, data = read_vtp_triangles(tmp_path / "s.vtp")
    ref_pts, ref_tri, ref_data = _read_pyvista(tmp_path / "s.vtp", [])
    # same triangles in the same order (VTK's path may renumber the vertices)
    assert len(tri) == len(ref_tri) and np.allclose(pts[tri], ref_pts[ref_tri])
    assert set(data) == set(ref_data) == {"region", "area"}
    for k in data:
        assert np.allclose(data[k], ref_data[k]) and data[k].dtype == ref_data[k].dtype


def test_vtp_reader_leaves_other_cells_to_vtk(tmp_path):
    """Quads (and lines, strips, other polygons) are refused, so read_surface asks VTK."""
    from vmesh.io.surface import read_surface
    from vmesh.io.vtk_xml import UnsupportedVTKXML, read_vtp_triangles

    mesh = grid_mesh()
    write_boundary(tmp_path / "b.vtp", mesh)
    with pytest.raises(UnsupportedVTKXML):
        read_vtp_triangles(tmp_path / "b.vtp")
    surf = read_surface(tmp_path / "b.vtp")
    assert surf.n_faces == 2 * len(mesh.boundary_faces)


@pytest.mark.parametrize("suffix", [".ply", ".vtp"])
def test_surface_written_without_vtk_reads_back(tmp_path, suffix):
    """write_surface's numpy writers (.ply, .vtp) round-trip exactly and VTK reads them."""
    import pyvista as pv

    from vmesh.io.surface import read_surface, write_surface
    from vmesh.surface import SurfaceMesh

    s = _sphere_with_data()
    faces = np.asarray(s.faces).reshape(-1, 4)[:, 1:]
    surf = SurfaceMesh(np.asarray(s.points, float), faces, face_data={"region": np.asarray(s.cell_data["region"])})
    path = write_surface(tmp_path / f"s{suffix}", surf)
    back = read_surface(path)
    # VTK's readers may renumber the vertices (the surface cells are extracted): compare the
    # triangles by their corner coordinates
    def corners(m):
        c = np.sort(m.vertices[m.faces].reshape(len(m.faces), -1).round(12), axis=0)
        return c[np.lexsort(c.T[::-1])]

    assert len(back.faces) == len(surf.faces) and np.array_equal(corners(back), corners(surf))
    if suffix == ".vtp":
        assert np.array_equal(back.face_data["region"], surf.face_data["region"])
    r = pv.read(path)
    assert r.n_points == surf.n_vertices and r.n_cells == surf.n_faces


def test_int64_cell_data_narrowed_only_when_it_fits(tmp_path):
    import pyvista as pv

    mesh = grid_mesh()
    k = mesh.n_cells
    data = {"small": np.arange(k, dtype=np.int64), "big": np.arange(k, dtype=np.int64) + 2**40}
    write_vtu(tmp_path / "i.vtu", mesh.points, mesh.corner_cells(), 12, data)
    r = pv.read(tmp_path / "i.vtu")
    assert r.cell_data["small"].dtype == np.int32 and np.array_equal(r.cell_data["small"], data["small"])
    assert r.cell_data["big"].dtype == np.int64 and np.array_equal(r.cell_data["big"], data["big"])
