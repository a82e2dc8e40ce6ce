"""Export: every solver format written and read back (meshio, gmsh, VTK's readers), the
MeshLab layers and project in pymeshlab, order refusals, atomic writes, the command line."""

import numpy as np
import pytest

from conftest import synthetic_case
from vmesh.cli import main
from vmesh.errors import ParameterError
from vmesh.io.export import EXPORT_FORMATS, boundary_local_faces, export_mesh, tensor_faces
from vmesh.io.run_folder import read_mesh_vtu, read_run_mesh
from vmesh.mesh import HexMesh


@pytest.fixture(scope="module")
def mesh(y_run):
    return read_run_mesh(y_run)


@pytest.fixture(scope="module")
def mesh_p2(tmp_path_factory):
    """A second-order straight tube (coarse along the axis)."""
    from vmesh.chain import FilterChain

    surface, skeleton = synthetic_case("straight_tube")
    out = tmp_path_factory.mktemp("p2") / "run"
    chain = FilterChain.load("default").with_overrides({"mesh_transfinite.order": 2, "mesh_transfinite.element_length": 1.5})
    chain.run(surface=surface, skeleton=skeleton, out_dir=out)
    return read_run_mesh(out)


def expected(mesh):
    """Element count per label name and face count per boundary name."""
    labels = {mesh.label_names[k]: int(c) for k, c in zip(*np.unique(mesh.cell_data["label"], return_counts=True))}
    bounds = {mesh.boundary_names[k]: int(c) for k, c in zip(*np.unique(mesh.boundary_ids, return_counts=True))}
    return labels, bounds


def safe(name):
    return name.replace("+", "_")


def test_run_folder_reads_back(y_run, mesh):
    import json

    report = json.loads((y_run / "report.json").read_text())
    assert mesh.n_cells == report["counts"]["elements"] and mesh.n_points == report["counts"]["nodes"]
    labels, bounds = expected(mesh)
    assert bounds == report["labels"]["boundary_faces"]
    assert labels == report["labels"]["elements"]
    assert len(mesh.boundary_faces) == len(mesh.boundary_cells) == sum(bounds.values())


def test_vtu(mesh, tmp_path):
    """VTK's reader and meshio's read the VTU, with the label and boundary names."""
    import meshio
    import pyvista as pv

    from vmesh.io.mesh import names_from_field_data

    path = export_mesh(tmp_path / "m.vtu", mesh)
    r = pv.read(path)
    assert r.n_points == mesh.n_points and r.n_cells == mesh.n_cells
    assert set(mesh.cell_data) <= set(r.cell_data.keys())
    assert np.array_equal(r.cell_data["label"], mesh.cell_data["label"])
    m = meshio.read(path)
    assert len(m.points) == mesh.n_points and sum(len(c.data) for c in m.cells) == mesh.n_cells
    assert np.array_equal(np.concatenate(m.cell_data["label"]), mesh.cell_data["label"])
    for field in (r.field_data, m.field_data):
        assert names_from_field_data(field, "label") == dict(mesh.label_names)
        assert names_from_field_data(field, "boundary") == dict(mesh.boundary_names)


def test_gmsh(mesh, tmp_path):
    gmsh = pytest.importorskip("gmsh")
    import meshio

    path = export_mesh(tmp_path / "m.msh", mesh)
    assert path.read_text()[:40].split()[1] == "4.1"
    labels, bounds = expected(mesh)
    gmsh.initialize()
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.open(str(path))
        groups = {}
        for dim, tag in gmsh.model.getPhysicalGroups():
            n = sum(len(gmsh.model.mesh.getElements(dim, e)[1][0]) for e in gmsh.model.getEntitiesForPhysicalGroup(dim, tag))
            groups[(dim, gmsh.model.getPhysicalName(dim, tag))] = n
        assert len(gmsh.model.mesh.getNodes()[0]) == mesh.n_points
        types, tags, _ = gmsh.model.mesh.getElements(3)
        assert list(types) == [5] and sum(map(len, tags)) == mesh.n_cells
        assert gmsh.model.mesh.getElementQualities(np.concatenate(tags), "minSJ").min() > 0  # node order right
    finally:
        gmsh.finalize()
    assert groups == {**{(3, k): v for k, v in labels.items()}, **{(2, k): v for k, v in bounds.items()}}
    r = meshio.read(path)
    assert len(r.points) == mesh.n_points


def test_gmsh_node_order_tables_match_gmsh():
    gmsh = pytest.importorskip("gmsh")
    from vmesh.io import gmsh as writer

    gmsh.initialize()
    try:
        for table, types, dim in ((writer.GMSH_HEX, writer.HEX_TYPES, 3), (writer.GMSH_QUAD, writer.QUAD_TYPES, 2)):
            for p, t in types.items():
                coords = np.array(gmsh.model.mesh.getElementProperties(t)[4]).reshape(-1, dim)
                ijk = np.rint((coords + 1) / 2 * p).astype(int)
                idx = ijk[:, 0] + (p + 1) * ijk[:, 1] + (0 if dim == 2 else (p + 1) ** 2 * ijk[:, 2])
                assert idx.tolist() == table[p], (t, p)
    finally:
        gmsh.finalize()


def test_abaqus(mesh, tmp_path):
    import meshio

    from vmesh.io.abaqus import read_surfaces

    path = export_mesh(tmp_path / "m.inp", mesh)
    r = meshio.read(path)
    labels, bounds = expected(mesh)
    assert len(r.points) == mesh.n_points and [(c.type, len(c.data)) for c in r.cells] == [("hexahedron", mesh.n_cells)]
    for name, n in labels.items():
        assert sum(map(len, r.cell_sets[safe(name)])) == n
    assert read_surfaces(path) == bounds
    for b, name in mesh.boundary_names.items():
        assert len(r.point_sets[name]) == len(np.unique(mesh.boundary_faces[mesh.boundary_ids == b]))


def test_exodus(mesh, tmp_path):
    import meshio
    import pyvista as pv

    from vmesh.io.exodus import read_sets

    path = export_mesh(tmp_path / "m.exo", mesh)
    labels, bounds = expected(mesh)
    sets = read_sets(path)
    assert sets["blocks"] == {safe(k): v for k, v in labels.items()}
    assert sets["side_sets"] == bounds
    r = meshio.read(path)
    assert len(r.points) == mesh.n_points and sum(len(c.data) for c in r.cells) == mesh.n_cells
    assert "scaled_jacobian" in r.cell_data
    # VTK's Exodus reader: blocks, and side sets on the right element faces
    reader = pv.get_reader(str(path))
    data = reader.read()
    blocks = data["Element Blocks"]
    assert {k: blocks[k].n_cells for k in blocks.keys()} == {safe(k): v for k, v in labels.items()}
    side = data["Side Sets"]
    assert {k: side[k].n_cells for k in side.keys()} == bounds
    for b, name in mesh.boundary_names.items():
        centres = mesh.points[mesh.corner_boundary_faces()[mesh.boundary_ids == b]].mean(axis=1)
        got = np.asarray(side[name].cell_centers().points)
        from scipy.spatial import cKDTree

        assert cKDTree(centres).query(got)[0].max() < 1e-5


def test_medit(mesh, tmp_path):
    import meshio

    path = export_mesh(tmp_path / "m.mesh", mesh)
    r = meshio.read(path)
    labels, bounds = expected(mesh)
    assert len(r.points) == mesh.n_points
    hexes, quads = r.cell_data["medit:ref"]
    assert len(hexes) == mesh.n_cells and len(quads) == len(mesh.boundary_faces)
    assert {mesh.label_names[k - 1]: int(c) for k, c in zip(*np.unique(hexes, return_counts=True))} == labels
    assert {mesh.boundary_names[k - 1]: int(c) for k, c in zip(*np.unique(quads, return_counts=True))} == bounds


def test_xdmf(mesh, tmp_path):
    import meshio

    path = export_mesh(tmp_path / "m.xdmf", mesh)
    assert path.with_suffix(".h5").is_file()
    r = meshio.read(path)
    assert len(r.points) == mesh.n_points
    assert [(c.type, len(c.data)) for c in r.cells] == [("hexahedron", mesh.n_cells), ("quad", len(mesh.boundary_faces))]
    assert np.array_equal(r.cell_data["label"][0], mesh.cell_data["label"])
    assert np.array_equal(r.cell_data["boundary_id"][1], mesh.boundary_ids)


def _check_polymesh(poly, n_cells, points, bounds):
    """Counts, patch sizes, and OpenFOAM's orientation rules (as checkMesh would)."""
    assert poly["n_cells"] == n_cells and len(poly["points"]) == len(points)
    assert {k: v["nFaces"] for k, v in poly["patches"].items()} == bounds
    faces, own, nb = poly["faces"], poly["owner"], poly["neighbour"]
    assert len(faces) == len(own) == len(nb) + sum(bounds.values())
    assert (own[: len(nb)] < nb).all()
    assert (np.diff(own[: len(nb)]) >= 0).all()  # upper-triangular: sorted by owner
    p = poly["points"][faces]
    normal = np.cross(p[:, 2] - p[:, 0], p[:, 3] - p[:, 1])
    centre = np.zeros((n_cells, 3))
    np.add.at(centre, own, p.mean(axis=1))
    np.add.at(centre, nb, p[: len(nb)].mean(axis=1))
    centre /= np.bincount(np.r_[own, nb], minlength=n_cells)[:, None]
    out = np.einsum("ij,ij->i", normal, p.mean(axis=1) - centre[own])
    assert (out > 0).all()  # every face points away from its owner


def test_openfoam(mesh, tmp_path):
    import pyvista as pv

    from vmesh.io.openfoam import read_polymesh

    case = export_mesh(tmp_path / "case", mesh, "openfoam")
    labels, bounds = expected(mesh)
    _check_polymesh(read_polymesh(case), mesh.n_cells, mesh.points, bounds)
    assert {k: v["type"] for k, v in read_polymesh(case)["patches"].items()}["wall"] == "wall"
    reader = pv.OpenFOAMReader(str(case / "case.foam"))
    reader.enable_all_patch_arrays()
    data = reader.read()
    internal = data["internalMesh"]
    assert internal.n_cells == mesh.n_cells and internal.n_points == mesh.n_points
    assert set(np.unique(internal.celltypes)) == {12}  # VTK recognises every cell as a hexahedron
    assert {k: data["boundary"][k].n_cells for k in data["boundary"].keys()} == bounds


def unit_cube_mesh():
    """One hexahedron whose six faces are six named boundaries."""
    pts = np.array([[i, j, k] for k in (0, 1) for j in (0, 1) for i in (0, 1)], float)
    cells = np.arange(8)[None]
    faces = cells[0][tensor_faces(1)]  # i0, ip, j0, jp, k0, kp
    names = {b: n for b, n in enumerate(("x0", "x1", "y0", "y1", "z0", "z1"))}
    return HexMesh(points=pts, cells=cells, order=1, cell_data={"label": np.zeros(1, np.int64)},
                   boundary_faces=faces, boundary_ids=np.arange(6), boundary_cells=np.zeros(6, np.int64),
                   boundary_names=names, label_names={0: "vessel"})


def test_face_numbering_on_one_hexahedron(tmp_path):
    """All six local faces: Exodus sides via VTK's reader, Abaqus S1..S6 by the manual's table,
    OpenFOAM: six outward patches."""
    import meshio
    import pyvista as pv

    from vmesh.io.openfoam import read_polymesh

    m = unit_cube_mesh()
    assert boundary_local_faces(m).tolist() == list(range(6))
    normals = {"x0": [-1, 0, 0], "x1": [1, 0, 0], "y0": [0, -1, 0], "y1": [0, 1, 0], "z0": [0, 0, -1], "z1": [0, 0, 1]}
    data = pv.get_reader(str(export_mesh(tmp_path / "c.exo", m))).read()
    for name, n in normals.items():
        c = np.asarray(data["Side Sets"][name].cell_centers().points)[0]
        assert np.allclose(c, 0.5 + 0.5 * np.array(n), atol=1e-6), name
    # Abaqus C3D8 faces (node numbers 1..8): S1 1234, S2 5876, S3 1562, S4 2673, S5 3784, S6 4851
    abaqus = {1: [1, 2, 3, 4], 2: [5, 8, 7, 6], 3: [1, 5, 6, 2], 4: [2, 6, 7, 3], 5: [3, 7, 8, 4], 6: [4, 8, 5, 1]}
    path = export_mesh(tmp_path / "c.inp", m)
    r = meshio.read(path)
    corners = r.cells[0].data[0]
    text = path.read_text()
    for b, name in m.boundary_names.items():
        s = int(text.split(f"*SURFACE, NAME={name}, TYPE=ELEMENT\n")[1].split("\n")[0].split("S")[-1])
        nodes = r.points[corners[np.array(abaqus[s]) - 1]]
        assert np.allclose(nodes.mean(axis=0), 0.5 + 0.5 * np.array(normals[name])), name
    poly = read_polymesh(export_mesh(tmp_path / "cube", m, "openfoam"))
    _check_polymesh(poly, 1, m.points, {n: 1 for n in normals})


def test_second_order(mesh_p2, tmp_path):
    from vmesh.io.xdmf import read_cell_counts

    m = mesh_p2
    assert m.order == 2
    back = read_mesh_vtu(export_mesh(tmp_path / "q.vtu", m))
    assert back.order == 2 and back.n_cells == m.n_cells and back.n_points == m.n_points
    assert np.array_equal(back.cells, m.cells)
    assert read_cell_counts(export_mesh(tmp_path / "q.xdmf", m)) == {"hexahedron27": m.n_cells, "quad9": len(m.boundary_faces)}
    gmsh = pytest.importorskip("gmsh")
    path = export_mesh(tmp_path / "q.msh", m)
    gmsh.initialize()
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.open(str(path))
        types, tags, _ = gmsh.model.mesh.getElements(3)
        assert list(types) == [12] and sum(map(len, tags)) == m.n_cells  # hex27
        assert list(gmsh.model.mesh.getElements(2)[0]) == [10]  # quad9 boundary faces
        assert len(gmsh.model.mesh.getNodes()[0]) == m.n_points
        assert gmsh.model.mesh.getElementQualities(np.concatenate(tags), "minSJ").min() > 0
    finally:
        gmsh.finalize()


@pytest.mark.parametrize("name", ["openfoam", "abaqus", "exodus", "medit"])
def test_second_order_refused_or_linearized(mesh_p2, tmp_path, name):
    f = EXPORT_FORMATS[name]
    path = tmp_path / ("case" if f.folder else "q" + f.suffixes[0])
    with pytest.raises(ParameterError, match=r"holds hexahedra of order p <= 1, the mesh has p = 2") as err:
        export_mesh(path, mesh_p2, name)
    assert "\n" not in str(err.value)
    assert list(tmp_path.iterdir()) == []
    export_mesh(path, mesh_p2, name, linearize=True)
    assert path.exists()


def test_failed_write_leaves_nothing(mesh, tmp_path, monkeypatch):
    """Fail in the middle of writing (after part of the file is out): no file, no temporary."""
    from vmesh.io import gmsh as gmsh_writer
    from vmesh.io import openfoam

    calls = {"n": 0}
    real = np.savetxt

    def failing(*args, **kw):
        calls["n"] += 1
        if calls["n"] == 3:
            raise OSError("disk full")
        return real(*args, **kw)

    monkeypatch.setattr(gmsh_writer.np, "savetxt", failing)
    (tmp_path / "keep.txt").write_text("x")
    with pytest.raises(OSError, match="disk full"):
        export_mesh(tmp_path / "m.msh", mesh)
    assert calls["n"] == 3
    monkeypatch.setattr(gmsh_writer.np, "savetxt", real)
    # an OpenFOAM case fails after points and faces are written
    real_list = openfoam._list

    def failing_list(fh, header, rows, fmt):
        if "owner" in header:
            raise OSError("disk full")
        return real_list(fh, header, rows, fmt)

    monkeypatch.setattr(openfoam, "_list", failing_list)
    with pytest.raises(OSError):
        export_mesh(tmp_path / "case", mesh, "openfoam")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["keep.txt"]
    # an existing export stays as it was when its replacement fails
    monkeypatch.setattr(openfoam, "_list", real_list)
    export_mesh(tmp_path / "case", mesh, "openfoam")
    before = (tmp_path / "case" / "constant" / "polyMesh" / "owner").read_text()
    monkeypatch.setattr(openfoam, "_list", failing_list)
    with pytest.raises(OSError):
        export_mesh(tmp_path / "case", mesh, "openfoam")
    assert (tmp_path / "case" / "constant" / "polyMesh" / "owner").read_text() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["case", "keep.txt"]


def test_unknown_format(mesh, tmp_path):
    with pytest.raises(ParameterError, match="unknown export format '.xyz'"):
        export_mesh(tmp_path / "m.xyz", mesh)
    with pytest.raises(ParameterError, match="unknown export format 'stl'"):
        export_mesh(tmp_path / "m.msh", mesh, "stl")
    assert list(tmp_path.iterdir()) == []


def test_export_filter(mesh, tmp_path):
    from vmesh.context import Context
    from vmesh.registry import get_filter

    ctx = Context(mesh=mesh, stage_dir=tmp_path)
    get_filter("export_mesh")(ctx, filename="solver/m.inp")
    get_filter("export_mesh")(ctx, filename="foam", format="openfoam")
    assert (tmp_path / "solver" / "m.inp").is_file() and (tmp_path / "foam" / "constant" / "polyMesh" / "owner").is_file()
    with pytest.raises(ParameterError, match="unknown export format"):
        get_filter("export_mesh")(ctx, filename="m.abc")


def test_meshlab_layers_load_in_pymeshlab(y_run, mesh):
    """The default chain's export_meshlab: every PLY and the project load with the right counts."""
    import pymeshlab

    from vmesh.io.surface import read_surface

    folder = y_run / "meshlab"
    ms = pymeshlab.MeshSet()
    ms.load_project(str(folder / "vmesh.mlp"))
    layers = {ms.mesh(i).label(): ms.mesh(i) for i in range(ms.mesh_number())}
    assert set(layers) == {"surface", "coarse_surface", "boundary_label", "boundary_quality", "skeleton", "blocks_edges"}
    for name in ("surface", "coarse_surface"):
        s = read_surface(folder / f"{name}.ply")
        assert (layers[name].vertex_number(), layers[name].face_number()) == (s.n_vertices, s.n_faces)
    nb = len(mesh.boundary_faces)
    for name in ("boundary_label", "boundary_quality"):
        m = layers[name]
        assert m.vertex_number() == len(np.unique(mesh.boundary_faces))
        assert len(m.polygonal_face_list()) == nb and m.face_number() == 2 * nb  # quads, shown as 2 triangles
        assert m.has_face_color() and m.has_face_scalar()
    q = layers["boundary_quality"].face_scalar_array()
    sj = mesh.cell_data["scaled_jacobian"][mesh.boundary_cells]
    assert np.isclose(q.min(), sj.min(), atol=1e-5) and np.isclose(q.max(), sj.max(), atol=1e-5)
    assert len(np.unique(layers["boundary_label"].face_color_matrix(), axis=0)) == len(np.unique(mesh.cell_data["label"][mesh.boundary_cells]))
    from vmesh.io.skeleton import read_skeleton

    sk = read_skeleton(y_run / "skeleton.json")
    assert (layers["skeleton"].vertex_number(), layers["skeleton"].edge_number()) == (sk.n_nodes, sk.n_edges)
    assert layers["blocks_edges"].edge_number() > 0 and layers["blocks_edges"].face_number() == 0
    # each file also loads alone
    for f in folder.glob("*.ply"):
        one = pymeshlab.MeshSet()
        one.load_new_mesh(str(f))
        assert one.current_mesh().vertex_number() == layers[f.stem].vertex_number()


def test_meshlab_second_order_splits_faces(mesh_p2, tmp_path):
    import pymeshlab

    from vmesh.io.meshlab import write_meshlab_folder

    written = write_meshlab_folder(tmp_path / "ml", mesh_p2)
    ms = pymeshlab.MeshSet()
    ms.load_project(str(tmp_path / "ml" / "vmesh.mlp"))
    assert ms.mesh_number() == written["project"]["layers"] == 2
    assert len(ms.mesh(0).polygonal_face_list()) == 4 * len(mesh_p2.boundary_faces)  # p x p quads per face


def test_cli_export(y_run, capsys):
    assert main(["export", str(y_run), "--format", "msh,inp,exo,mesh,xdmf,openfoam,meshlab", "-q"]) == 0
    for name in ("mesh.msh", "mesh.inp", "mesh.exo", "mesh.mesh", "mesh.xdmf", "mesh.h5", "openfoam/constant/polyMesh/boundary", "meshlab/vmesh.mlp"):
        assert (y_run / name).is_file(), name
    assert not list(y_run.glob(".*partial*"))


def test_cli_export_bad_input(y_run, tmp_path, capsys):
    before = sorted(p.name for p in y_run.iterdir())
    assert main(["export", str(tmp_path / "missing"), "--format", "msh"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"vmesh: error: {tmp_path / 'missing'}: run folder not found"
    assert main(["export", str(y_run), "--format", "msh,xyz"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"vmesh: error: {y_run}: unknown export format 'xyz'") and "\n" not in err
    assert main(["export", str(tmp_path), "--format", "msh"]) == 2
    assert "no mesh.vtu" in capsys.readouterr().err
    assert sorted(p.name for p in y_run.iterdir()) == before


# --- every format read back by its real consumer, on a small labelled block mesh -----------


@pytest.fixture(scope="module")
def small():
    """A labelled cylinder (aneurysm and vessel regions; wall, inlet, outlet_1), 576 hexahedra."""
    from cfd_meshes import cylinder_mesh

    mesh, _ = cylinder_mesh(tags=[("inlet", "vessel"), ("aneurysm", "cap_end")])
    mesh.cell_data["scaled_jacobian"] = np.ones(mesh.n_cells)
    return mesh


def small_expected(mesh):
    labels, bounds = expected(mesh)
    assert labels == {"vessel": 288, "aneurysm": 288} and bounds == {"wall": 96, "inlet": 96, "outlet_1": 96}
    return labels, bounds


def gmsh_groups(path):
    """``{(dim, name): element count}`` of every physical group, as gmsh's own reader sees them."""
    gmsh = pytest.importorskip("gmsh")
    gmsh.initialize()
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.open(str(path))
        return {
            (dim, gmsh.model.getPhysicalName(dim, tag)): sum(len(gmsh.model.mesh.getElements(dim, e)[1][0]) for e in gmsh.model.getEntitiesForPhysicalGroup(dim, tag))
            for dim, tag in gmsh.model.getPhysicalGroups()
        }
    finally:
        gmsh.finalize()


def meshio_groups(path):
    """``{name: element count}`` of every named group as meshio reads a .msh (cell sets)."""
    import meshio

    r = meshio.read(path)
    return {k: sum(len(x) for x in v) for k, v in r.cell_sets.items() if not k.startswith("gmsh:")}, r


def test_round_trip_gmsh_meshio_and_gmsh_see_every_group(small, tmp_path):
    labels, bounds = small_expected(small)
    path = export_mesh(tmp_path / "m.msh", small)
    groups, r = meshio_groups(path)
    assert groups == {**labels, **bounds}  # volume and surface groups apart, none lost
    assert {k: int(v[1]) for k, v in r.field_data.items()} == {**{k: 3 for k in labels}, **{k: 2 for k in bounds}}
    assert sum(len(c.data) for c in r.cells if c.type == "hexahedron") == small.n_cells
    assert gmsh_groups(path) == {**{(3, k): v for k, v in labels.items()}, **{(2, k): v for k, v in bounds.items()}}
    assert "$Units\nmm\n$EndUnits" in path.read_text()[:200]


def test_gmsh_names_stay_distinct_for_old_labels(small, tmp_path):
    """A mesh labelled before labels were cleaned (a volume label named like a patch)."""
    import dataclasses

    old = dataclasses.replace(small, label_names={0: "aneurysm", 1: "inlet"})
    path = export_mesh(tmp_path / "old.msh", old)
    groups, _ = meshio_groups(path)
    assert groups == {"aneurysm": 288, "inlet_volume": 288, "wall": 96, "inlet": 96, "outlet_1": 96}
    assert gmsh_groups(path)[(3, "inlet_volume")] == 288


def test_round_trip_vtu_abaqus_exodus_medit_xdmf(small, tmp_path):
    import meshio

    from vmesh.io.abaqus import read_surfaces
    from vmesh.io.exodus import read_sets
    from vmesh.io.mesh import names_from_field_data, units_from_field_data

    labels, bounds = small_expected(small)
    for fmt in ("vtu", "inp", "exo", "mesh", "xdmf"):
        path = export_mesh(tmp_path / f"m.{fmt}", small)
        r = meshio.read(path)
        assert len(r.points) == small.n_points, fmt
        assert sum(len(c.data) for c in r.cells if c.type == "hexahedron") == small.n_cells, fmt
        if fmt == "vtu":
            assert {n: int((r.cell_data["label"][0] == k).sum()) for k, n in names_from_field_data(r.field_data, "label").items()} == labels
            assert units_from_field_data(r.field_data) == "mm"
        elif fmt == "inp":
            assert {k: sum(map(len, v)) for k, v in r.cell_sets.items() if k in labels} == labels
            assert read_surfaces(path) == bounds
            assert "** units: mm" in path.read_text()[:500]
        elif fmt == "exo":
            sets = read_sets(path)
            assert sets["blocks"] == labels and sets["side_sets"] == bounds
        elif fmt == "mesh":
            hexes, quads = r.cell_data["medit:ref"]
            assert {small.label_names[k - 1]: int(c) for k, c in zip(*np.unique(hexes, return_counts=True))} == labels
            assert {small.boundary_names[k - 1]: int(c) for k, c in zip(*np.unique(quads, return_counts=True))} == bounds
        elif fmt == "xdmf":
            assert {small.label_names[k]: int(c) for k, c in zip(*np.unique(r.cell_data["label"][0], return_counts=True))} == labels


def test_round_trip_meshlab_in_pymeshlab(small, tmp_path):
    import pymeshlab

    from vmesh.io.meshlab import write_meshlab_folder

    write_meshlab_folder(tmp_path / "ml", small)
    ms = pymeshlab.MeshSet()
    ms.load_project(str(tmp_path / "ml" / "vmesh.mlp"))
    layers = {ms.mesh(i).label(): ms.mesh(i) for i in range(ms.mesh_number())}
    assert len(layers["boundary_label"].polygonal_face_list()) == len(small.boundary_faces)
    # one colour per label on the boundary
    assert len(np.unique(layers["boundary_label"].face_color_matrix(), axis=0)) == 2


def test_round_trip_openfoam_zones_and_patches(small, tmp_path):
    """pyvista's OpenFOAM reader (and checkMesh where OpenFOAM is installed) see the patches
    and the label cellZones."""
    import pyvista as pv

    from vmesh.io.openfoam import read_polymesh

    labels, bounds = small_expected(small)
    case = export_mesh(tmp_path / "case", small, "openfoam")
    poly = read_polymesh(case)
    assert {k: v["nFaces"] for k, v in poly["patches"].items()} == bounds
    zones = (case / "constant" / "polyMesh" / "cellZones").read_text()
    for name, n in labels.items():
        assert f"{name}\n{{\n    type cellZone;\ncellLabels      List<label> \n{n}\n" in zones
    layer_sets = {p.name for p in (case / "constant" / "polyMesh" / "sets").iterdir()}
    assert layer_sets == {"core", "ring", "boundary_layer"}
    reader = pv.OpenFOAMReader(str(case / "case.foam"))
    data = reader.read()
    assert data["internalMesh"].n_cells == small.n_cells
    assert {k: data["boundary"][k].n_cells for k in data["boundary"].keys()} == bounds


def test_names_table_in_report(y_run):
    import json

    table = json.loads((y_run / "report.json").read_text())["labels"]["table"]
    names = {(row["kind"], row["name"]) for row in table}
    assert ("elements", "vessel") in names and ("boundary faces", "inlet") in names
    assert not any("+" in n or n.startswith(("inlet", "outlet")) for kind, n in names if kind == "elements")
    for row in table:
        assert row["name"] in row["msh"] and row["name"] in row["inp"] and row["name"] in row["openfoam"]


def test_cli_export_to_units(y_run, tmp_path, capsys):
    from vmesh.io.openfoam import read_polymesh

    mesh = read_run_mesh(y_run)
    assert main(["export", str(y_run), "--format", "openfoam", "--to-units", "m", "-o", str(tmp_path / "foam")]) == 0
    assert "lengths in m" in capsys.readouterr().out
    assert np.allclose(read_polymesh(tmp_path / "foam")["points"], mesh.points * 1e-3)
    assert main(["export", str(y_run), "--format", "msh", "--scale", "2", "-o", str(tmp_path / "s.msh")]) == 0
    import meshio

    assert np.allclose(meshio.read(tmp_path / "s.msh").points, mesh.points * 2)
