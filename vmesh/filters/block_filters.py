"""Block-structure filters: build the hexahedral block structure and write it out.

Thin wrappers around :mod:`vmesh.geometry.block_builder` (assembly, validity fixes) and
:mod:`vmesh.geometry.cross_sections` (templates, planes, frames, junction schemes).
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np

from ..errors import ChainError, ParameterError
from ..registry import Parameter, register_filter


@register_filter(
    description="Build the hexahedral block structure from the skeleton: O-grid cross-sections, junction half-sections, twist-free frames, valid blocks.",
    parameters=[
        Parameter("blocks_around", "int", 8, "Blocks around the circumference (even; the core is a x b with 2(a+b) of them: 6 -> 1x2, 8 -> 2x2, 10 -> 3x2). 4 (a 1x1 core) only for skeletons without junctions.", min=4, max=64, multiple_of=2),
        Parameter("core_size", "float", 0.3, "Half-width of the core relative to the distance from the section centre to the wall.", unit="× wall distance", min=0.05, max=0.6),
        Parameter("layer_thickness", "float", 0.3, "Thickness of the boundary-layer block ring relative to the distance to the wall.", unit="× wall distance", min=0.02, max=0.6),
        Parameter("plane_bias", "float", 1.0, "Turn bisecting planes towards perpendicular to the shorter of their two segments: weights (radius / length) ** bias (0: plain bisector).", min=0.0, max=4.0),
        Parameter("junction_rotation", "str", "closest", "Rotation of each junction half-plane about the junction axis: 'closest' keeps the half cross-section closest to the junction node on average (within room for the branches' first blocks), 'bisector' keeps the bisector.", choices=("closest", "bisector")),
        Parameter("rotation_range", "float", 0.6, "How far a half-plane may turn from the bisector towards a branch, as a fraction of half the angle between the two branches.", min=0.0, max=0.95),
        Parameter("max_out_of_plane", "float", 60.0, "Largest angle between a junction's branch and the junction plane (the plane normal to its axis).", unit="degrees", min=5.0, max=85.0),
        Parameter("min_branch_gap", "float", 12.0, "Smallest angle between consecutive branches around a junction axis.", unit="degrees", min=1.0, max=90.0),
        Parameter("split_nonplanar", "bool", True, "When blocks stay invalid, change the skeleton and rebuild instead of failing: split junctions of 4 or more branches (too far from planar, or whose blocks cannot be fixed) into chains of 3-junctions (new nodes up to 1.2 radii along a pair of branches, alternative pairings in turn), and merge two junctions whose half cross-sections leave the branch between them no room into one (split again if need be)."),
        Parameter("clear_ray_factor", "float", 1.8, "Near a junction, a branch's cross-section is clear of the other branches when no ray from its centre to the wall is longer than this many branch radii.", unit="× radius", min=1.1, max=10.0),
        Parameter("junction_margin", "float", 0.3, "Least distance between a junction's half cross-sections and a branch's first cross-section.", unit="× radius", min=0.0, max=5.0),
        Parameter("cap_distance", "float", 1.0, "An endpoint is the open end of a cap when it lies within this many radii of the cap centre.", unit="× radius", min=0.0, max=20.0),
        Parameter("dome_depth", "float", 1.0, "A closed end (a dome without cap, such as an aneurysm sac) ends in a cap of blocks that carries the boundary layer round the dome; its last cross-section moves back from the endpoint until the wall ahead along the axis is at least this many times its mean distance to the wall in the section.", unit="× wall distance", min=0.0, max=5.0),
        Parameter("dome_max_retreat", "float", 1.5, "How far a closed end's last cross-section may move back from its endpoint (at most half its branch).", unit="× radius", min=0.0, max=10.0),
        Parameter("dome_keep", "float", 0.0, "How far a closed end's last cross-section stays back from its endpoint where its junction's half-sections take the room of its dome (a closed branch shorter than they need). 0: it may reach the endpoint; where that is the dome's tip, on the wall, the cap of blocks round the dome has no height (collapsed elements).", unit="× radius", min=0.0, max=1.0),
        Parameter("max_fix_rounds", "int", 16, "Rounds of repairs of invalid blocks before failing.", min=0, max=100),
        Parameter("junction_centre", "float", 1.0, "Where a junction's half cross-sections meet: 0 on the skeleton node, 1 at the centre of the wall points straight out between its branches (each crotch's apex and the outer walls), as vascularmd places a bifurcation's centre; blends in between.", min=0.0, max=1.0),
        Parameter("relieve_wall_folds", "bool", True, "Where a junction's boundary-layer blocks would still fold once projected on the wall, try further first cross-sections and other half-plane rotations, judged by filling the junction's blocks (costs seconds per junction)."),
        Parameter("check_wall_projection", "bool", True, "Also check boundary-layer blocks with their wall faces projected onto the wall, and thicken the layer (up to 0.5) where they would fold."),
        Parameter("own_territory", "bool", True, "Cut cross-section rays where they cross into a touching vessel (one whose way along the skeleton is much longer than the straight way), so that each vessel's blocks stay in its own lumen."),
        Parameter("centre_sections", "float", 0.0, "Move a regular cross-section's skeleton node (in its plane) to the middle of the section's chords where it lies more than this share of its rays' mean reach off that middle and the middle is deeper in the lumen (a skeleton wandering over a flattened lumen's wide side, whose tilted sections cross; 0: never; docs/junctions.md h25/realbuild).", unit="× mean ray", min=0.0, max=1.0),
        Parameter("junction_lean", "float", 1.0, "How far the half cross-sections of a junction of 4 or more branches that leave its plane unalike may lean about its axis towards the true bisector of their branches (0: half-planes).", min=0.0, max=1.5),
        Parameter("choose_lean", "bool", False, "Where a junction of 4 or more branches leans, also build it with half-planes from the start, finish both, and keep per junction the choice whose blocks there and at the junctions one branch away have the higher least corner scaled Jacobian (up to twice the block-building time on such trees; off by default, docs/junctions.md h14/trif)."),
        Parameter("cut_contacts", "bool", True, "Where two vessels pass in contact with no junction between them, mesh them apart: a planar cut on the radical plane between their axes is part of the wall for every later stage (rays, projection, optimisers); the fused neck's surface is left out (report.json: blocks.contact_cuts)."),
        Parameter("dent_sections", "int", 2, "Rounds of cross-sections added halfway along the skeleton segments whose boundary-layer blocks would fold once their wall faces are projected onto the wall (the wall dipping between two sections): each round halves those segments, builds the structure again, and keeps the halvings whose own blocks fold in the transfinite fill and fill better with them, where the stretch around them then fills better (up to two more builds and four fills a round; 0: none; needs check_wall_projection).", min=0, max=5),
        Parameter("saddle_split", "float", 0.5, "Where the straight wall faces of a junction end's first block column (from the half cross-sections to the branch's first cross-section) dip this many boundary-layer thicknesses or more outside the wall (the saddle beside a crotch), split the column there with a cross-section of its own that follows the wall, up to three times (0: never; docs/junctions.md h20/crotch).", unit="× layer thickness", min=0.0, max=5.0),
        Parameter("stub_within_reach", "bool", False, "Cut a side branch back into its parent as a stub (left unmeshed, named in the report) only where it ends within 3 of its own radii past its junction's radius; off: wherever it ends within its junction's half cross-sections, which a junction whose half-sections run along a fused neighbour stretches over real branches (a 5.8-long branch of radius 0.36 in seed 1 g0000 given; docs/junctions.md h23/fans)."),
        Parameter("short_end_rays", "float", 0.5, "An open end's cross-section whose rays reach less than this share of the previous section's at the same azimuth (its plane cuts the wall short: a flat closed end taken for an opening, a voxel staircase's terraces) moves half way back towards that section, kept when its shortest share rises (0: never; docs/optimiser.md).", min=0.0, max=1.0),
        Parameter("bend_drops", "int", 0, "Only where every other try failed: rounds of building again without the skeleton node at a bend whose cross-section, straightened as far as it goes, still crosses its neighbour within the reach of its rays (a skeleton wandering over a flattened lumen's wide side; 0: never, the default: it won no run of the corpora, docs/junctions.md h24/realbuild); all rounds together get one extra work_budget.", min=0, max=3),
        Parameter("reroot_backwards", "bool", False, "After every other try failed: where a junction's thin branch leaves backwards and runs inside the lumen of the branch to a close neighbour junction until past its middle (its tube, not only its axis), re-root it at that neighbour (through its first node whose tube clears that lumen) and build again on a budget of its own; taken only where the blocks still cover the pair's wall; where the re-rooted branch's new first node at the deepest point of its section fails, 16 ring placements around the section's centre are tried, each on an eighth of a budget (opt-in: failing runs take up to four times as long, each crowded pair tried getting a work budget of its own and its ring two more; docs/junctions.md)."),
        Parameter("poor_block_sj", "float", 0.0, "Valid blocks whose least corner scaled Jacobian is below this get, segment by segment, first the extra margin the fix loop gave their junction ends back (sections moved half a radius towards the junction), then the repairs of invalid blocks (sections moved from junctions, half-planes re-rotated, planes straightened, cores shrunk), round by round, each round kept only where the poor blocks get better and no block falls below the least before (0: never; a block's fill cannot be better than the block: docs/optimiser.md h24/minima).", min=0.0, max=1.0),
        Parameter("carry_next_nodes", "bool", False, "Where the fix loop moves a junction away from a close neighbour junction and the move brings the next node of another of its branches within its half cross-sections (that branch's first segment a stub: its boundary-layer blocks collapse onto the wall), move that node by the same step (at most 1.5 of its radii from its skeleton point, 0.4 of its radius inside the wall; opt-in: not measured over the corpora, docs/junctions.md h26/pair)."),
        Parameter("poor_block_optimised", "bool", False, "Judge poor_block_sj's rounds by the blocks they move, filled at the default resolution and optimised as mesh_transfinite optimises (untangling, light pass; the faces shared with other blocks held): a round is kept where their least element rises and their mean does not fall, instead of by the blocks' corner scaled Jacobians (opt-in; docs/optimiser.md h26/minima)."),
        Parameter("work_budget", "int", 160, "Most assemblies of the whole block structure over all fix rounds and changed skeletons (each costs time in proportion to the tree); a structure still invalid then fails with the usual error (0: no budget). With bend_drops > 0 its rounds share one more such budget.", min=0, max=10000),
    ],
    reads=("skeleton", "sdf"),
    optional_reads=("caps", "surface"),
    writes=("blocks", "skeleton"),
    category="block structure",
)
def build_block_structure(ctx, blocks_around, core_size, layer_thickness, plane_bias, junction_rotation, rotation_range,
                          max_out_of_plane, min_branch_gap, split_nonplanar, clear_ray_factor, junction_margin, cap_distance,
                          dome_depth, dome_max_retreat, max_fix_rounds, check_wall_projection, junction_centre=1.0, dome_keep=0.0,
                          relieve_wall_folds=True, work_budget=160, own_territory=True, junction_lean=1.0, cut_contacts=True,
                          choose_lean=False, dent_sections=2, saddle_split=0.5, stub_within_reach=False, short_end_rays=0.5,
                          bend_drops=0, reroot_backwards=False, poor_block_sj=0.0, centre_sections=0.0, carry_next_nodes=False, poor_block_optimised=False):
    """One O-grid cross-section per skeleton node (a core of a x b blocks, a ring and a
    boundary-layer ring whose outer corners are found on the wall by ray casting in the
    section plane), half cross-sections on half-planes through each junction's axis shared
    by neighbouring branches, frames transported along branches with the remaining twist
    spread evenly, and every block checked for positive corner Jacobians (fixed by moving
    sections, re-rotating junction half-planes, straightening planes and shrinking the
    core; a block that stays invalid fails with its skeleton node and a VTU of the bad
    blocks), then boundary-layer blocks checked with their wall faces projected onto the
    wall and thickened where they would fold. Endpoints near a cap end on the cap plane with the cap's name; endpoints
    without a cap are closed on the wall by a cap of blocks round the dome; without caps every endpoint is open."""
    from ..geometry.block_builder import BlockOptions, block_structure_checks, build_blocks
    from ..geometry.blocks.options import EndOptions, JunctionOptions, LastTryOptions, RepairOptions, SectionOptions

    options = BlockOptions(
        section=SectionOptions(blocks_around=blocks_around, core_size=core_size, layer_thickness=layer_thickness, plane_bias=plane_bias,
                                own_territory=own_territory, centre_sections=centre_sections),
        junction=JunctionOptions(
            junction_rotation=junction_rotation, rotation_range=rotation_range, max_out_of_plane=max_out_of_plane,
            min_branch_gap=min_branch_gap, clear_ray_factor=clear_ray_factor, junction_margin=junction_margin,
            junction_centre=junction_centre, junction_lean=junction_lean, choose_lean=choose_lean, saddle_split=saddle_split,
        ),
        ends=EndOptions(cap_distance=cap_distance, dome_depth=dome_depth, dome_max_retreat=dome_max_retreat, dome_keep=dome_keep,
                        short_end_rays=short_end_rays),
        repair=RepairOptions(split_nonplanar=split_nonplanar, max_fix_rounds=max_fix_rounds, relieve_wall_folds=relieve_wall_folds,
                             work_budget=work_budget, dent_sections=dent_sections, stub_within_reach=stub_within_reach,
                             poor_block_sj=poor_block_sj, carry_next_nodes=carry_next_nodes,
                             poor_block_optimised=poor_block_optimised),
        last=LastTryOptions(bend_drops=bend_drops, reroot_backwards=reroot_backwards),
    )
    sdf = ctx.sdf  # a vmesh.geometry.surface_query.SurfaceQuery
    bad_path = ctx.output_path("invalid_blocks.vtu")
    if bad_path is None:
        bad_path = Path(tempfile.gettempdir()) / f"vmesh_invalid_blocks_{os.getpid()}.vtu"
    built_on = ctx.skeleton
    found = _vessels_in_contact(built_on)
    cuts, touched_radii = _contact_cuts(built_on, found, ctx.caps, cap_distance) if cut_contacts else (None, {})
    options.ends.touched_caps = tuple(touched_radii)  # {cap id: least radius in contact}'s caps: the rays' territory ends at their planes, as the cuts do
    project = None
    if check_wall_projection:
        if ctx.surface is not None:
            from ..geometry.projection import wall_projector

            project = wall_projector(ctx.surface, ctx.caps, kept=touched_radii)  # shared with mesh_transfinite and the checks
        else:
            project = sdf.closest_points
    if cuts is not None:
        from ..geometry.contact_cut import with_cuts

        sdf, project = with_cuts(sdf, project, cuts)
    blocks = build_blocks(
        ctx.skeleton, sdf.distance, ctx.caps, options, bad_blocks_path=bad_path, warn=ctx.warn, progress=ctx.tick, project=project,
        intersect_lines=sdf.intersect_lines,
    )
    skeleton = blocks.info.pop("skeleton", None)
    if skeleton is not None and skeleton is not ctx.skeleton:
        ctx.skeleton = skeleton  # junctions were split
    checks = block_structure_checks(blocks)
    if checks["face_use_errors"]:
        raise ChainError(f"block structure is not conforming: {checks['face_use_errors']} faces are shared wrongly (a bug; please report it)")
    ctx.blocks = blocks
    info = blocks.info
    ctx.count(
        blocks=blocks.n_blocks, vertices=len(blocks.vertices),
        junctions=len(info.get("junctions", {})),
        max_twist_deg=float(info.get("max_twist_deg", 0.0)),
        fixes=len(info.get("fixes", [])),
        cut_stubs=len(info.get("cut_stubs", [])),
    )
    ctx.report.sections["blocks"] = {
        "blocks": blocks.n_blocks,
        "vertices": int(len(blocks.vertices)),
        "blocks_around": info["blocks_around"],
        "core": info["core"],
        "max_twist_deg": info["max_twist_deg"],
        "fixes": info.get("fixes", []),
        "junctions": info.get("junctions", {}),
        "boundary_names": {int(k): v for k, v in blocks.boundary_names.items()},
        "checks": checks,
        "blocks_folding_on_wall": info.get("blocks_folding_on_wall"),
        "min_projected_wall_quality": info.get("min_projected_wall_quality"),
        "work": info.get("work"),  # assemblies (and the budget), rays cast and reused
        "cut_stubs": _cut_stubs(ctx, info.get("cut_stubs", [])),
        "contact_cuts": cuts.summary() if cuts is not None else [],
    }
    if "junction_lean" in info:  # choose_lean's scores and choice per leaning n-furcation
        ctx.report.sections["blocks"]["junction_lean"] = info["junction_lean"]
    if cuts is not None and len(cuts):
        info["contact_cuts"] = cuts  # mesh_transfinite and compute_quality see the same domain
    if touched_radii:
        info["touched_caps"] = touched_radii  # {cap id: keep radius}: mesh_transfinite's wall projector keeps these caps as the checks did
    if checks["boundary_components"] != 1:
        ctx.warn(f"the outer block faces form {checks['boundary_components']} pieces (is the skeleton connected?)")
    # named on the skeleton the run goes on with (the builder may have changed it)
    _warn_vessels_in_contact(ctx, found if ctx.skeleton is built_on else _vessels_in_contact(ctx.skeleton), cut=cuts is not None)


def _vessels_in_contact(sk) -> np.ndarray:
    """:func:`~vmesh.geometry.skeleton.contact.vessels_in_contact` on a skeleton."""
    from ..geometry.skeleton.contact import vessels_in_contact

    return vessels_in_contact(sk.points, sk.radii, sk.edges)


def _contact_cuts(sk, found: np.ndarray, caps=None, cap_distance: float = 1.0):
    """The cuts between the vessels in contact ``found`` on the skeleton ``sk`` the blocks
    are built on (:mod:`vmesh.geometry.contact_cut`), each stopping at an open end (an
    endpoint the builder puts on a cap; None when there are no cuts), and the ids of the
    caps of the open ends in contact with another vessel (whose cap the wall projector
    keeps: :func:`vmesh.geometry.projection.wall_projector`), each with the radius of the
    thinnest vessel in contact at that end (the scale of the lumen its cap may cross)."""
    from ..geometry.blocks.prep import endpoint_caps
    from ..geometry.contact_cut import contact_cuts

    if not len(found):
        return None, {}
    ends = sk.endpoints
    cap_of = endpoint_caps(sk.points, sk.radii, ends, caps, cap_distance) if caps else {}
    cuts = contact_cuts(sk.points, sk.radii, sk.edges, found, open_ends=list(cap_of) if caps else ends)  # no caps: every end open, as the builder
    touched_radii = {}
    for pair in np.asarray(cuts.nodes).tolist():
        for end, other in (pair, pair[::-1]):
            if int(end) in cap_of:
                cap = int(cap_of[int(end)].id)
                touched_radii[cap] = min(touched_radii.get(cap, np.inf), float(sk.radii[int(other)]))
    return (cuts if len(cuts) else None), dict(sorted(touched_radii.items()))


def _warn_vessels_in_contact(ctx, found: np.ndarray, cut: bool = False) -> None:
    """Name the places ``found`` where two vessels pass in contact with no junction between
    them (:func:`_vessels_in_contact`): without a cut between them (``cut``) their blocks
    meet the other vessel's wall and the mesh may fold there beyond what untangling can
    open; with one, the fused neck's wall is left out."""
    ctx.report.sections["blocks"]["vessels_in_contact"] = [
        {"nodes": [int(a), int(b)], "gap": round(float(g), 6)} for a, b, g in found.tolist()
    ]
    if len(found):
        where = ", ".join(f"{int(a)}/{int(b)} ({g:+.3g})" for a, b, g in found[:5].tolist())
        more = f" and {len(found) - 5} more" if len(found) > 5 else ""
        ctx.warn(f"{len(found)} place(s) where two vessels pass in contact with no junction between them, at skeleton nodes "
                 f"{where}{more} (gap between the walls; negative: the lumens overlap): "
                 + ("meshed apart by a cut between them, the neck's wall left out (report.json: blocks.contact_cuts)" if cut
                    else "the mesh may fold there (report.json: blocks.vessels_in_contact)"))


def _cut_stubs(ctx, stubs: list) -> list:
    """The side-branch stubs the builder cut (:mod:`vmesh.geometry.blocks.stubs`), with the wall
    each leaves unmeshed; a warning gives the total."""
    if not stubs:
        return []
    from ..geometry.blocks.stubs import stub_wall

    if ctx.surface is not None:
        stubs = stub_wall(ctx.surface.vertices, ctx.surface.faces, stubs)
        share = sum(s["wall_share"] for s in stubs)
        ctx.warn(f"{len(stubs)} side-branch stub(s) cut (cap(s) {', '.join(repr(s['cap']) for s in stubs)}): "
                 f"{100 * share:.2g} % of the wall is not meshed there")
    return [{k: v for k, v in s.items() if k != "nodes"} for s in stubs]


def write_edge_ply(path, vertices: np.ndarray, edges: np.ndarray, edge_data: dict | None = None) -> Path:
    """Write a binary PLY with vertices and edges (``element edge``, read by MeshLab);
    ``edge_data`` maps names to (ne,) integer arrays written as edge properties
    (:func:`vmesh.io.meshlab.write_edge_ply`)."""
    from ..io.meshlab import write_edge_ply as write

    return write(path, vertices, edges, "vmesh block edges", edge_data)


def block_edges(blocks) -> tuple[np.ndarray, np.ndarray]:
    """Unique block edges ``(ne, 2)`` and whether each lies on the wall."""
    from ..blocks import HEX_EDGES

    e = np.unique(np.sort(blocks.hexes[:, HEX_EDGES].reshape(-1, 2), axis=1), axis=0)
    wall = blocks.surface_edges()
    on_wall = np.zeros(len(e), bool)
    if len(wall):
        n = len(blocks.vertices)
        key = e[:, 0] * n + e[:, 1]
        wkey = np.sort(wall, axis=1)
        on_wall = np.isin(key, wkey[:, 0] * n + wkey[:, 1])
    return e, on_wall


# duplicates: the name checks and register_filter declarations of the writers share their shape, not logic (other parameters)
def _check_block_file_names(filename, edges_filename):
    if not filename.lower().endswith(".vtu"):
        raise ParameterError(f"filter 'write_blocks': parameter 'filename' must end in .vtu, got {filename!r}")
    if edges_filename and not edges_filename.lower().endswith(".ply"):
        raise ParameterError(f"filter 'write_blocks': parameter 'edges_filename' must end in .ply, got {edges_filename!r}")


@register_filter(
    description="Write the block structure: hexahedra with block/segment/node/layer data (VTU, for ParaView) and the block edges (PLY edge mesh, for MeshLab).",
    parameters=[
        Parameter("filename", "str", "blocks.vtu", "VTU file name in the output folder."),
        Parameter("edges_filename", "str", "blocks_edges.ply", "PLY edge-mesh file name in the output folder ('' for none)."),
    ],
    reads=("blocks",),
    category="export",
    check=lambda params: _check_block_file_names(**params),
)
def write_blocks(ctx, filename, edges_filename):
    """The VTU carries per block ``block_id``, ``segment_id``, ``node_id``, ``layer`` (0 core,
    1 ring, 2 boundary layer), ``min_corner_jacobian`` and per corner ``on_surface``; the PLY
    holds every block edge once with ``wall`` = 1 on the vessel wall."""
    from ..io.atomic import atomic_path
    from ..io.vtk_xml import write_vtu
    from ..mesh import VTK_HEXAHEDRON

    blocks = ctx.blocks
    path = ctx.output_file(filename)
    if path is None:
        return
    boundary = blocks.face_boundary
    cell_data = {
        **blocks.cell_arrays(),
        "wall_faces": (boundary == 0).sum(axis=1).astype(np.uint8),
        "open_end": np.where(boundary > 0, boundary, 0).max(axis=1).astype(np.int32),
    }
    with atomic_path(path) as tmp:  # raw VTK XML: no VTK import for this file
        write_vtu(tmp, blocks.vertices, blocks.hexes, VTK_HEXAHEDRON, cell_data,
                  point_data={"on_surface": blocks.vertex_on_surface.astype(np.uint8)})
    written = [str(path.name)]
    if edges_filename:
        e, wall = block_edges(blocks)
        write_edge_ply(ctx.output_path(edges_filename), blocks.vertices, e, {"wall": wall.astype(np.int32)})
        written.append(edges_filename)
    ctx.count(files=len(written))
