"""Side-branch stubs shorter than their junction's half cross-sections (issue 17).

The generator's ``stub`` feature cuts a side branch open one or two of its radii past its
parent's wall; ``thin_stubs`` leaves it one segment from the junction to its cap. When the
junction's half-sections reach as far along it as its cap, the blocks between the folded
end section and the cap section have no thickness and no fix can move a section: the
builder cuts the stub back into its parent (:mod:`vmesh.geometry.blocks.stubs`), warns and
records the cut; a stub with room for its blocks keeps them.
"""

from __future__ import annotations

import numpy as np
import pytest

from junction_cases import direction, side_stub
from vmesh.geometry.block_builder import BlockOptions, build_blocks
from vmesh.geometry.quality import scaled_jacobian
from vmesh.geometry.skeleton.graft import extend_to_caps
from vmesh.skeleton import Skeleton
from vmesh.geometry.transfinite import Refinement, mesh_blocks

#: the default chain's resolution and a finer one (as ``blocks.checks.FILL_CHECKS``)
REFINEMENTS = (Refinement(around=2, core=2, ring=2, layer=3, element_length=0.5, first_layer=0.02),
               Refinement(around=4, core=3, ring=3, layer=4, element_length=0.25, first_layer=0.01))


def _build(*args):
    case, caps = side_stub(*args)
    warnings = []
    blocks = build_blocks(case.skeleton, case.distance, caps, BlockOptions(), project=case.project, warn=warnings.append)
    return case, blocks, warnings


@pytest.mark.parametrize("args", [(55, 0.3, 1.0), (50, 0.4, 1.0)])
def test_short_stub_is_cut_back_into_its_parent(args):
    """A stub that ends within its junction's half-sections: valid blocks without it, the cut
    named by its cap in a warning and in ``info['cut_stubs']``, the cap left out of the
    boundary names."""
    case, blocks, warnings = _build(*args)
    assert blocks.corner_jacobians().min() > 0
    cut = blocks.info["cut_stubs"]
    assert [s["cap"] for s in cut] == ["outlet_2"]
    assert cut[0]["length"] <= cut[0]["reach"] + BlockOptions().junction.junction_margin * cut[0]["radius"]
    assert any("cut the side branch" in w and "'outlet_2'" in w for w in warnings)
    assert "outlet_2" not in blocks.boundary_names.values()
    sk = blocks.info["skeleton"]
    assert len(sk.junctions) == 0 and sk.n_nodes == case.skeleton.n_nodes - 1
    # the parent keeps both its open ends
    assert {"inlet", "outlet_1"} <= set(blocks.boundary_names.values())


def test_cut_stub_mouth_is_named_not_wall():
    """The parent's wall faces over a cut stub's mouth are a cap ``stub_1`` of their own (a
    missing branch never shows as wall): only faces over the mouth, all of them within the
    stub's radius of its axis, and the wall elsewhere keeps its label."""
    case, blocks, _ = _build(55, 0.3, 1.0)
    stub = blocks.info["cut_stubs"][0]
    assert stub["boundary"] == "stub_1"
    fid = [k for k, v in blocks.boundary_names.items() if v == "stub_1"]
    assert len(fid) == 1
    quads, ids = blocks.boundary_quads()
    mouth = blocks.vertices[quads[ids == fid[0]]].mean(axis=1)
    a0, a1 = np.asarray(stub["start"]), np.asarray(stub["end_point"])
    ax = (a1 - a0) / np.linalg.norm(a1 - a0)
    t = (mouth - a0) @ ax
    assert len(mouth) >= 1 and np.all(np.linalg.norm(mouth - a0 - t[:, None] * ax, axis=1) < stub["radius"])
    assert np.count_nonzero(ids == 0) > 10 * len(mouth)


def test_cut_stub_mouth_faces_of_the_mesh_are_those_of_its_named_block_faces():
    """The mesh names a wall face ``stub_k`` exactly where it lies on a block face so named
    (its element's block and that block's face, as the mesher made it): as many mesh faces
    as the named block faces hold elements, every one on such a face. Naming by the nearest
    block-face centre could give a wall face of a block next to the mouth the mouth's name."""
    from vmesh.blocks import FACE_WALL
    from vmesh.geometry.blocks.stubs import meshed_as_wall, name_stub_faces, stub_face_ids

    case, blocks, _ = _build(55, 0.3, 1.0)
    ref = REFINEMENTS[0]
    sm = mesh_blocks(meshed_as_wall(blocks), case.project, ref, signed_distance=case.distance)
    ids = name_stub_faces(blocks, sm.boundary_ids, sm.boundary_cells, sm.cell_block, sm.boundary_local_face)
    fid = stub_face_ids(blocks)
    named = np.isin(ids, fid)
    b = sm.cell_block[sm.boundary_cells]
    on_named = np.isin(blocks.face_boundary[b, sm.boundary_local_face], fid)
    assert named.any() and np.array_equal(named, on_named)
    assert np.array_equal(ids[~named], sm.boundary_ids[~named])  # every other face keeps its id
    # per named block face, its elements: the product of the block's counts along the face's two axes
    nb, f = np.nonzero(np.isin(blocks.face_boundary, fid))
    counts = sm.block_counts[nb]
    per_face = np.where(f // 2 == 0, counts[:, 1] * counts[:, 2], np.where(f // 2 == 1, counts[:, 0] * counts[:, 2], counts[:, 0] * counts[:, 1]))
    assert named.sum() == per_face.sum()


def test_cut_stub_fills_valid_at_every_refinement():
    """The parent without its stub fills with min scaled Jacobian >= 0.3 at the default and a
    finer resolution (no untangling)."""
    case, blocks, _ = _build(55, 0.3, 1.0)
    for ref in REFINEMENTS:
        sm = mesh_blocks(blocks, case.project, ref, signed_distance=case.distance)
        assert scaled_jacobian(sm.points, sm.cells, ref.order).min() >= 0.3


@pytest.mark.parametrize("args", [(90, 0.6, 2.0), (80, 0.6, 3.0)])
def test_stub_with_room_keeps_its_blocks(args):
    """A stub long enough for a block between its junction and its cap is not cut."""
    _, blocks, warnings = _build(*args)
    assert blocks.corner_jacobians().min() > 0
    assert blocks.info["cut_stubs"] == []
    assert "outlet_2" in blocks.boundary_names.values()
    assert not any("cut the side branch" in w for w in warnings)


def test_stub_cut_slant_at_its_parents_wall_is_cut_not_a_lost_section():
    """A thin stub (radius 0.12) cut open at its parent's wall by a plane 55 degrees off its
    axis (as a generated vessel's extracted skeleton has it: a 0.019 cm opening on a 0.07
    vessel): its cap section lies in that plane, half inside the parent, and its rays run 12
    stub radii through the parent's lumen without meeting the wall ("finds no wall within reach"). The stub is cut
    back into its parent instead, as any stub within its junction's half-sections."""
    case, blocks, warnings = _build(90, 0.12, 0.4, 8.0, 55)
    assert blocks.corner_jacobians().min() > 0
    assert [s["cap"] for s in blocks.info["cut_stubs"]] == ["outlet_2"]
    assert "outlet_2" not in blocks.boundary_names.values()
    assert any("cut the side branch" in w for w in warnings)


def _stub_skeleton_with_nodes(angle: float, ratio: float, length: float, n: int = 4) -> tuple:
    """``side_stub``'s vessel with the stub's centerline in ``n`` segments, as a given
    centerline has it (the generator's stub: nodes every stub radius or so)."""
    case, caps = side_stub(angle, ratio, length)
    sk = case.skeleton
    j = int(np.flatnonzero(sk.degrees == 3)[0])
    end = int(sk.endpoints[np.argmin(sk.radii[sk.endpoints])])
    inner = sk.points[j] + (sk.points[end] - sk.points[j]) * np.arange(1, n)[:, None] / n
    k = sk.n_nodes
    keep = sk.edges[~np.all(np.sort(sk.edges, axis=1) == sorted((j, end)), axis=1)]
    chain = [j, *range(k, k + n - 1), end]
    edges = np.r_[keep, np.c_[chain[:-1], chain[1:]]]
    out = Skeleton(np.r_[sk.points, inner], np.r_[sk.radii, np.full(n - 1, ratio)], edges)
    return out, caps, j, end


@pytest.mark.parametrize("turn", [100.0, 130.0])
def test_a_stub_cap_fitted_askew_keeps_its_branch(turn):
    """A stub ending against another vessel has a ragged rim whose fitted plane can face
    away from the stub (a generated stub's: 102 degrees off its axis), so that every
    node of the stub lies past it. ``extend_to_caps`` trimmed the whole stub and moved its
    junction onto the cap (the parent bent out to the cap, the stub gone, the cap counted
    as reached); the stub now stays whole and ends at its cap, the junction where it was."""
    sk, caps, j, end = _stub_skeleton_with_nodes(70, 0.4, 1.5)
    d = direction(70)
    # the cap's normal turned ``turn`` degrees from the stub's axis, the end just past it
    ez = np.array([0.0, 0.0, 1.0])
    n = np.cos(np.radians(turn)) * d + np.sin(np.radians(turn)) * ez
    stub_cap = caps[2]
    centre = sk.points[end] - 0.1 * stub_cap.radius * n
    h = (sk.points - centre) @ n
    chain = np.flatnonzero(np.linalg.norm(np.cross(sk.points - sk.points[j], d), axis=1) < 1e-9)
    assert np.all(h[np.setdiff1d(chain, [j])] > 1e-3 * stub_cap.radius)  # the whole stub past the plane
    C = np.array([c.center for c in caps[:2]] + [centre])
    N = np.array([c.normal for c in caps[:2]] + [n])
    R = np.array([c.radius for c in caps])
    out, matched = extend_to_caps(sk, C, N, R, [c.name for c in caps])
    assert (matched >= 0).all()
    assert out.n_nodes == sk.n_nodes and int((out.degrees == 3).sum()) == 1
    np.testing.assert_allclose(out.points[out.degrees == 3][0], sk.points[j], atol=1e-12)
    np.testing.assert_allclose(out.points[matched[2]], centre, atol=1e-9)
    # the stub's branch still leaves the junction along its axis
    nb = out.neighbors(int(np.flatnonzero(out.degrees == 3)[0]))
    assert any(abs((out.points[v] - sk.points[j]) @ d - np.linalg.norm(out.points[v] - sk.points[j])) < 1e-9 for v in nb)


@pytest.mark.parametrize("cap_x", [0.5, -0.5])
def test_a_cap_facing_along_its_branch_trims_the_branch_past_it(cap_x):
    """A T of straight centerlines (parent along y, junction at the origin, end branch nodes
    at x = 1, 2, 3) whose branch cap lies at x = ``cap_x`` facing +x, along the branch: the
    cap is the branch's cut, not fitted askew, so the nodes past it are trimmed (the whole
    branch, even when the junction is past the plane too) and no node of the final skeleton
    lies farther past the cap's plane than the junction, the branch's end on the plane."""
    parent = np.c_[np.zeros(7), np.arange(-3.0, 4.0), np.zeros(7)]
    branch = np.c_[np.arange(1.0, 4.0), np.zeros(3), np.zeros(3)]
    edges = np.r_[np.c_[np.arange(6), np.arange(1, 7)], [[3, 7], [7, 8], [8, 9]]]
    sk = Skeleton(np.r_[parent, branch], np.full(10, 0.4), edges)
    C = np.array([[0.0, -3.0, 0.0], [0.0, 3.0, 0.0], [cap_x, 0.0, 0.0]])
    N = np.array([[0.0, -1.0, 0.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]])
    out, matched = extend_to_caps(sk, C, N, np.full(3, 0.4), max_distance=10.0)
    assert (matched >= 0).all()
    height = (out.points - C[2]) @ N[2]
    assert height.max() <= max(-cap_x, 0.0) + 1e-9
    np.testing.assert_allclose(height[matched[2]], 0.0, atol=1e-9)


def _generated_stub(tmp_path, angle, ratio, length):
    """The generator's stub on a straight vessel (``stub_vessel``), written as the corpus
    writes a vessel; returns the surface and centerline paths."""
    from data_synthetic.vessel_generator import stub_vessel, write_vessel

    m = write_vessel(stub_vessel(angle, ratio, length), tmp_path / "v")
    return tmp_path / "v" / m["files"]["surface"], tmp_path / "v" / m["files"]["centerline_vtp"]


@pytest.mark.slow
@pytest.mark.parametrize("args, cut", [((70, 0.45, 2.0), False), ((90, 0.6, 1.5), False), ((55, 0.45, 1.5), True)])
def test_generated_stub_meshes_through_the_chain(tmp_path, args, cut):
    """The generator's stub (straight vessel, given centerline) meshes through the default
    chain: valid, min scaled Jacobian >= 0.3, coverage passed. A stub with room keeps its
    cap ``outlet_2``; one within its junction's half-sections (55 degrees, 1.5 radii) is cut
    and the coverage check still measures the whole wall (the small stub stays under its
    missing-part limit)."""
    from vmesh.chain import FilterChain

    surface, centerline = _generated_stub(tmp_path, *args)
    chain = FilterChain.load("default")
    chain.steps = [s for s in chain.steps if not s.filter.startswith("write")]
    ctx = chain.run(surface=surface, skeleton=centerline)
    assert ctx.report.sections["quality"]["scaled_jacobian"]["min"] >= 0.3
    assert ctx.report.sections["coverage"]["missing_parts"] == 0
    cuts = [s["cap"] for s in ctx.report.sections["blocks"]["cut_stubs"]]
    assert cuts == (["outlet_2"] if cut else [])
    assert ("outlet_2" in ctx.blocks.boundary_names.values()) is not cut
    if cut:  # the mouth is meshed as the wall it continues (nodes on the wall), named stub_1
        fid = [k for k, v in ctx.mesh.boundary_names.items() if v == "stub_1"]
        mouth = ctx.mesh.boundary_faces[np.isin(ctx.mesh.boundary_ids, fid)]
        assert len(mouth) > 0 and ctx.mesh.on_wall[mouth].all()


@pytest.mark.parametrize("args", [(70, 0.3, 1.0), (55, 0.3, 1.0), (90, 0.6, 2.0)])
def test_a_short_stubs_open_end_is_not_a_hole(tmp_path, args):
    """A stub cut one or two of its radii past its parent's wall: the generator's open end
    leaves a bevelled rim (radius 0.22 of the stub's 0.3 at 70 degrees) whose faces, and the
    parent's wall at the stub's mouth, lie nearly in the rim's plane. ``wall_hole_loops``
    took it for a hole; repair_surface filled it and the stub became a closed bump the builder
    could not close ("no wall found round the dome") or blocks stayed invalid at its junction.
    Past its flange the wall turns back along the stub (on one side only at 55 degrees, the
    parent's wall): an open end, not a hole, with ``wall_beyond`` (opt-in, see
    ``repair_surface.hole_wall_beyond``)."""
    from vmesh import repair as rp
    from vmesh.geometry import topology
    from vmesh.io import read_surface

    surface, _ = _generated_stub(tmp_path, *args)
    s = read_surface(surface)
    v, f = np.asarray(s.vertices, float), np.asarray(s.faces)
    assert all(len(h) <= 3 for h in rp.wall_hole_loops(v, f, wall_beyond=True))  # at most a triangle beside a pinched rim
    _, f2, _, _ = rp.repair(v, f, hole_wall_beyond=True)
    assert len(topology.boundary_loops(f2)) == 3  # both ends of the parent and the stub's


@pytest.mark.slow
@pytest.mark.parametrize("wall_beyond", [
    True,
    # the default chain (wall_beyond off) still fills the open end as a hole: kept tracked
    pytest.param(False, marks=pytest.mark.xfail(strict=True, reason="open (issue 17, docs/junctions.md): the default "
                                                "chain takes the short stub's bevelled open rim for a hole and fills it")),
])
def test_short_stub_meshes_with_its_open_end_kept(tmp_path, wall_beyond):
    """The generator's stub cut one radius past its parent's wall (radius 0.3, 70 degrees)
    fails the default chain ("closed end ... no wall found round the dome": its open end
    filled as a hole); with ``repair_surface.hole_wall_beyond`` it stays open and meshes,
    min scaled Jacobian >= 0.3, coverage passed, its cap named."""
    from vmesh.chain import FilterChain

    surface, centerline = _generated_stub(tmp_path, 70, 0.3, 1.0)
    chain = FilterChain.load("default").with_overrides({"repair_surface.hole_wall_beyond": wall_beyond})
    chain.steps = [s for s in chain.steps if not s.filter.startswith("write")]
    ctx = chain.run(surface=surface, skeleton=centerline)
    assert "filled_holes" not in ctx.report.sections["repair"] or not ctx.report.sections["repair"]["filled_holes"]
    assert ctx.report.sections["quality"]["scaled_jacobian"]["min"] >= 0.3
    assert ctx.report.sections["coverage"]["missing_parts"] == 0
    assert "outlet_2" in ctx.blocks.boundary_names.values()


@pytest.mark.parametrize("args", [(20, 0.3, 5.0), (30, 0.4, 4.0)])
def test_a_long_side_branch_is_no_stub_with_stub_within_reach(args):
    """A side branch five (four) of its radii past its parent's wall, leaving it 20 (30)
    degrees apart: the junction's half-sections run along the parent past its cap, so by
    default it is cut as a stub; with ``stub_within_reach`` (longer than ``REACH_RADII`` of
    its radii past the junction's radius: no half-section bounded by its own wall reaches
    that far) it is no stub, and the build fails rather than leave it out. A stub one radius
    past the wall is cut either way (docs/junctions.md h23/fans)."""
    from vmesh.errors import MeshingError

    case, caps = side_stub(*args)
    blocks = build_blocks(case.skeleton, case.distance, caps, BlockOptions(), project=case.project, warn=lambda m: None)
    assert [s["cap"] for s in blocks.info["cut_stubs"]] == ["outlet_2"]
    with pytest.raises(MeshingError, match="block.s. stay invalid"):  # the junction fails, the branch is not cut
        build_blocks(case.skeleton, case.distance, caps, BlockOptions(stub_within_reach=True), project=case.project, warn=lambda m: None)
    case, caps = side_stub(55, 0.3, 1.0)
    blocks = build_blocks(case.skeleton, case.distance, caps, BlockOptions(stub_within_reach=True), project=case.project, warn=lambda m: None)
    assert [s["cap"] for s in blocks.info["cut_stubs"]] == ["outlet_2"] and blocks.corner_jacobians().min() > 0
