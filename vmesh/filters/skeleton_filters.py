"""Skeleton filters: load, estimate radii, clean, resample, tag and render a skeleton.

Thin wrappers around :mod:`vmesh.geometry.skeleton` (the kernels) and
:mod:`vmesh.io.skeleton_formats`. Extraction from the surface is the separate
``extract_skeleton`` filter.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import InputError
from ..geometry.rays import RayCache
from ..geometry.skeleton import clean as sk_clean, distance as sk_distance, graft as sk_graft, graph as sk_graph, sample as sk_sample, tags as sk_tags
from ..geometry.skeleton.bends import chamfer_hairpins, thin_sharp_bends, thin_stubs
from ..geometry.skeleton.defects import cut_necks, weld_coincident_nodes
from ..registry import Parameter, register_filter
from .skeleton_fit_checks import fit_to_surface


# duplicates: the register_filter declarations in this module share their shape (Parameter lists), not logic
@register_filter(
    description="Read a centerline file (json, swc, csv, ply, or vtp/vtk from VMTK, SimVascular or plain polylines) as the skeleton.",
    parameters=[
        Parameter("path", "path", None, "Centerline file, or a folder holding nodes.csv and edges.csv."),
        Parameter(
            "vtk_kind",
            "str",
            "auto",
            "What a .vtp/.vtk file holds: overlapping inlet-to-outlet lines (vmtk), a SimVascular centerline graph, "
            "or plain polylines; auto tells from the content.",
            choices=("auto", "vmtk", "simvascular", "polylines"),
        ),
        Parameter(
            "merge_tolerance",
            "float",
            0.2,
            "VMTK centerlines: points of different lines closer than this are one (their shared trunk).",
            unit="× radius",
            min=0.0,
            max=2.0,
        ),
        Parameter(
            "scale",
            "float",
            1.0,
            "Multiply the centerline's coordinates and radii by this (a centerline in other units than the surface: "
            "10 for cm -> mm, 1000 for m -> mm, 0.1 for mm -> cm).",
            min=1e-9,
        ),
    ],
    writes=("skeleton",),
    category="skeleton",
)
def load_skeleton(ctx, path, vtk_kind, merge_tolerance, scale):
    """Read the skeleton from a file; tags in the file (JSON tags, SWC types, VTK label arrays) are kept."""
    from ..io.skeleton import read_skeleton

    if path is None:
        raise InputError("load_skeleton needs a path (the centerline file)")
    p = Path(path)
    options = {"kind": vtk_kind, "merge_tolerance": merge_tolerance} if p.suffix.lower() in (".vtp", ".vtk") else {}
    skel = read_skeleton(p, **options)
    if scale != 1.0:
        skel = skel.copy(points=skel.points * scale, radii=skel.radii * scale)
    ctx.inputs["skeleton"] = str(p)
    ctx.skeleton = skel
    _count_summary(ctx, skel)


def _count_summary(ctx, skel):
    s = skel.summary()
    ctx.count(nodes=s["nodes"], junctions=s["junctions"], endpoints=s["endpoints"], cycles=s["cycles"])
    if s["components"] > 1:
        ctx.warn(f"skeleton has {s['components']} separate pieces (clean_skeleton reconnects close ones)")


def _sdf_functions(sdf):
    """(distance, gradient) callables of the SDF layer (a :class:`~vmesh.geometry.surface_query.SurfaceQuery`)."""
    return sdf.distance, sdf.gradient


@register_filter(
    description="Fill missing skeleton radii from the signed distance (inscribed sphere radius), else by interpolation along branches.",
    parameters=[
        Parameter("overwrite", "bool", False, "Recompute every radius from the signed distance, not only the missing ones."),
        Parameter(
            "scale",
            "float",
            1.0,
            "Multiply the skeleton's coordinates and radii by this first (a centerline in other units than the surface: "
            "10 for cm -> mm, 1000 for m -> mm, 0.1 for mm -> cm).",
            min=1e-9,
        ),
    ],
    reads=("skeleton",),
    optional_reads=("sdf", "surface", "caps"),
    writes=("skeleton",),
    category="skeleton",
)
def estimate_radii(ctx, overwrite, scale):
    """A centerline file without radii (plain polylines, CSV without a radius column, an
    SWC with zero radii) gets the distance from each node to the wall; nodes outside the
    wall, or all nodes without an SDF, get radii interpolated along their branch from the
    known ones. Radii that are all equal (a placeholder) or far from the surface's
    inscribed radii (other units) are measured from the surface instead, with a warning.
    With the sdf, a centerline that does not fit the surface (other units, another
    vessel) is an error that says so."""
    skel = ctx.skeleton
    none_given = not np.isfinite(skel.radii).any()  # said below: the user may not know the file has none
    if scale != 1.0:
        skel = ctx.skeleton = skel.copy(points=skel.points * scale, radii=skel.radii * scale)
    if ctx.sdf is not None:
        skel, unknown = fit_to_surface(ctx, skel)
        overwrite = unknown or overwrite
    if ctx.sdf is None:
        if overwrite:
            raise InputError("estimate_radii: overwrite needs the sdf layer (add build_sdf before it)")
        if not np.isfinite(skel.radii).any():
            raise InputError("the skeleton has no radii and there is no sdf layer to measure them (add build_sdf before estimate_radii)")
    distance = ctx.sdf.distance if ctx.sdf is not None else None
    before = skel.radii
    if distance is not None:
        skel = _radii_from_sections(skel, distance, overwrite, ctx.caps or ())
    ctx.skeleton, _ = sk_distance.estimate_radii(skel, distance, overwrite=False)
    filled = int((~np.isclose(ctx.skeleton.radii, before, equal_nan=True)).sum())
    if none_given and filled and distance is not None:
        ctx.warn(f"the centerline has no radii: {filled} measured from the surface (the inscribed sphere at each "
                 "node); a VMTK file keeps them in MaximumInscribedSphereRadius, an SWC in its radius column")
    ctx.count(radii_filled=filled, radius_min=float(np.min(ctx.skeleton.radii)), radius_max=float(np.max(ctx.skeleton.radii)))


@register_filter(
    description="Clean the skeleton: bring nodes back inside, reconnect pieces, merge split junctions, remove spurs, graft branches to caps it misses, extend ends to the caps.",
    parameters=[
        Parameter(
            "outside",
            "str",
            "pull",
            "Nodes outside the wall: pull them up the signed distance towards the vessel axis (dropping those that "
            "cannot be brought in; an end outside goes back along its branch to the last full cross-section instead), "
            "drop them, or keep them. Needs the sdf layer.",
            choices=("pull", "drop", "keep"),
        ),
        Parameter("outside_tolerance", "float", 0.02, "A node is outside when its signed distance is below minus this.", unit="× radius", min=0.0),
        Parameter(
            "reconnect_distance",
            "float",
            1.0,
            "Join an endpoint to another piece of the skeleton when that piece passes this close (0: never).",
            unit="× radius",
            min=0.0,
        ),
        Parameter(
            "junction_distance",
            "float",
            0.5,
            "Merge junctions joined by a branch shorter than this into one junction (0: never).",
            unit="× radius",
            min=0.0,
        ),
        Parameter(
            "parallel_angle",
            "float",
            30.0,
            "Move a junction whose two closest branches leave it less than this apart (directions one radius along "
            "them: centerlines that part well before the carina) downstream to where they are part_angle apart (0: never).",
            unit="degrees",
            min=0.0,
            max=90.0,
        ),
        Parameter(
            "part_angle",
            "float",
            60.0,
            "Where such a junction moves to: the first point between the two branches from which they are this far apart.",
            unit="degrees",
            min=0.0,
            max=150.0,
        ),
        Parameter(
            "spur_length",
            "float",
            1.0,
            "Remove side branches ending freely that are shorter than this times the radius at their junction (0: never).",
            unit="× radius",
            min=0.0,
        ),
        Parameter(
            "spur_shadow",
            "float",
            0.5,
            "Also remove a side branch of any length whose free end lies this close to another branch of its "
            "junction (a second path inside that vessel; 0: never).",
            unit="× radius",
            min=0.0,
            max=1.0,
        ),
        Parameter(
            "weld_distance",
            "float",
            0.001,
            "First weld nodes closer than this into one (repeated points of a centerline file; 0: never). Kept far "
            "below the node spacing of dense centerlines, whose consecutive nodes would otherwise weld in a chain.",
            unit="× radius",
            min=0.0,
            max=0.05,
        ),
        Parameter("extend_to_caps", "bool", True, "Trim or extend each end that belongs to a cap so that it ends on the cap (needs the caps layer)."),
        Parameter(
            "cap_mode",
            "str",
            "center",
            "Where an extended end stops: the cap centre, or where its end direction meets the cap plane (the centre when that is off-centre).",
            choices=("center", "plane"),
        ),
        Parameter("cap_distance", "float", 3.0, "An endpoint belongs to a cap when it is at most this far from the cap centre.", unit="× cap radius", min=0.0),
        Parameter(
            "graft_to_caps",
            "bool",
            True,
            "A cap that no endpoint belongs to (the centerline misses that vessel) gets the branch leading to it in a "
            "skeleton extracted from the signed distance, grafted on where that branch meets the skeleton (needs the "
            "caps and sdf layers).",
        ),
        Parameter(
            "graft_join",
            "float",
            0.5,
            "A grafted branch joins the skeleton at its first node this close to it.",
            unit="× radius",
            min=0.0,
            max=5.0,
        ),
        Parameter(
            "neck",
            "float",
            0.25,
            "Cut the bridge through the neck where two vessels touch: a junction whose radius is below this share of "
            "its neighbours' (median), and whose neighbours do not all see each other through the lumen (0: never).",
            min=0.0,
            max=1.0,
        ),
    ],
    reads=("skeleton",),
    optional_reads=("sdf", "caps", "surface"),
    writes=("skeleton", "caps", "surface"),
    updates=("caps", "surface"),
    category="skeleton",
)
def clean_skeleton(
    ctx,
    outside,
    outside_tolerance,
    reconnect_distance,
    junction_distance,
    parallel_angle,
    part_angle,
    spur_length,
    spur_shadow,
    weld_distance,
    extend_to_caps,
    cap_mode,
    cap_distance,
    graft_to_caps,
    graft_join,
    neck=0.25,
):
    """Steps, in order: welding of repeated points, cutting off what runs out through a cap, nodes outside the wall,
    bridges through the neck where two vessels touch, reconnection of separated pieces, merging of junctions split into nearby nodes, spur
    removal (ends at caps are kept), merging again, grafting a branch to every cap no end
    belongs to (then merging again), moving junctions whose branches leave nearly parallel
    to where they part, and trimming/extending the ends to the caps. Grafted branches are
    listed in the report section ``grafted_branches``."""
    skel = ctx.skeleton
    if ctx.sdf is not None and outside != "keep" and "skeleton_fit" not in ctx.report.sections:
        skel, _ = fit_to_surface(ctx, skel)  # estimate_radii did not run
    if not np.isfinite(skel.radii).all() and ctx.sdf is not None:
        skel, _ = sk_distance.estimate_radii(skel, ctx.sdf.distance)
    counts = {}
    skel, counts["welded"] = weld_coincident_nodes(skel, weld_distance)
    caps = list(ctx.caps or [])
    if caps and any(c.needs_end for c in caps):  # before a terrace's plane could trim the centerline
        skel, caps = _facets_to_wall(ctx, skel, caps)
    if extend_to_caps and caps:  # centerlines running out through an open end stop at its cap
        cap_arrays = (np.array([c.center for c in caps]), np.array([c.normal for c in caps]), np.array([c.radius for c in caps]))
        skel, counts["cut_at_caps"] = sk_clean.trim_at_caps(skel, *cap_arrays)
    if outside != "keep":
        if ctx.sdf is None:
            ctx.warn("no sdf layer: nodes outside the wall are not checked")
        else:
            distance, gradient = _sdf_functions(ctx.sdf)
            at_cap = None if ctx.caps is None else _near_caps(skel, caps, cap_distance)  # left to extend_to_caps
            skel, counts["pulled"], counts["dropped"] = sk_distance.pull_inside(skel, distance, gradient, outside_tolerance, outside, at_cap)
            if neck > 0:  # before reconnecting and merging, which would take the bridge for a junction
                skel, counts["necks_cut"] = cut_necks(skel, distance, neck)
    ctx.tick(0.25, "reconnect")
    skel, counts["reconnected"] = sk_clean.reconnect_components(skel, reconnect_distance)
    skel, merged = sk_clean.merge_close_junctions(skel, junction_distance)
    protected = None
    if caps:
        centers = np.array([c.center for c in caps], float)
        radii = np.array([c.radius for c in caps], float)
        near = np.linalg.norm(skel.points[:, None, :] - centers[None], axis=2) <= cap_distance * radii[None]
        protected = near.any(axis=1)
    ctx.tick(0.5, "spurs")
    skel, counts["spurs_removed"] = sk_clean.remove_spurs(skel, spur_length, protected, spur_shadow)
    skel, merged2 = sk_clean.merge_close_junctions(skel, junction_distance)
    if graft_to_caps and caps:
        skel, counts["grafted"] = _graft_missing_branches(ctx, skel, caps, cap_distance, graft_join)
        if counts["grafted"]:
            skel, merged3 = sk_clean.merge_close_junctions(skel, junction_distance)
            merged2 += merged3
    counts["junctions_merged"] = merged + merged2
    skel, counts["junctions_moved"] = sk_clean.separate_parallel_branches(
        skel, parallel_angle, part_angle, distance=ctx.sdf.distance if ctx.sdf is not None else None
    )
    if extend_to_caps and caps:
        ctx.tick(0.75, "caps")
        skel, matched = sk_graft.extend_to_caps(
            skel,
            *cap_arrays,
            [c.name for c in caps],
            mode=cap_mode,
            max_distance=cap_distance,
        )
        counts["ends_at_caps"] = int((matched >= 0).sum())
        reached = {i for i, m in enumerate(matched) if m >= 0}
        for i in sorted(set(range(len(caps))) - reached):
            o = _overlapping_cap(caps, i, reached)
            if o is not None:
                ctx.warn(f"cap {caps[i].name} overlaps cap {caps[o].name}, whose skeleton end stands for both")
                reached.add(i)
        missing = [caps[i] for i in range(len(caps)) if i not in reached]
        if missing and graft_to_caps and ctx.sdf is not None:
            where = "; ".join(f"{c.name} at {np.round(c.center, 3).tolist()} (radius {c.radius:.3g})" for c in missing)
            raise InputError(
                f"no skeleton end reaches cap(s) {where}: the vessel behind would be missing from the "
                "mesh. Give a centerline that reaches every open end, or none (to extract one)"
            )
        if missing:
            ctx.warn(f"no skeleton end near cap(s) {', '.join(c.name for c in missing)}")
    if outside != "keep" and ctx.sdf is not None:
        skel, counts["pulled_in"] = _keep_inside(ctx, skel)
    skel.edge_tags = sk_tags.derive_edge_tags(skel)  # new segments take the tags of their nodes
    ctx.skeleton = skel
    ctx.count(**counts)
    _count_summary(ctx, skel)


def _radii_from_sections(skel, distance, overwrite: bool, caps=()):
    """Radii of the nodes to fill (all with ``overwrite``): the signed distance (the
    inscribed sphere), except where the wall nearest to a node lies along the axis (an
    open end's cap or an end face, to which the signed distance measures the way): there
    the node's cross-section. An end, which sits on a cap or an end face, gets its radius
    from its branch (as the nodes still missing)."""
    from ..geometry.skeleton_fit import node_tangents, section_radii

    todo = np.ones(skel.n_nodes, bool) if overwrite else ~(np.isfinite(skel.radii) & (skel.radii > 0))
    if not todo.any():
        return skel
    radii = skel.radii.copy()
    radii[todo] = np.nan
    nodes = np.flatnonzero(todo & (skel.degrees >= 2))
    if len(nodes):
        p = skel.points[nodes]
        d = np.asarray(distance(p), float)
        extent = float(np.ptp(skel.points, axis=0).max()) or 1.0
        towards_wall = sk_distance.distance_gradient(distance, p, np.maximum(0.1 * np.abs(d), 1e-9 * extent))
        along = np.abs(np.einsum("ij,ij->i", towards_wall, node_tangents(skel)[nodes])) > np.cos(np.radians(45.0))
        along &= skel.degrees[nodes] == 2  # a junction has no section plane
        mask = np.zeros(skel.n_nodes, bool)
        mask[nodes[along]] = True
        section = section_radii(skel, distance, mask, caps)[nodes]
        radii[nodes] = np.where(along, section, np.where(d > 0, d, np.nan))
    if np.isfinite(radii).any():
        radii = sk_distance.fill_missing_along_branches(skel.n_nodes, skel.edges, skel.points, radii)
    return skel.copy(radii=radii)


def _keep_inside(ctx, skel):
    """Move nodes that graze or cross the wall onto the vessel's axis (every later stage
    needs them inside); a node that cannot be brought inside is an error naming it."""
    from ..geometry.skeleton_fit import ensure_inside

    distance, gradient = _sdf_functions(ctx.sdf)
    skel, moved, stuck = ensure_inside(skel, distance, gradient)
    if len(stuck):
        k = int(stuck[0])
        d = float(np.asarray(distance(skel.points[[k]]), float)[0])
        raise InputError(
            f"skeleton node {k} at {np.round(skel.points[k], 4).tolist()} lies outside the surface (signed distance "
            f"{d:.3g}) and no walk up the signed distance brings it inside ({len(stuck)} such node(s)): the centerline "
            "leaves the vessel there (is the surface broken or the centerline of another vessel?)"
        )
    return skel, moved


def _overlapping_cap(caps, c: int, others) -> int | None:
    """A cap among ``others`` whose disc overlaps cap ``c`` (centres closer than the sum of
    the radii): two open ends cannot overlap, so ``c`` is a piece of that end (a cap face
    detected in two parts), not a vessel of its own."""
    for o in others:
        if o != c and np.linalg.norm(np.asarray(caps[o].center) - caps[c].center) < caps[o].radius + caps[c].radius:
            return o
    return None


def _facets_to_wall(ctx, skel, caps):
    """Turn the caps that need an end (flat regions whose wall behind is no tube) and that
    no skeleton end reaches into wall (:func:`walls_not_caps`); returns the caps left.
    The ends choose caps known to be ends first (``_match_caps``, as the extraction); a
    cap off the skeleton's vessels (``on_branch_wall``) stays, to be grafted to."""
    from ..geometry.skeleton.ends import _match_caps, on_branch_wall
    from .preprocess_filters import walls_not_caps

    ends = skel.endpoints
    matched = _match_caps(skel.points[ends], skel.radii[ends], caps, _end_directions(skel, ends)) if len(ends) else {}
    reached = set(matched.values())
    for i, c in enumerate(caps):  # an end on the region itself (a branch grafted to it) reaches it too
        if len(ends) and np.linalg.norm(skel.points[ends] - c.center, axis=1).min() <= c.radius:
            reached.add(i)
    facets = [i for i, c in enumerate(caps) if c.needs_end and i not in reached and on_branch_wall(c, skel.points, skel.radii, skel.edges)]
    if not facets:
        return skel, caps
    renamed = {old: new for old, new in walls_not_caps(ctx, facets).items() if old != new}
    if renamed:  # ends tagged with a cap's name follow its new name
        skel = skel.copy(node_tags=[_renamed_end_tags(t, renamed) for t in skel.node_tags], edge_tags=[_renamed_end_tags(t, renamed) for t in skel.edge_tags])
    return skel, list(ctx.caps)


def _renamed_end_tags(tags: tuple, renamed: dict) -> tuple:
    """``tags`` with a cap's old name replaced by its new one (and ``inlet`` / ``outlet`` to match)."""
    old = next((t for t in tags if t in renamed), None)
    if old is None:
        return tags
    new = renamed[old]
    kind = "inlet" if new.startswith("inlet") else "outlet"
    rest = [t for t in tags if t not in (old, "inlet", "outlet")]
    return tuple(dict.fromkeys([*rest, kind] + ([new] if new != kind else [])))


def _end_directions(skel, ends) -> np.ndarray:
    """Outward unit directions of the branches at ``ends``: from the node about a radius
    (at least two nodes, at most the next junction) inwards to the end."""
    from ..geometry.skeleton.graft import _end_chain

    adj = skel.adjacency()
    deg = np.diff(adj.indptr)
    out = np.zeros((len(ends), 3))
    for k, e in enumerate(ends):
        chain = _end_chain(adj, deg, int(e))
        arc = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(skel.points[chain], axis=0), axis=1))]
        far = np.flatnonzero((np.arange(len(chain)) >= 2) & (arc >= float(skel.radii[e])))
        d = skel.points[e] - skel.points[chain[far[0] if len(far) else -1]]
        out[k] = d / max(np.linalg.norm(d), 1e-300)
    return out


def _near_caps(skel, caps, cap_distance) -> np.ndarray:
    """Nodes within ``cap_distance`` cap radii of a cap's centre (ends that belong to it)."""
    near = np.zeros(skel.n_nodes, bool)
    for c in caps:
        near |= np.linalg.norm(skel.points - np.asarray(c.center, float), axis=1) <= cap_distance * c.radius
    return near


def _graft_missing_branches(ctx, skel, caps, cap_distance, join):
    """Graft a branch of an extracted skeleton to each cap that no endpoint of ``skel``
    belongs to (see :func:`~vmesh.geometry.skeleton.graft.graft_branches`); returns the
    skeleton and the number of branches grafted."""
    centers = np.array([c.center for c in caps], float)
    radii = np.array([c.radius for c in caps], float)
    reached = {c for _, c in sk_graft.match_ends_to_caps(skel, centers, radii, cap_distance)}
    missing = [c for c in range(len(caps)) if c not in reached and _overlapping_cap(caps, c, reached) is None]
    if not missing:
        return skel, 0
    if ctx.sdf is None:
        ctx.warn("no sdf layer: caps without a skeleton end get no grafted branch")
        return skel, 0
    from ..geometry.skeleton import extract as se

    if ctx.surface is not None:
        surface, bounds = (ctx.surface.vertices, ctx.surface.faces), ctx.surface.bounds
    elif ctx.sdf is not None:
        surface, bounds = (ctx.sdf.vertices, ctx.sdf.faces), ctx.sdf.bounds
    else:
        ctx.warn("no surface layer: caps without a skeleton end get no grafted branch")
        return skel, 0
    ctx.tick(0.6, f"extracting a skeleton for {len(missing)} cap(s) without an end")
    try:  # the same extraction as the extract_skeleton filter's defaults
        source, _ = se.extract_skeleton(ctx.sdf.distance, bounds, surface=surface, caps=caps)
    except ValueError as exc:
        ctx.warn(f"could not extract a skeleton to graft from: {exc}")
        return skel, 0
    names = [caps[c].name for c in missing]
    skel, grafts = sk_graft.graft_branches(skel, source, centers[missing], radii[missing], names, join=join)
    ctx.report.sections["grafted_branches"] = grafts
    done = [g for g in grafts if g["nodes"]]
    for g in done:
        ctx.warn(
            f"no skeleton end at cap {g['cap']}: grafted the extracted branch to it "
            f"({g['nodes']} nodes, {g['length']:.3g} long, joined at {np.round(g['joined_at'], 3).tolist()})"
        )
    for g in grafts:
        if not g["nodes"]:
            ctx.warn(f"no skeleton end at cap {g['cap']} and no branch grafted: {g['reason']}")
    return skel, len(done)


@register_filter(
    description="Resample the skeleton to a coarse one: node spacing proportional to the local radius, keeping every junction and endpoint.",
    parameters=[
        Parameter("spacing", "float", 1.25, "Distance between nodes along a branch (1.25 gives about the node counts of the reference meshes).", unit="× radius", min=0.05, max=100.0),
        Parameter(
            "radius_change",
            "float",
            0.25,
            "Add nodes where the radius changes faster than this per unit length (|dr/ds|: coarctation throat, "
            "aneurysm neck); 0 adds none.",
            min=0.0,
        ),
        Parameter("smooth_radii", "float", 0.0, "Gaussian smoothing of the radii along each branch (standard deviation; 0: none).", unit="× radius", min=0.0),
        Parameter("min_segments", "int", 1, "Least number of segments per branch.", min=1, max=1000),
        Parameter(
            "min_section_gap",
            "float",
            1.0,
            "At sharp bends (SWC corners, hairpins) drop nodes until the cross-section planes of every segment cross only "
            "this far beyond the wall (x the wall's distance towards the crossing; needs the sdf for the cast); 0: off.",
            min=0.0,
        ),
    ],
    reads=("skeleton",),
    optional_reads=("sdf",),
    writes=("skeleton",),
    category="skeleton",
)
def resample_skeleton(ctx, spacing, radius_change, smooth_radii, min_segments, min_section_gap):
    """Every branch between junctions and endpoints is resampled as a curve (arc-length
    interpolation of positions and radii); tags come from the nearest original node."""
    skel = ctx.skeleton
    if not (np.isfinite(skel.radii) & (skel.radii > 0)).all():
        if ctx.sdf is None and not np.isfinite(skel.radii).any():
            raise InputError("the skeleton has no radii (add build_sdf and estimate_radii before resample_skeleton)")
        ctx.warn("some radii were missing: estimated first")
        skel, _ = sk_distance.estimate_radii(skel, ctx.sdf.distance if ctx.sdf is not None else None)
    before = skel.n_nodes
    skel = sk_sample.resample_skeleton(skel, spacing, radius_change or None, smooth_radii, min_segments)
    if ctx.sdf is not None:  # a resampled chord across a bend can graze the wall
        skel, moved = _keep_inside(ctx, skel)
        ctx.count(pulled_in=moved)
    skel, stubs = thin_stubs(skel)
    if stubs:
        ctx.count(thinned_stubs=stubs)
    if min_section_gap > 0:
        distance = _sdf_functions(ctx.sdf)[0] if ctx.sdf is not None else None
        lines = ctx.sdf.intersect_lines if ctx.sdf is not None else None
        rays = RayCache()
        skel, thinned = thin_sharp_bends(skel, min_section_gap, distance, intersect_lines=lines, rays=rays)
        if thinned:
            ctx.count(thinned_at_bends=thinned)
        # a corner left turning past a right angle: its mitre section would lie along its arms
        skel, chamfered = chamfer_hairpins(skel, distance=distance)
        if chamfered:
            ctx.count(chamfered_corners=chamfered)
        ctx.count(bend_rays_cast=rays.misses, bend_rays_reused=rays.hits)
    ctx.skeleton = skel
    ctx.count(nodes_before=before)
    _count_summary(ctx, ctx.skeleton)


def _check_dict(name, value, what):
    if not isinstance(value, dict) or not all(isinstance(k, str) and k for k in value):
        raise InputError(f"tag_skeleton: {name} must map tag names to {what}")


@register_filter(
    description="Tag skeleton nodes and segments by rules: branch index, spheres around points, radius ratio (aneurysm sac), node lists.",
    parameters=[
        Parameter("clear", "bool", False, "Remove every existing tag first (tags read from the file are kept otherwise)."),
        Parameter("branches", "bool", False, "Tag branch_<k> on the nodes and segments of each branch, numbered breadth-first from the inlet (junctions get all of theirs)."),
        Parameter("regions", "dict", {}, "Spheres: tag -> [x, y, z, radius]; nodes inside get the tag.", unit="mm"),
        Parameter(
            "sac_ratio",
            "float",
            None,
            "Flag nodes whose radius exceeds this times the median radius of their parent branch (an aneurysm sac); unset: off.",
            min=1.0,
        ),
        Parameter("sac_tag", "str", "aneurysm", "Tag given by the radius-ratio rule."),
        Parameter("nodes", "dict", {}, "Explicit node lists: tag -> [node index, ...]."),
    ],
    reads=("skeleton",),
    writes=("skeleton",),
    category="skeleton",
)
def tag_skeleton(ctx, clear, branches, regions, sac_ratio, sac_tag, nodes):
    """A segment gets a rule's tag when both its end nodes do (branch tags go to the
    segments of the branch); segments still without tags take the tags both their nodes
    carry."""
    skel = ctx.skeleton
    _check_dict("regions", regions, "[x, y, z, radius]")
    _check_dict("nodes", nodes, "lists of node indices")
    node_tags = [()] * skel.n_nodes if clear else list(skel.node_tags)
    edge_tags = [()] * skel.n_edges if clear else list(skel.edge_tags)
    a, b = skel.edges.T
    tagged = {}

    def apply(mask, tag):
        nonlocal node_tags, edge_tags
        node_tags = sk_tags.tag_nodes(node_tags, mask, tag)
        edge_tags = sk_tags.tag_nodes(edge_tags, mask[a] & mask[b], tag)
        tagged[tag] = tagged.get(tag, 0) + int(mask.sum())

    if branches:
        tree = sk_tags.branch_tree(skel)
        node_tags = [tuple(t for t in x if not t.startswith("branch_")) for x in node_tags]
        edge_tags = [tuple(t for t in x if not t.startswith("branch_")) for x in edge_tags]
        for k, p in enumerate(tree.paths):
            node_tags = sk_tags.tag_nodes(node_tags, np.isin(np.arange(skel.n_nodes), p), f"branch_{k}")
        for e, k in enumerate(tree.edge_branch.tolist()):
            if k >= 0:
                edge_tags[e] = sk_graph._union(edge_tags[e], (f"branch_{k}",))
        ctx.count(branches=len(tree.paths))
    for tag, sphere in regions.items():
        if not isinstance(sphere, (list, tuple)) or len(sphere) != 4 or not all(isinstance(v, (int, float)) for v in sphere):
            raise InputError(f"tag_skeleton: region '{tag}' must be [x, y, z, radius], got {sphere!r}")
        apply(sk_tags.nodes_in_sphere(skel.points, sphere[:3], float(sphere[3])), tag)
    if sac_ratio is not None:
        apply(sk_tags.sac_nodes(skel, sac_ratio), sac_tag)
    for tag, ids in nodes.items():
        ids = np.asarray(ids)
        if ids.dtype.kind not in "iu" or (len(ids) and (ids.min() < 0 or ids.max() >= skel.n_nodes)):
            raise InputError(f"tag_skeleton: node list '{tag}' must hold node indices 0..{skel.n_nodes - 1}")
        mask = np.zeros(skel.n_nodes, bool)
        mask[ids.astype(np.int64)] = True
        apply(mask, tag)
    out = skel.copy(node_tags=node_tags, edge_tags=edge_tags)
    out.edge_tags = sk_tags.derive_edge_tags(out)
    ctx.skeleton = out
    ctx.count(tags=len(out.tag_names()), **{f"tagged_{k}": v for k, v in tagged.items()})


# ---------------------------------------------------------------------------
# rendering
# ---------------------------------------------------------------------------


def render_skeleton_png(path, skeleton, surface=None, size=(1200, 900), opacity=0.2, title: str | None = None) -> Path:
    """Render the skeleton (segments coloured by radius, junctions red, endpoints blue)
    over the transparent surface, off-screen, to a PNG file (written atomically).

    The camera looks along the direction in which the skeleton is thinnest (its least
    principal axis), so planar trees are seen face-on.
    """
    from ..io.atomic import atomic_path
    from ..render import _setup

    pv = _setup()  # off screen, VTK's display fallback quiet
    path = Path(path)
    plotter = pv.Plotter(off_screen=True, window_size=list(size))
    try:
        plotter.set_background("white")
        if surface is not None and surface.n_faces:
            plotter.add_mesh(surface.to_pyvista(), color="#d8c8c0", opacity=opacity, smooth_shading=True)
        scale = float(np.nanmedian(skeleton.radii)) if np.isfinite(skeleton.radii).any() else 1.0
        if skeleton.n_edges:
            lines = pv.PolyData(skeleton.points.copy(), lines=np.c_[np.full(skeleton.n_edges, 2), skeleton.edges].ravel())
            lines.point_data["radius"] = skeleton.radii
            plotter.add_mesh(
                lines,
                scalars="radius",
                cmap="viridis",
                line_width=5,
                render_lines_as_tubes=True,
                nan_color="gray",
                scalar_bar_args={"title": "radius", "color": "black", "vertical": True},
            )
        deg = skeleton.degrees
        if 0 < skeleton.n_nodes <= 5000 and (deg == 2).any():  # coarse skeletons: show where the nodes are
            plotter.add_points(skeleton.points[deg == 2], color="black", point_size=6, render_points_as_spheres=True)
        size = 0.3 * np.where(np.isfinite(skeleton.radii), skeleton.radii, scale)
        for mask, color in ((deg >= 3, "red"), (deg == 1, "royalblue"), (deg == 0, "black")):
            if mask.any():
                centres = pv.PolyData(skeleton.points[mask])
                centres.point_data["size"] = size[mask]
                glyphs = centres.glyph(geom=pv.Sphere(radius=1.0), scale="size", orient=False)
                plotter.add_mesh(glyphs, color=color, smooth_shading=True)
        s = skeleton.summary()
        text = title if title is not None else skeleton.name
        text = f"{text}\n{s['nodes']} nodes, {s['segments']} segments, {s['junctions']} junctions, {s['endpoints']} endpoints, {s['cycles']} cycles"
        plotter.add_text(text, font_size=10, color="black")
        from ..render import view_frame

        centre, view, up, extent = view_frame(skeleton.points if surface is None or not surface.n_vertices else surface.vertices)
        plotter.camera_position = [tuple(centre + 3 * extent * view), tuple(centre), tuple(up)]
        plotter.reset_camera()
        with atomic_path(path) as tmp:
            plotter.screenshot(str(tmp))
    finally:
        plotter.close()
    return path


@register_filter(
    description="Render the skeleton over the transparent surface to a PNG in the output folder (off-screen).",
    parameters=[
        Parameter("filename", "str", "skeleton.png", "File name in the output folder."),
        Parameter("width", "int", 1200, "Image width.", unit="pixels", min=64, max=8192),
        Parameter("height", "int", 900, "Image height.", unit="pixels", min=64, max=8192),
        Parameter("surface_opacity", "float", 0.2, "Opacity of the surface (0 hides it).", min=0.0, max=1.0),
    ],
    reads=("skeleton",),
    optional_reads=("surface",),
    category="export",
)
def render_skeleton(ctx, filename, width, height, surface_opacity):
    path = ctx.output_file(filename)
    if path is None:
        return
    surface = ctx.surface if surface_opacity > 0 else None
    try:
        render_skeleton_png(path, ctx.skeleton, surface, (width, height), surface_opacity)
    except (RuntimeError, OSError, ImportError) as exc:  # no OpenGL context on this machine
        ctx.warn(f"could not render {filename}: {type(exc).__name__}: {exc}")
