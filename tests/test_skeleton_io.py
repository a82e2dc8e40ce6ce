"""Skeleton readers and writers: the real centerline files (VMTK, SimVascular, SWC),
format detection, round trips through every writer, and bad input."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from conftest import synthetic_case
from vmesh.caps import Cap
from vmesh.context import Context
from vmesh.errors import InputError
from vmesh.geometry import skeleton_ops as ops
from vmesh.geometry.topology import boundary_loops
from vmesh.io import skeleton_formats as fmt
from vmesh.io.skeleton import SKELETON_READERS, SKELETON_WRITERS, read_skeleton, write_skeleton
from vmesh.io.surface import read_surface
from vmesh.registry import get_filter
from vmesh.skeleton import Skeleton


def closed_with_caps(surface):
    """Close every boundary loop with a fan around its centroid; return (V, F, caps).

    Cap normals point away from the vessel (away from the surface behind the rim).
    """
    V, F = surface.vertices, surface.faces
    new_v, new_f, caps = [], [], []
    for k, loop in enumerate(boundary_loops(F), 1):
        rim = V[loop]
        centre = rim.mean(axis=0)
        radius = float(np.linalg.norm(rim - centre, axis=1).mean())
        normal = np.linalg.svd(rim - centre)[2][2]
        behind = V[np.linalg.norm(V - centre, axis=1) < 3 * radius].mean(axis=0)
        if (behind - centre) @ normal > 0:
            normal = -normal
        caps.append(Cap(k, f"cap_{k}", centre, normal, radius, rim))
        c = len(V) + len(new_v)
        new_v.append(centre)
        new_f.append(np.c_[np.roll(loop, -1), loop, np.full(len(loop), c)])
    if new_v:
        V, F = np.r_[V, np.asarray(new_v)], np.r_[F, *new_f]
    return V, F, caps


def winding(V, F, points):
    import igl

    return np.abs(igl.fast_winding_number(np.asarray(V, float), np.asarray(F, np.int64), np.asarray(points, float)))


def counts(skel):
    s = skel.summary()
    return s["nodes"], s["segments"], s["junctions"], s["endpoints"], s["cycles"], s["components"]


# ---------------------------------------------------------------------------
# real centerline files
# ---------------------------------------------------------------------------


def test_vmtk_carotid_merges_into_one_bifurcation(real_path):
    path = real_path("carotid_vmtk_centerline.vtp")
    import pyvista as pv

    mesh = pv.read(str(path))
    assert fmt.vtk_centerline_kind(mesh) == "vmtk"
    skel = read_skeleton(path)
    n, e, j, ends, cycles, comps = counts(skel)
    assert (j, ends, cycles, comps) == (1, 3, 0, 1) and e == n - 1
    assert skel.degrees[skel.junctions[0]] == 3
    assert n < mesh.n_points  # the shared trunk is stored once
    assert np.isfinite(skel.radii).all() and (skel.radii > 0).all()
    tags = [skel.node_tags[i] for i in skel.endpoints]
    assert sorted(t for tt in tags for t in tt) == ["inlet", "outlet", "outlet"]
    # the junction sits where the lines separate: on both daughter lines' common trunk,
    # more than a radius before the carina
    surface = read_surface(real_path("carotid_vmtk.vtp"))
    assert (winding(surface.vertices, surface.faces, skel.points) > 0.5).all()
    trunk = ops.arc_length(skel.points[ops.branch_tree(skel).paths[0]])[-1]
    assert 25 < trunk < 45


def test_vmtk_cell_group_ids_become_segment_tags(tmp_path):
    """Session 22: VMTK centerlines kept point arrays only, so vmtkbranchextractor's cell
    array ``GroupIds`` was dropped; each segment now carries the group of its tract (a
    joint point belongs to both tracts, a segment to the tract of both its ends)."""
    import pyvista as pv

    trunk = np.c_[np.linspace(0, 10, 21), np.zeros(21), np.zeros(21)]
    pts, cells, groups, centerline, tract = [], [], [], [], []
    for c, side in enumerate((1.0, -1.0)):  # two inlet-to-outlet lines sharing the trunk
        branch = np.c_[np.linspace(10, 15, 11), side * np.linspace(0, 5, 11), np.zeros(11)]
        for t, piece in enumerate((trunk, branch)):  # the branch tract repeats the joint point
            start = sum(len(p) for p in pts)
            pts.append(piece)
            cells.append([len(piece), *range(start, start + len(piece))])
            groups.append(0 if t == 0 else 1 + c)
            centerline.append(c)
            tract.append(t)
    mesh = pv.PolyData(np.concatenate(pts), lines=np.concatenate(cells))
    mesh.cell_data["GroupIds"] = np.array(groups)
    mesh.cell_data["CenterlineIds"] = np.array(centerline)
    mesh.cell_data["TractIds"] = np.array(tract)
    mesh.point_data["MaximumInscribedSphereRadius"] = np.full(mesh.n_points, 1.0)
    mesh.save(tmp_path / "groups.vtp")
    skel = read_skeleton(tmp_path / "groups.vtp")
    assert fmt.vtk_centerline_kind(mesh) == "vmtk" and skel.summary()["junctions"] == 1
    assert all(len(t) == 1 for t in skel.edge_tags)  # one group per segment
    mid = skel.points[skel.edges].mean(axis=1)
    expect = np.where(mid[:, 0] < 10, "group_0", np.where(mid[:, 1] > 0, "group_1", "group_2"))
    assert [t[0] for t in skel.edge_tags] == expect.tolist()
    assert sorted(t for e in skel.endpoints.tolist() for t in skel.node_tags[e]) == ["inlet", "outlet", "outlet"]


def test_vmtk_thoracic_aorta(real_path):
    skel = read_skeleton(real_path("thoracic_aorta_centerlines.vtp"))
    n, e, j, ends, cycles, comps = counts(skel)
    assert (j, ends, cycles, comps) == (3, 5, 0, 1) and e == n - 1
    # the supra-aortic lines run on past the open ends of the (clipped) surface: every node
    # is inside the capped surface or beyond one of its caps
    surface = read_surface(real_path("thoracic_aorta_open.vtp"))
    V, F, caps = closed_with_caps(surface)
    inside = winding(V, F, skel.points) > 0.5
    beyond = np.zeros(skel.n_nodes, bool)
    for c in caps:
        beyond |= (skel.points - c.center) @ c.normal > 0
    assert inside.mean() > 0.9 and (inside | beyond).all()


@pytest.mark.slow
def test_thoracic_aorta_cleaned_against_its_caps(real_path):
    """clean_skeleton cuts the lines at the caps they run through, ends the branches on
    the caps and merges the two arch junctions 0.4 radii apart (without grafting: the
    grafted descending aorta is tested in test_skeleton_ops)."""
    from vmesh.geometry.sdf import SignedDistance

    surface = read_surface(real_path("thoracic_aorta_open.vtp"))
    V, F, caps = closed_with_caps(surface)
    ctx = Context(surface=surface, skeleton=read_skeleton(real_path("thoracic_aorta_centerlines.vtp")), sdf=SignedDistance(V, F), caps=caps)
    get_filter("clean_skeleton")(ctx, graft_to_caps=False)
    skel = ctx.skeleton
    assert ctx.report.counts["cut_at_caps"] == 4 and ctx.report.counts["ends_at_caps"] == 5
    assert counts(skel)[2:] == (2, 5, 0, 1)
    assert skel.degrees.max() == 4
    # one open end (the descending aorta) has no centerline: reported
    assert any("no skeleton end near cap" in w for w in ctx.report.warnings)
    ends = skel.endpoints
    at_cap = np.linalg.norm(skel.points[ends][:, None] - np.array([c.center for c in caps])[None], axis=2).min(axis=1)
    assert at_cap.max() < 1e-9
    inner = skel.degrees != 1
    assert (winding(V, F, skel.points[inner]) > 0.5).all()
    assert "inlet" in sum((skel.node_tags[e] for e in ends), ())


def test_simvascular_centerline_graph(real_path):
    path = real_path("aorta_simvascular_demo_centerlines.vtp")
    import pyvista as pv

    assert fmt.vtk_centerline_kind(pv.read(str(path))) == "simvascular"
    skel = read_skeleton(path)
    assert counts(skel) == (1274, 1273, 1, 3, 0, 1)
    assert {"branch_0", "branch_1", "branch_2", "bifurcation_0", "inlet", "outlet"} <= set(skel.tag_names())
    assert "bifurcation_0" in skel.node_tags[skel.junctions[0]]
    inlet = [e for e in skel.endpoints if "inlet" in skel.node_tags[e]]
    assert len(inlet) == 1 and "branch_0" in skel.node_tags[inlet[0]]
    # segment tags come from their nodes
    assert sum("branch_1" in t for t in skel.edge_tags) > 300
    surface = read_surface(real_path("aorta_simvascular_demo.vtp"))
    w = winding(surface.vertices, surface.faces, skel.points)
    inner = skel.degrees != 1
    assert (w[inner] > 0.5).all()
    # end nodes lie on the flat caps
    import igl

    d = np.sqrt(igl.point_mesh_squared_distance(skel.points[~inner], surface.vertices, surface.faces)[0])
    assert (d < 0.01 * skel.radii[~inner]).all()


def test_swc_internal_carotid(real_path):
    skel = read_skeleton(real_path("ica_centerline.swc"))
    assert counts(skel) == (96, 95, 2, 4, 0, 1)
    assert set(skel.tag_names()) == {"swc_type_1", "swc_type_3"}
    assert "swc_type_1" in skel.node_tags[0] and skel.degrees[0] == 1
    np.testing.assert_allclose(skel.points[0], [65.35923767089844, 2.456251859664917, 61.297576904296875])
    assert abs(skel.radii[0] - 1.9054933785222485) < 1e-12
    surface = read_surface(real_path("ica_swc_surface.vtp"))
    assert (winding(surface.vertices, surface.faces, skel.points) > 0.5).all()


# ---------------------------------------------------------------------------
# round trips
# ---------------------------------------------------------------------------


def tagged_skeleton():
    path = synthetic_case("aneurysm")[1]
    if not path.exists():
        pytest.skip("synthetic case aneurysm not generated")
    return read_skeleton(path)


def matched(a: Skeleton, b: Skeleton) -> np.ndarray:
    """Index in ``b`` of every node of ``a`` (by position)."""
    d, idx = cKDTree(b.points).query(a.points)
    assert d.max() < 1e-6
    assert len(np.unique(idx)) == a.n_nodes
    return idx


def edge_set(skel, index=None):
    e = skel.edges if index is None else index[skel.edges]
    return {tuple(sorted(x)) for x in e.tolist()}


@pytest.mark.parametrize("suffix", [".json", ".vtp", ".vtk", ".csv", ".swc", ".ply"])
def test_writers_round_trip(tmp_path, suffix):
    skel = tagged_skeleton()
    skel.edge_tags = [t + (f"e{k % 3}",) for k, t in enumerate(skel.edge_tags)]
    write_skeleton(tmp_path / f"skel{suffix}", skel)
    back = read_skeleton(tmp_path / f"skel{suffix}")
    assert counts(back) == counts(skel)
    idx = matched(skel, back)
    assert edge_set(skel, idx) == edge_set(back)
    np.testing.assert_allclose(back.radii[idx], skel.radii, rtol=1e-6)
    if suffix in (".json", ".vtp", ".vtk", ".csv"):  # formats that store tags
        assert [back.node_tags[i] for i in idx] == skel.node_tags
        lookup = {tuple(sorted(e)): t for e, t in zip(back.edges.tolist(), back.edge_tags)}
        assert [lookup[tuple(sorted(e))] for e in idx[skel.edges].tolist()] == skel.edge_tags


def test_swc_keeps_types_and_refuses_cycles(tmp_path):
    skel = Skeleton([[0, 0, 0], [1, 0, 0], [2, 0, 0]], [1, 1, 1], [[0, 1], [1, 2]], [("swc_type_1",), (), ("swc_type_7",)])
    back = read_skeleton(write_skeleton(tmp_path / "a.swc", skel))
    assert back.node_tags[0] == ("swc_type_1",) and back.node_tags[2] == ("swc_type_7",)
    assert back.node_tags[1] == ("swc_type_0",)
    ring = Skeleton([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [1, 1, 1], [[0, 1], [1, 2], [2, 0]])
    with pytest.raises(InputError, match="cycle"):
        write_skeleton(tmp_path / "ring.swc", ring)
    assert not (tmp_path / "ring.swc").exists()


def test_swc_carries_other_tags_as_named_custom_types(tmp_path):
    """Branch and node tags survive SWC: custom types from 10 up, named in '# vmesh tag' lines."""
    skel = Skeleton(
        [[0, 0, 0], [1, 0, 0], [2, 0, 0], [2, 1, 0]],
        [1, 1, 1, 1],
        [[0, 1], [1, 2], [2, 3]],
        [("swc_type_1",), (), ("aneurysm",), ()],
        [("branch_0",), ("branch_1",), ("branch_1",)],
    )
    path = write_skeleton(tmp_path / "t.swc", skel)
    assert "# vmesh tag 10 branch_0" in path.read_text()
    back = read_skeleton(path)
    assert back.node_tags[0] == ("swc_type_1",)  # an SWC type stays itself
    assert back.node_tags[1] == ("branch_0",)  # the tag of the segment to its parent
    assert set(back.node_tags[2]) == {"aneurysm", "branch_1"} and back.node_tags[3] == ("branch_1",)
    edge = {tuple(sorted(e)): set(t) for e, t in zip(back.edges.tolist(), back.edge_tags)}
    assert edge[(0, 1)] == {"branch_0"} and edge[(2, 3)] == {"branch_1"} and "branch_1" in edge[(1, 2)]


def test_ply_edge_mesh_opens_in_pymeshlab(tmp_path):
    import pymeshlab

    skel = tagged_skeleton()
    path = write_skeleton(tmp_path / "edges.ply", skel)
    ms = pymeshlab.MeshSet()
    ms.load_new_mesh(str(path))
    m = ms.current_mesh()
    assert m.vertex_number() == skel.n_nodes and m.edge_number() == skel.n_edges and m.face_number() == 0
    np.testing.assert_allclose(m.vertex_matrix(), skel.points, atol=1e-6)
    np.testing.assert_allclose(m.vertex_scalar_array(), skel.radii, rtol=1e-6)  # quality = radius



@pytest.mark.parametrize("order", ["<", ">"])
def test_binary_ply_edge_mesh(tmp_path, order):
    skel = tagged_skeleton()
    endian = "little" if order == "<" else "big"
    head = (
        f"ply\nformat binary_{endian}_endian 1.0\nelement vertex {skel.n_nodes}\nproperty float x\nproperty float y\n"
        f"property float z\nproperty float radius\nelement face 1\nproperty list uchar int vertex_indices\n"
        f"element edge {skel.n_edges}\nproperty int vertex1\nproperty int vertex2\nend_header\n"
    )
    vert = np.c_[skel.points, skel.radii].astype(order + "f4").tobytes()
    face = np.array([3], "u1").tobytes() + np.array([0, 1, 2], order + "i4").tobytes()
    edges = skel.edges.astype(order + "i4").tobytes()
    path = tmp_path / "binary.ply"
    path.write_bytes(head.encode() + vert + face + edges)
    back = read_skeleton(path)
    assert edge_set(back) == edge_set(skel)
    np.testing.assert_allclose(back.points, skel.points, atol=1e-4)
    np.testing.assert_allclose(back.radii, skel.radii, rtol=1e-6)


def test_csv_folder_single_file_and_parent_column(tmp_path):
    skel = tagged_skeleton()
    folder = tmp_path / "case"
    folder.mkdir()
    write_skeleton(folder / "nodes.csv", skel)
    assert (folder / "edges.csv").exists()
    for given in (folder, folder / "nodes.csv", folder / "edges.csv"):
        assert counts(read_skeleton(given)) == counts(skel)
    (tmp_path / "tree_nodes.csv").write_text("id,x,y,z,radius,parent\n1,0,0,0,2,-1\n2,1,0,0,,1\n3,2,0,0,1.5,2\n")
    tree = read_skeleton(tmp_path / "tree_nodes.csv")
    assert counts(tree) == (3, 2, 0, 2, 0, 1) and np.isnan(tree.radii[1])


def test_plain_polylines_without_radius_get_radii_from_the_sdf(tmp_path):
    import pyvista as pv

    from vmesh.geometry.sdf import SignedDistance

    surface_path, skel_path = synthetic_case("y_bifurcation")
    if not skel_path.exists():
        pytest.skip("synthetic case y_bifurcation not generated")
    gt = read_skeleton(skel_path)
    # three separate polylines that only share coordinates (not point ids) at the junction
    pts, lines = [], []
    for p in ops.branch_paths(gt.n_nodes, gt.edges):
        lines.append(np.r_[len(p), np.arange(len(pts), len(pts) + len(p))])
        pts.extend(gt.points[p])
    mesh = pv.PolyData(np.asarray(pts), lines=np.concatenate(lines))
    mesh.save(str(tmp_path / "plain.vtp"))
    assert fmt.vtk_centerline_kind(pv.read(str(tmp_path / "plain.vtp"))) == "polylines"
    skel = read_skeleton(tmp_path / "plain.vtp")
    assert counts(skel) == counts(gt) and np.isnan(skel.radii).all()
    surface = read_surface(surface_path)
    ctx = Context(surface=surface, skeleton=skel, sdf=SignedDistance.from_surface(surface))
    get_filter("estimate_radii")(ctx)
    idx = matched(ctx.skeleton, gt)
    inner = ctx.skeleton.degrees == 2
    np.testing.assert_allclose(ctx.skeleton.radii[inner], gt.radii[idx][inner], rtol=0.05)
    assert np.isfinite(ctx.skeleton.radii).all()
    with pytest.raises(InputError, match="no radii"):
        get_filter("estimate_radii")(Context(skeleton=skel))


def test_load_skeleton_filter_options(real_path):
    path = real_path("carotid_vmtk_centerline.vtp")
    sizes = {}
    for kind, tol in (("vmtk", 0.2), ("vmtk", 0.5), ("polylines", 0.2)):
        ctx = Context()
        get_filter("load_skeleton")(ctx, path=str(path), vtk_kind=kind, merge_tolerance=tol)
        assert counts(ctx.skeleton)[2:] == (1, 3, 0, 1)
        sizes[kind, tol] = ctx.skeleton.n_nodes
    # plain polylines only weld identical points (the lines split where they stop being
    # identical); a larger tolerance moves the junction downstream
    assert sizes["polylines", 0.2] > sizes["vmtk", 0.2] > sizes["vmtk", 0.5]
    with pytest.raises(InputError):
        get_filter("load_skeleton")(Context())


def test_registered_formats():
    for suffix in (".json", ".vtp", ".vtk", ".swc", ".csv", ".ply"):
        assert suffix in SKELETON_READERS and suffix in SKELETON_WRITERS


# ---------------------------------------------------------------------------
# bad input: one-line errors naming the file
# ---------------------------------------------------------------------------

BAD = {
    "empty.swc": "",
    "columns.swc": "1 1 0 0 0\n",
    "text.swc": "1 1 a 0 0 1 -1\n",
    "parent.swc": "1 1 0 0 0 1 -1\n2 3 1 0 0 1 9\n",
    "dup.swc": "1 1 0 0 0 1 -1\n1 3 1 0 0 1 1\n",
    "bad.json": "{not json",
    "noedges.json": '{"nodes": []}',
    "dangling.json": '{"nodes": [{"id": 0, "xyz": [0, 0, 0]}], "edges": [[0, 5]]}',
    "nan.csv": "id,x,y,z\n0,nan,0,0\n",
    "noxyz_nodes.csv": "id,a,b\n0,1,2\n",
    "faces.ply": "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
    "element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n",
    "short.ply": "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement edge 1\n"
    "property int vertex1\nproperty int vertex2\nend_header\n0 0 0\n",
    "garbage.vtp": "this is not vtk",
    "unknown.xyz": "1 2 3",
}


@pytest.mark.parametrize("name", sorted(BAD))
def test_bad_files_fail_with_one_line(tmp_path, name):
    path = tmp_path / name
    path.write_text(BAD[name])
    with pytest.raises(InputError) as info:
        read_skeleton(path)
    message = str(info.value)
    assert name in message and "\n" not in message


def test_surface_given_as_centerline(tmp_path, real_path):
    with pytest.raises(InputError, match="no line"):
        read_skeleton(real_path("carotid_vmtk.vtp"))
    with pytest.raises(InputError, match="not found"):
        read_skeleton(tmp_path / "missing.vtp")
    with pytest.raises(InputError, match="edge file not found"):
        (tmp_path / "lonely_nodes.csv").write_text("id,x,y,z\n0,0,0,0\n")
        read_skeleton(tmp_path / "lonely_nodes.csv")
    with pytest.raises(InputError, match="unknown skeleton format"):
        write_skeleton(tmp_path / "x.stl", Skeleton([[0, 0, 0]], [1], np.zeros((0, 2))))
