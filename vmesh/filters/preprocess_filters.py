"""Preprocessing and implicit-surface filters: repair, capping, cap detection, Loop
smoothing, decimation and the signed distance (thin wrappers of :mod:`vmesh.preprocess`
and :mod:`vmesh.geometry.sdf`).

Caps follow the surface through every filter as the per-face array
``surface.face_data["cap_id"]`` (0 = wall, k = id of cap k); ``ctx.caps`` holds their
geometry and names.
"""

from __future__ import annotations

import dataclasses
import time
import warnings

import numpy as np

from .. import preprocess as pre
from ..errors import InputError, ParameterError
from ..preload import LATER_STEPS
from ..registry import Parameter, register_filter
from ..surface import SurfaceMesh


# ---------------------------------------------------------------------------
# cap bookkeeping shared by the filters
# ---------------------------------------------------------------------------
def cap_labels(ctx, surface: SurfaceMesh | None = None) -> np.ndarray:
    """Per-face cap ids of ``surface`` (default ``ctx.surface``): from its ``cap_id``
    array, else from ``ctx.caps[i].faces``, else all zero."""
    surface = ctx.surface if surface is None else surface
    labels = surface.face_data.get(pre.CAP_LABEL)
    if labels is not None and len(labels) == surface.n_faces:
        return np.asarray(labels, np.int64)
    labels = np.zeros(surface.n_faces, np.int64)
    for cap in ctx.caps or []:
        faces = np.asarray(cap.faces, np.int64)
        if len(faces) and faces.max() < surface.n_faces:
            labels[faces] = cap.id
    return labels


def set_caps(ctx, surface: SurfaceMesh, labels: np.ndarray, inlet=None, inlet_point=None, keep_names: bool = False, needs_end=None) -> None:
    """Compute cap geometry from face labels, name the caps, store surface and caps.

    ``needs_end``: the label ids of the caps that need an end (``Cap.needs_end``); by
    default those of ``ctx.caps`` with the same ids (labels that carry ``ctx.caps``' ids)."""
    caps = pre.caps_from_labels(surface.vertices, surface.faces, labels)
    if needs_end is None:
        needs_end = {c.id for c in ctx.caps or [] if c.needs_end}
    for c in caps:  # before naming: the caps that need an end are named after the sure ones
        c.needs_end = c.id in needs_end
    if keep_names and ctx.caps:
        names = {c.id: c.name for c in ctx.caps}
        for c in caps:
            c.name = names.get(c.id, c.name)
        mapping = {c.id: c.id for c in caps}
    else:
        try:
            caps, mapping = pre.name_caps(caps, inlet=inlet, inlet_point=inlet_point)
        except ValueError as exc:
            raise ParameterError(str(exc)) from None
    _store_cap_labels(ctx, surface, pre.relabel(labels, mapping) if mapping else labels, caps)
    ctx.caps = caps
    ctx.report.sections["caps"] = [c.as_dict() for c in caps]


def _store_cap_labels(ctx, surface: SurfaceMesh, labels: np.ndarray, caps) -> None:
    """Put the cap labels on ``surface`` (the context's surface from now on) and each cap's faces."""
    surface.face_data[pre.CAP_LABEL] = labels.astype(np.int32)
    for c in caps:
        c.faces = np.flatnonzero(labels == c.id)
    ctx.surface = surface


def walls_not_caps(ctx, dropped) -> dict:
    """Turn caps that need an end and that no skeleton end reaches back into wall.

    Parameters
    ----------
    ctx : Context
        Its ``caps`` (and the ``cap_id`` labels of its surface, if any) are updated.
    dropped : iterable of int
        Indices into ``ctx.caps`` of the flat regions that are facets of the wall.

    Returns
    -------
    dict
        Old name -> new name of every cap left. The caps left keep their geometry (an
        inward surface's flipped normals too); they are renumbered ``inlet``,
        ``outlet_1``, ... with ids 1..n in their former order, so that names and ids stay
        contiguous; where the inlet was dropped, the widest cap left that is known to be an
        end (else the widest) becomes the inlet. Their dropped names are added to the
        report section ``caps_turned_wall``.
    """
    dropped = sorted(set(int(i) for i in dropped))
    names = [ctx.caps[i].name for i in dropped]
    ctx.warn(
        f"{len(names)} flat region(s) taken for caps ({', '.join(names[:6])}{', ...' if len(names) > 6 else ''}) "
        "are facets of the wall, not ends: no skeleton end reaches them and the wall behind them is no tube "
        "of their size (the terraces of a voxel staircase surface?); labelled wall"
    )
    ctx.report.sections["caps_turned_wall"] = [*ctx.report.sections.get("caps_turned_wall", []), *names]
    gone = {ctx.caps[i].id for i in dropped}
    kept = sorted((c for c in ctx.caps if c.id not in gone), key=lambda c: c.id)
    if kept and not any(c.name == "inlet" for c in kept):
        first = max(kept, key=lambda c: (not c.needs_end, c.radius))
        kept = [first] + [c for c in kept if c is not first]
    ids = {c.id: k for k, c in enumerate(kept, start=1)}
    caps = [dataclasses.replace(c, id=k, name="inlet" if k == 1 else f"outlet_{k - 1}") for c, k in zip(kept, ids.values())]
    if ctx.surface is not None:
        labels = cap_labels(ctx).copy()
        labels[np.isin(labels, list(gone))] = 0
        _store_cap_labels(ctx, ctx.surface.copy(), pre.relabel(labels, ids), caps)
    ctx.caps = caps
    ctx.report.sections["caps"] = [c.as_dict() for c in caps]
    return {old.name: new.name for old, new in zip(kept, caps)}


def _pad_face_data(face_data: dict, n_old: int, n_new: int) -> dict:
    """Extend per-face arrays to ``n_new`` faces (new faces: -1 for integers, NaN for floats)."""
    out = {}
    for key, arr in face_data.items():
        arr = np.asarray(arr)
        if len(arr) != n_old or key == pre.CAP_LABEL:
            continue
        if np.issubdtype(arr.dtype, np.integer):
            fill = -1
        elif np.issubdtype(arr.dtype, np.floating):
            fill = np.nan
        else:
            continue
        out[key] = np.concatenate([arr, np.full((n_new - n_old, *arr.shape[1:]), fill, arr.dtype)])
    return out


def _surface_name(ctx) -> str:
    return (ctx.surface.name if ctx.surface is not None else "") or "surface"


INLET_PARAMETERS = [
    Parameter(
        "inlet",
        "int",
        None,
        "Which cap is the inlet: its position when caps are ordered by decreasing radius (1 = largest). "
        "Automatic: the largest cap.",
        min=1,
    ),
    Parameter("inlet_point", "float_list", None, "Name the cap whose centre is nearest to this point (x, y, z) the inlet.", unit="mm"),
]


def _check_point(inlet_point):
    if inlet_point is not None and len(inlet_point) != 3:
        raise ParameterError(f"inlet_point needs three numbers, got {inlet_point!r}")


# ---------------------------------------------------------------------------
# filters
# ---------------------------------------------------------------------------
@register_filter(
    description="Clean the surface: weld duplicate vertices, drop degenerate and duplicate faces, keep the largest piece, orient faces consistently and outward, fill holes in the wall.",
    parameters=[
        Parameter(
            "merge_tolerance",
            "float",
            1e-7,
            "Weld vertices closer than this fraction of the bounding-box diagonal (0: identical coordinates only).",
            unit="× diagonal",
            min=0.0,
            max=0.01,
        ),
        Parameter("keep", "str", "largest", "Keep only the largest connected piece (by area), or all pieces. Dropped pieces are named in a warning and in report.json (surface.dropped_components).", choices=("largest", "all")),
        Parameter("orient", "bool", True, "Make neighbouring faces agree on orientation, then turn each piece outward (positive enclosed volume)."),
        Parameter("fill_holes", "bool", True, "Close holes in the wall (boundary loops whose surrounding faces lie nearly in the loop's plane, unlike open ends) with a patch faired into the wall, with a warning naming each; open ends are left to cap_open_ends."),
        Parameter("debris_area", "float", 1e-3, "Dropped pieces smaller than this fraction of the kept piece's area are debris: only counted, not named in a warning.", unit="× kept area", min=0.0, max=1.0),
        Parameter(
            "cut_handles",
            "bool",
            True,
            "Cut out thin strands of outside material that cross the lumen (segmentation artefacts that make the surface a torus: "
            "a handle whose shortest non-separating loop goes round the strand with lumen all round it) and fill the wall where "
            "they stood, with a warning naming each. A real loop of vessels is kept (its short loop goes round the lumen). "
            "Genus-0 surfaces are left as they are (docs/junctions.md, h26/handle).",
        ),
        Parameter("hole_wall_beyond", "bool", False, "Count a loop as a hole only when the wall also goes on past it on two opposite sides, so that a vessel's open end whose rim is bevelled into a flange (the wall flaring out in the end plane, as at the ends of short or narrow vessels) stays an open end. Off by default: some surfaces that mesh with such an end filled then fail elsewhere (docs/junctions.md)."),
    ],
    reads=("surface",),
    optional_reads=("caps",),
    writes=("surface", "caps"),  # caps: cleared (they index the old faces)
    updates=("caps",),
    category="preprocessing",
)
def repair_surface(ctx, merge_tolerance, keep, orient, fill_holes, debris_area, hole_wall_beyond=False, cut_handles=True):
    """Repair the input surface and report what was removed or flipped.

    Open surfaces are oriented outward by their volume relative to the centroid (an
    estimate); ``cap_open_ends`` re-checks the orientation once the surface is closed.
    """
    s = ctx.surface
    v, f, data, report = pre.repair(
        s.vertices, s.faces, merge_tolerance=merge_tolerance * s.diagonal, keep=keep, orient=orient, outward=orient, face_data=s.face_data,
        debris_area=debris_area, fill_wall_holes=fill_holes, hole_wall_beyond=hole_wall_beyond,
    )
    if len(f) == 0:
        raise InputError("no faces left after removing degenerate and duplicate faces", _surface_name(ctx))
    if cut_handles and orient and not report.non_orientable:
        v, f, data = _cut_handles(ctx, v, f, data)
    ctx.surface = SurfaceMesh(v, f, name=s.name, face_data=data)
    info = report.as_dict()
    ctx.report.sections["repair"] = info
    ctx.count(
        triangles=len(f),
        merged_vertices=report.merged_vertices,
        removed_faces=report.degenerate_faces + report.duplicate_faces + report.removed_component_faces,
        removed_components=report.removed_components,
        flipped_faces=report.flipped_faces,
    )
    _report_dropped_components(ctx, report)
    if report.filled_holes:
        largest = max(report.filled_holes, key=lambda h: h["diameter"])
        ctx.count(filled_holes=len(report.filled_holes))
        ctx.warn(
            f"filled {len(report.filled_holes)} hole(s) in the wall (the largest {largest['diameter']:.3g} across, "
            f"at ({', '.join(f'{x:.4g}' for x in largest['center'])})): check the input surface there "
            f"(repair_surface.fill_holes=false leaves them open)"
        )
    if report.non_orientable:
        ctx.warn("surface is not orientable: orientation left partly inconsistent")
    if report.nonmanifold_edges:
        ctx.warn(f"{report.nonmanifold_edges} non-manifold edges remain (use meshlab_filter meshing_repair_non_manifold_edges)")
    if report.zero_area_faces:
        ctx.warn(f"{report.zero_area_faces} zero-area faces with distinct vertices kept (they do not open the surface)")
    if ctx.caps:
        ctx.caps = None
        ctx.warn("caps were dropped: run cap_open_ends or detect_caps after repair_surface")


def _cut_handles(ctx, v, f, data):
    """Cut the thin handles through the lumen out of the repaired surface (report section
    ``handles``, a warning naming the largest); patches get 0 in every face array."""
    from ..geometry.handles import cut_thin_handles

    v, f, origin, cuts = cut_thin_handles(v, f)
    ctx.report.sections["handles"] = cuts
    if not cuts:
        return v, f, data
    data = {k: np.where((origin >= 0).reshape(-1, *[1] * (a.ndim - 1)), a[np.maximum(origin, 0)], 0).astype(a.dtype) for k, a in data.items()}
    widest = max(cuts, key=lambda c: c["radius"])
    ctx.count(cut_handles=len(cuts))
    ctx.warn(
        f"cut {len(cuts)} thin handle(s) through the lumen (strands of outside material, the thickest "
        f"{2 * widest['radius']:.3g} across at ({', '.join(f'{x:.4g}' for x in widest['center'])})) and filled the wall "
        f"where they stood: check the input surface there (repair_surface.cut_handles=false keeps them)"
    )
    return v, f, data


def _report_dropped_components(ctx, report) -> None:
    """Name the pieces ``repair`` dropped (size, bounding box) in a warning and in the
    report's ``surface`` section; debris is only counted."""
    section = ctx.report.sections.setdefault("surface", {})
    section["dropped_components"] = [dict(c) for c in report.dropped_components]
    section["debris_components"] = report.debris_components
    if report.dropped_components:
        listed = "; ".join(
            f"{c['faces']} faces, {100 * c['area_fraction']:.2g} % of its area, box "
            f"({', '.join(f'{x:.4g}' for x in c['bbox_min'])}) - ({', '.join(f'{x:.4g}' for x in c['bbox_max'])})"
            for c in report.dropped_components[:5]
        )
        more = len(report.dropped_components) - 5
        ctx.warn(
            f"the surface has {report.removed_components + 1} separate pieces: meshing the largest "
            f"({ctx.surface.n_faces} faces) and dropping {len(report.dropped_components)} other(s) [{listed}]"
            + (f" and {more} more" if more > 0 else "")
            + (f", and {report.debris_components} debris piece(s)" if report.debris_components else "")
            + " (repair_surface.keep=all keeps every piece; mesh each piece from its own file)"
        )


def _centerline_with_radii(ctx):
    """The given centerline as ``(points, radii, edges)`` when every node has a radius."""
    sk = ctx.skeleton
    if sk is None or not len(sk.edges) or not np.all(np.isfinite(sk.radii)) or not np.all(sk.radii > 0):
        return None
    return sk.points, sk.radii, sk.edges


def _warn_windows(ctx, windows: list) -> None:
    """Name the open ends whose rim took in a passing vessel's wall (report section ``cap_windows``)."""
    if not windows:
        return
    ctx.report.sections["cap_windows"] = windows
    for w in windows:
        ctx.warn(
            f"open end {w['label']} (rim of {w['rim']} vertices) runs over the wall of a vessel of the centerline that passes it "
            f"({w['window']} rim vertices around ({', '.join(f'{x:.4g}' for x in w['center'])})): that part was closed as wall, the rest capped"
        )


@register_filter(
    description="Close every open end with a flat cap and record the caps as named inlet/outlet boundaries.",
    parameters=[
        Parameter(
            "method",
            "str",
            "rings",
            "'rings': concentric rings of triangles sized like the rim edges, zipped to the rim, with a centre fan; "
            "'meshlab': pymeshlab hole filling (meshing_close_holes) with refinement, which can leave sliver triangles on the cap "
            "(harmless for the signed distance; 'rings' gives well-shaped caps).",
            choices=("rings", "meshlab"),
        ),
        Parameter("rings", "int", None, "Inner rings per cap for method 'rings' (0: a plain centre fan). Automatic: about radius / rim edge length.", min=0, max=200),
        Parameter("detect_if_closed", "bool", True, "On a surface without open ends, find its flat end caps instead (as detect_caps with default settings)."),
        Parameter(
            "split_windows",
            "bool",
            True,
            "Where a centerline with radii is given (method 'rings'): an open end whose rim also runs over the wall of a vessel "
            "passing it (a cut through two touching vessels) has that part of the rim closed as wall, faired into it, and only "
            "the rest capped (a flat cap across the whole rim would cross the passing vessel's lumen). The wall of the parent a "
            "short branch grows out of is no such window. Without a centerline (extracted runs) every end is capped whole. "
            "On, a given centerline keys the cached prefix (with either method, whether or not an end has a window); "
            "off, it does not (docs/robustness.md, h22/fold, h23/windows).",
        ),
        *INLET_PARAMETERS,
    ],
    reads=("surface",),
    optional_reads=("skeleton",),
    reads_when={"skeleton": "split_windows"},  # a prefix without the split is shared by every centerline
    writes=("surface", "caps"),
    category="preprocessing",
)
def cap_open_ends(ctx, method, rings, detect_if_closed, split_windows, inlet, inlet_point):
    """Cap each boundary loop; the largest cap (by rim radius) becomes ``inlet``, the
    others ``outlet_1``, ``outlet_2``, ... by decreasing radius, with ids 1..n.

    After capping the surface is closed and is turned outward by its exact signed volume.
    """
    from ..geometry import topology

    _check_point(inlet_point)
    s = ctx.surface
    if not topology.is_consistently_oriented(s.faces):
        raise InputError("faces are not consistently oriented: run repair_surface before cap_open_ends", _surface_name(ctx))
    loops = topology.boundary_loops(s.faces)
    if not loops and detect_if_closed:
        from ..registry import get_filter

        get_filter("detect_caps")(ctx, inlet=inlet, inlet_point=inlet_point)
        return
    if not loops:
        ctx.warn("surface has no open ends; use detect_caps to find flat caps of a closed surface")
        set_caps(ctx, s.copy(), cap_labels(ctx), inlet, inlet_point)
        ctx.count(caps=len(ctx.caps))
        return
    centerline = _centerline_with_radii(ctx) if split_windows else None
    if centerline is not None and method != "rings":  # a centerline to split by, and a method that cannot
        from ..rim_windows import window_on_passing_branch

        points, radii, edges = centerline
        if any(window_on_passing_branch(s.vertices[lp], points, radii, edges).any() for lp in topology.join_touching(loops)):
            ctx.warn(f"an open end's rim runs over the wall of a passing vessel, which split_windows closes only with method 'rings'; with '{method}' every open end is capped whole")
        centerline = None
    if centerline is not None:
        from ..rim_windows import cap_loops_splitting_windows

        v, f, labels, windows = cap_loops_splitting_windows(s.vertices, s.faces, centerline, rings=rings)
        _warn_windows(ctx, windows)
    else:
        v, f, labels = pre.cap_boundary_loops(s.vertices, s.faces, rings=rings, method=method)
    old = np.asarray(s.face_data.get(pre.CAP_LABEL, np.zeros(s.n_faces)), np.int64)
    if old.any():  # keep caps found earlier, number the new ones after them
        labels = np.where(labels > 0, labels + old.max(), np.concatenate([old, np.zeros(len(f) - s.n_faces, np.int64)]))
    if topology.boundary_loops(f):
        raise InputError("capping left open ends (boundary loops touch each other); try method='meshlab'", _surface_name(ctx))
    if topology.signed_volume(v, f) < 0:
        f = np.ascontiguousarray(f[:, ::-1])
    face_data = _pad_face_data(s.face_data, s.n_faces, len(f)) if method == "rings" else {}
    capped = SurfaceMesh(v, f, name=s.name, face_data=face_data)
    kept = {c.id for c in ctx.caps or [] if c.needs_end} if old.any() else set()  # the earlier caps keep their ids here
    set_caps(ctx, capped, labels, inlet, inlet_point, needs_end=kept)
    ctx.count(caps=len(ctx.caps), cap_triangles=int((labels > 0).sum()), triangles=len(f))


@register_filter(
    description="Find the flat end caps of a closed surface (planar, round regions bounded by a crease) and name them inlet/outlets.",
    parameters=[
        Parameter("angle_tolerance", "float", 2.0, "Faces whose normals differ by less than this belong to the same flat region.", unit="degrees", min=0.0, max=30.0),
        Parameter("min_crease_angle", "float", 30.0, "Mean angle between a cap and the wall faces around it.", unit="degrees", min=0.0, max=180.0),
        Parameter("min_roundness", "float", 0.5, "Minimum 4π·area/perimeter² of a cap region (1 for a disc; long strips of a tube wall score low).", min=0.0, max=1.0),
        Parameter("min_faces", "int", 6, "Minimum number of faces of a cap region.", min=1),
        Parameter("planarity", "float", 0.02, "Largest distance of a cap vertex from the cap plane, relative to the cap's equivalent radius.", min=0.0, max=1.0),
        *INLET_PARAMETERS,
    ],
    reads=("surface",),
    writes=("surface", "caps"),
    category="preprocessing",
)
def detect_caps(ctx, angle_tolerance, min_crease_angle, min_roundness, min_faces, planarity, inlet, inlet_point):
    """Label the flat end caps of an already closed surface (synthetic cases, closed real
    cases) so that later stages can name inlets and outlets as after ``cap_open_ends``."""
    from ..geometry import topology

    _check_point(inlet_point)
    s = ctx.surface
    if topology.boundary_loops(s.faces):
        ctx.warn("surface has open ends: cap_open_ends closes them and records the caps")
    f = s.faces if topology.signed_volume(s.vertices, s.faces) >= 0 else s.faces[:, ::-1]
    labels = pre.detect_flat_caps(
        s.vertices, f, angle_tolerance=angle_tolerance, min_crease_angle=min_crease_angle, min_roundness=min_roundness, min_faces=min_faces, planarity=planarity
    )
    surface = s.copy()
    surface.face_data.pop(pre.CAP_LABEL, None)
    doubted = set(pre.flat_caps_needing_an_end(s.vertices, f, labels))  # before naming: the inlet is a sure cap
    set_caps(ctx, surface, labels, inlet, inlet_point, needs_end=doubted)
    if f is not s.faces:  # cap normals must point out of the vessel even if the faces point inward
        for c in ctx.caps:
            c.normal = -c.normal
    ctx.report.sections["caps"] = [c.as_dict() for c in ctx.caps]
    ctx.count(caps=len(ctx.caps))
    if not ctx.caps:
        # the naming is news only where a mesh follows (not to `vmesh skeleton`)
        meshed = any(step.filter == "mesh_transfinite" for step in LATER_STEPS.get())
        ctx.warn("no flat caps found (rounded ends?)" + (": the mesh's open ends will be named from the skeleton's endpoints, the widest one inlet" if meshed else ""))


@register_filter(
    description="Smooth by Loop subdivision (pymeshlab), on the whole surface or only near skeleton junctions, then optional Taubin smoothing.",
    parameters=[
        Parameter("iterations", "int", 1, "Loop subdivision steps (each splits every selected edge: about 4× the faces there).", min=0, max=6),
        Parameter(
            "region",
            "str",
            "auto",
            "Where to subdivide: 'all' faces, or faces near skeleton 'junctions'; 'auto' uses junctions when a skeleton with junctions is present.",
            choices=("auto", "all", "junctions"),
        ),
        Parameter("junction_distance", "float", 2.0, "Faces within this many node radii of a junction node are smoothed (region 'junctions').", unit="× radius", min=0.0),
        Parameter("edge_threshold", "float", 0.0, "Only edges longer than this are split (0 splits all, a uniform subdivision).", unit="mm", min=0.0),
        Parameter("weights", "str", "Loop", "pymeshlab's weighting scheme.", choices=("Loop", "Enhance regularity", "Enhance continuity")),
        Parameter("taubin_iterations", "int", 0, "Taubin λ|μ smoothing steps after subdivision (0: none).", min=0, max=1000),
        Parameter("taubin_lambda", "float", 0.5, "Taubin's positive step factor λ.", min=0.0, max=1.0),
        Parameter("taubin_mu", "float", -0.53, "Taubin's negative step factor μ (μ < -λ avoids shrinkage).", min=-1.0, max=0.0),
        Parameter("preserve_caps", "bool", True, "Leave flat caps flat: do not subdivide them, keep their vertices in their planes."),
    ],
    reads=("surface",),
    optional_reads=("skeleton", "caps"),
    writes=("surface", "caps"),
    category="preprocessing",
)
def smooth_loop(ctx, iterations, region, junction_distance, edge_threshold, weights, taubin_iterations, taubin_lambda, taubin_mu, preserve_caps):
    """Loop subdivision smoothing (``meshing_surface_subdivision_loop``), optionally local to
    the junctions of ``ctx.skeleton``, followed by Taubin smoothing."""
    s = ctx.surface
    labels = cap_labels(ctx)
    skeleton = ctx.skeleton
    junctions = skeleton.junctions if skeleton is not None else np.zeros(0, np.int64)
    if region == "auto":
        region = "junctions" if len(junctions) else "all"
    if region == "junctions":
        if skeleton is None:
            raise InputError("region 'junctions' needs a skeleton (give --skeleton FILE or extract one first)")
        if not len(junctions):
            ctx.warn("skeleton has no junctions: nothing smoothed")
            return
        mask = pre.faces_near_points(s.vertices, s.faces, skeleton.points[junctions], junction_distance * skeleton.radii[junctions])
    else:
        mask = np.ones(s.n_faces, bool)
    if preserve_caps:
        mask &= labels == 0
    caps = ctx.caps or []
    v, f, new_labels = s.vertices, s.faces, labels
    if iterations and mask.any():
        ctx.tick(0.1, "Loop subdivision")
        v, f, new_labels = pre.loop_subdivide(
            v, f, iterations=iterations, edge_threshold=edge_threshold, weights=weights, face_mask=None if mask.all() else mask, labels=labels
        )
    if taubin_iterations:
        ctx.tick(0.6, "Taubin smoothing")
        fixed = np.zeros(len(v), bool)
        if preserve_caps:
            fixed[f[new_labels > 0].ravel()] = True
        if region == "junctions":
            # smooth only around the junctions: vertices of the refined region
            near = pre.faces_near_points(v, f, skeleton.points[junctions], junction_distance * skeleton.radii[junctions])
            moved = np.zeros(len(v), bool)
            moved[f[near].ravel()] = True
            fixed |= ~moved
        v = pre.taubin_smooth(v, f, taubin_iterations, taubin_lambda, taubin_mu, fixed=fixed)
    if preserve_caps and caps:
        v = pre.flatten_caps(v, f, new_labels, caps)
    same_faces = len(f) == s.n_faces
    face_data = {k: a for k, a in s.face_data.items() if same_faces and k != pre.CAP_LABEL}
    smoothed = SurfaceMesh(v, f, name=s.name, face_data=face_data)
    if caps or new_labels.any():
        set_caps(ctx, smoothed, new_labels, keep_names=True)
    else:
        ctx.surface = smoothed
    ctx.count(triangles=len(f), smoothed_faces=int(mask.sum()), region=region)


@register_filter(
    description="Quadric edge-collapse decimation (pymeshlab or fast-simplification) to a face count or ratio; writes the coarse surface.",
    parameters=[
        Parameter("backend", "str", "pymeshlab", "pymeshlab's meshing_decimation_quadric_edge_collapse (topology, boundary and normals preserved) or fast_simplification (faster).", choices=("pymeshlab", "fast_simplification")),
        Parameter("target_faces", "int", None, "Number of triangles to reach (automatic: max(20000, a tenth of the input); smaller surfaces are kept as they are).", unit="faces", min=4),
        Parameter("target_ratio", "float", None, "Fraction of the triangles to keep. Without either target: 10 % of the faces, at least 20,000.", min=1e-6, max=1.0),
        Parameter("preserve_boundary", "bool", True, "Do not move or collapse open-boundary edges."),
        Parameter("preserve_topology", "bool", True, "pymeshlab: refuse collapses that change the topology (no new holes or handles)."),
        Parameter("quality_threshold", "float", 0.3, "pymeshlab: penalise collapses creating triangles of lower quality than this.", min=0.0, max=1.0),
        Parameter("aggressiveness", "float", 7.0, "fast_simplification: higher is faster but less accurate.", min=0.0, max=20.0),
        Parameter("output", "str", "coarse_surface", "Layer receiving the result; 'surface' decimates the input in place.", choices=("coarse_surface", "surface")),
        Parameter(
            "max_error",
            "float",
            None,
            "Tolerance on the coarse surface, relative to the local vessel radius (e.g. 0.015): when a fine vertex lies farther "
            "from the result, decimate again to more faces (about faces x error / tolerance, up to 5 tries). Off by default.",
            min=1e-6,
            max=1.0,
        ),
    ],
    reads=("surface",),
    optional_reads=("caps",),
    writes=("coarse_surface", "surface", "caps"),  # surface and caps with output="surface"
    updates=("caps",),
    category="preprocessing",
)
def decimate_surface(ctx, backend, target_faces, target_ratio, preserve_boundary, preserve_topology, quality_threshold, aggressiveness, output, max_error):
    """Decimate the fine surface; the result is the *coarse* surface used for a fast signed
    distance, while ``ctx.surface`` stays the fine one (unless ``output='surface'``).

    The largest deviation of the fine vertices from the result is reported
    (``max_deviation``, in surface units and relative to the bounding-box diagonal).
    """
    if target_faces is not None and target_ratio is not None:
        raise ParameterError("give target_faces or target_ratio, not both")
    s = ctx.surface
    automatic = target_faces is None and target_ratio is None
    if target_faces is None:
        target_faces = int(round(s.n_faces * target_ratio)) if target_ratio is not None else min(s.n_faces, max(20000, s.n_faces // 10))
    options = dict(backend=backend, preserve_boundary=preserve_boundary, preserve_topology=preserve_topology, quality_threshold=quality_threshold, aggressiveness=aggressiveness)
    tries, stored = None, None
    with warnings.catch_warnings(record=True) as caught:  # the backend fallback goes into the report
        warnings.simplefilter("always", RuntimeWarning)
        if max_error is None:
            v, f, stored = _decimate_and_index(ctx, target_faces, options, prepare=output != "surface")
        else:
            labels = s.face_data.get(pre.CAP_LABEL)
            wall = None if labels is None or len(labels) != s.n_faces else np.asarray(labels) == 0
            v, f, tries = pre.decimate_to_tolerance(s.vertices, s.faces, target_faces, max_error, wall_faces=wall, **options)
    for message in dict.fromkeys(str(w.message) for w in caught if issubclass(w.category, RuntimeWarning)):
        ctx.warn(message)
    if tries:  # max_error's decimations (a warning, e.g. the backend fallback, used to reach this without them)
        for k, (n_faces, err) in enumerate(tries, 1):
            ctx.tick(k / len(tries), f"{n_faces} faces: max error {100 * err:.2f} % of the local radius")
        if tries[-1][1] > max_error:
            ctx.warn(f"coarse surface still {100 * tries[-1][1]:.2f} % of the radius off after {len(tries)} tries (tolerance {100 * max_error:.2f} %)")
    from ..geometry.projection import surface_tree

    coarse = SurfaceMesh(v, f, name=f"{s.name} (decimated)" if s.name else "decimated")
    # the coarse surface's tree is cached: build_sdf's signed distance reuses it
    if stored is not None and "max_deviation" in stored.arrays:
        deviation = float(stored.arrays["max_deviation"])
    else:
        deviation = float(np.sqrt(surface_tree(coarse).closest(s.vertices)[0].max())) if len(f) else 0.0
        if stored is not None:
            stored.save(vertices=v, faces=f, max_deviation=np.float64(deviation))
    if output == "surface":
        ctx.surface = coarse.copy(name=s.name)
        if ctx.caps:
            ctx.caps = None
            ctx.warn("caps refer to the old faces and were dropped: run detect_caps again")
    else:
        ctx.coarse_surface = coarse
    ctx.report.sections["decimation"] = {
        "backend": backend,
        "faces_in": s.n_faces,
        "faces_out": len(f),
        "target_faces": int(target_faces),
        "max_deviation": deviation,
        "max_deviation_rel_diagonal": deviation / max(s.diagonal, 1e-300),
    }
    if tries is not None:
        ctx.report.sections["decimation"].update(max_error=max_error, tries=[{"faces": n, "max_error_rel": e} for n, e in tries])
    ctx.count(faces_in=s.n_faces, faces_out=len(f), max_deviation=deviation, **({"max_error_rel": round(tries[-1][1], 5)} if tries else {}))
    if target_faces >= s.n_faces:
        if not automatic:  # the automatic target keeps surfaces under 20k faces on purpose
            ctx.warn(f"the surface has {s.n_faces} faces, no more than the target {target_faces}: kept as it is")
    elif abs(len(f) - target_faces) > 0.01 * target_faces and tries is None:
        ctx.warn(f"decimation stopped at {len(f)} faces, target was {target_faces} (topology or boundary constraints)")


def _decimate_and_index(ctx, target_faces, options, prepare: bool = True):
    """``pre.decimate`` of the fine surface; while pymeshlab decimates (it releases the GIL),
    the fine surface's tree and its wall projector, which build_sdf and the mesher query
    next, are built on the other core (cached per surface: docs/sdf.md), the later steps'
    modules are imported and what they will ask of the surface is built (the fine signed
    distance of a two-step ``build_sdf``, ``check_coverage``'s surface facts:
    :mod:`vmesh.preload`).

    pymeshlab's result is kept on disk (:mod:`vmesh.disk_cache`, keyed by the surface's bytes
    and the options): a rerun on the same surface reads it back. Returns the vertices, the
    faces and the :class:`_Stored` entry (None for other backends), which holds the cached
    arrays and saves new ones. ``prepare=False`` (the result replaces the surface) builds
    nothing for the later steps on the surface that is about to go."""
    s = ctx.surface
    if options["backend"] != "pymeshlab" or target_faces >= s.n_faces:
        return (*pre.decimate(s.vertices, s.faces, target_faces, **options), None)
    import threading

    from .. import disk_cache, preload
    from ..geometry.projection import wall_projector

    # pymeshlab is deterministic: the same surface and options give the same bytes, which a
    # rerun on this surface (other meshing parameters) reads back instead of ~2 s of collapses
    digest = disk_cache.key("pymeshlab quadric", _pymeshlab_version(), np.asarray(s.vertices), np.asarray(s.faces), int(target_faces), sorted(options.items()))
    hit = disk_cache.load("decimated", digest)
    if hit is not None and {"vertices", "faces"} <= hit.keys():
        ctx.count(cached=True)
        return hit["vertices"], hit["faces"], _Stored(digest, hit)
    result = {}

    def work():
        try:
            result["surface"] = pre.decimate(s.vertices, s.faces, target_faces, **options)
        except BaseException as exc:  # re-raised in the calling thread
            result["error"] = exc

    thread = threading.Thread(target=work, name="vmesh-decimate")
    thread.start()
    try:
        wall_projector(s)
        if ctx.caps:
            wall_projector(s, ctx.caps)
        # off the critical path (docs/speed.md, 20th round): the later steps' modules, and what
        # they will ask of this surface (build_sdf's fine distance, check_coverage's facts)
        preload.import_later_steps()
        if prepare:
            preload.prepare_surface(s)
    finally:
        thread.join()
    if "error" in result:
        raise result["error"]
    return (*result["surface"], _Stored(digest, {}))


class _Stored:
    """A decimation's entry in the disk cache: the arrays read back (empty when new)."""

    def __init__(self, digest: str, arrays: dict):
        self.digest, self.arrays = digest, arrays

    def save(self, **arrays) -> None:
        from .. import disk_cache

        disk_cache.store("decimated", self.digest, arrays)


def _pymeshlab_version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("pymeshlab")
    except PackageNotFoundError:  # pragma: no cover - an unpackaged build
        return "unknown"


@register_filter(
    description="Build the signed distance (positive inside, negative outside) with closest-point projection, from the fine or the coarse surface.",
    parameters=[
        Parameter("source", "str", "fine", "Surface to build it from: the fine input or the decimated coarse surface.", choices=("fine", "coarse")),
        Parameter(
            "sign",
            "str",
            "auto",
            "Inside test: angle-weighted 'pseudonormal' (exact on closed, manifold, oriented surfaces; fastest), "
            "generalised 'winding_number' (tolerates small defects), or 'auto' (pseudonormal where the surface allows it).",
            choices=("auto", "pseudonormal", "winding_number"),
        ),
        Parameter("refine_on_fine", "bool", False, "With source 'coarse': project on the coarse surface, then refine the projection on the fine surface (two-step projection)."),
        Parameter("check_points", "int", 2000, "Random points in the bounding box whose sign is checked against the winding number (0: no check).", min=0, max=10_000_000),
        Parameter(
            "index",
            "str",
            "bvh",
            "Closest-point search: the exact 'bvh', or an 'octree' of candidate triangles checked against it "
            "(5-7x faster for large batches, distances within octree_error radii at its check points; costs seconds to build).",
            choices=("bvh", "octree"),
        ),
        Parameter("octree_error", "float", 0.002, "With index 'octree': largest distance error at the octree's check points, in local radii.", min=1e-4, max=0.1),
    ],
    reads=("surface",),
    optional_reads=("coarse_surface",),
    writes=("sdf",),
    category="implicit surface",
)
def build_sdf(ctx, source, sign, refine_on_fine, check_points, index, octree_error):
    """Put a :class:`~vmesh.geometry.sdf.SignedDistance` (or, with ``refine_on_fine``, a
    :class:`~vmesh.geometry.sdf.TwoStepSignedDistance`; with ``index="octree"``, an
    :class:`~vmesh.geometry.octree_sdf.OctreeSignedDistance` over it) into ``ctx.sdf``.

    The surface must be closed (``cap_open_ends``) unless the winding-number sign is
    chosen; inward-oriented surfaces are handled (faces are flipped by signed volume).
    """
    from ..geometry.projection import surface_distance
    from ..geometry.sdf import SignedDistance, TwoStepSignedDistance

    if source == "coarse" and ctx.coarse_surface is None:
        raise InputError("source 'coarse' needs a coarse surface: add decimate_surface before build_sdf")
    if refine_on_fine and source != "coarse":
        raise ParameterError("refine_on_fine needs source 'coarse'")
    surface = ctx.coarse_surface if source == "coarse" else ctx.surface
    if sign != "winding_number":
        from ..geometry import topology

        n_open = len(topology.boundary_loops(surface.faces))
        if n_open:
            raise InputError(f"surface has {n_open} open ends: add cap_open_ends before build_sdf (or use sign 'winding_number')", surface.name or "surface")
    t0 = time.perf_counter()
    sdf = SignedDistance.from_surface(surface, sign=sign)
    if index == "octree":
        from ..geometry.octree_sdf import OctreeSignedDistance

        caps = surface.face_data.get("cap_id")
        wall = np.asarray(caps) == 0 if caps is not None and len(caps) == surface.n_faces else None
        sdf = OctreeSignedDistance(sdf, max_error=octree_error, wall_faces=wall)
    if refine_on_fine:  # the fine surface's distance: built while pymeshlab decimated, where it did
        sdf = TwoStepSignedDistance(sdf, surface_distance(ctx.surface, sign=sign))
    base = sdf.fine if refine_on_fine else sdf
    build_s = time.perf_counter() - t0
    info = {
        "source": source,
        "two_step": bool(refine_on_fine),
        "triangles": surface.n_faces,
        "sign": base.sign_method,
        "flipped_to_outward": base.flipped,
        "suspect_faces": base.n_suspect_faces,
        "build_s": build_s,
        "index": index,
    }
    octree = sdf.coarse if refine_on_fine else sdf
    if index == "octree":
        info.update(octree_leaves=octree.n_leaves, octree_exact_leaves=octree.n_exact_leaves, octree_candidates_mean=octree.candidates_mean, octree_error=octree_error)
    if check_points:
        rng = np.random.default_rng(0)
        lo, hi = sdf.bounds
        pts = rng.uniform(lo, hi, size=(check_points, 3))
        inside = sdf.distance(pts) > 0
        # the pseudonormal sign's surface is closed and oriented: its winding number is the
        # rays' signed crossings, exactly and without libigl (its import and tree: ~0.14 s CPU of the ICA's step)
        wn_inside = (base.ray_winding_number(pts) if base.sign_method == "pseudonormal" else base.winding_number(pts)) > 0.5
        disagree = int(np.sum(inside != wn_inside))
        info["sign_check_points"] = check_points
        info["sign_disagreements"] = disagree
        if disagree:
            ctx.warn(f"{disagree} of {check_points} random points get a different inside/outside answer from the winding number (surface self-intersects or has holes?)")
    ctx.sdf = sdf
    ctx.report.sections["sdf"] = info
    ctx.count(triangles=surface.n_faces, sign=base.sign_method, flipped=base.flipped)


@register_filter(
    description="Measure the coarse signed distance against the fine one: build time, queries per second, projection error relative to the local radius.",
    parameters=[
        Parameter("points", "int_list", [10_000, 100_000, 1_000_000], "Numbers of query points (around the wall, from the centreline to 0.3 radii outside).", min=1),
        Parameter("seed", "int", 0, "Random seed of the query points."),
        Parameter("filename", "str", "sdf_coarse_vs_fine.json", "Rows written to this file in the output folder (skipped without one)."),
        Parameter("octree", "bool", True, "Also measure the octree index (build_sdf index 'octree') over the coarse and the fine surface."),
    ],
    reads=("surface", "coarse_surface"),
    category="implicit surface",
)
def measure_sdf(ctx, points, seed, filename, octree):
    """Benchmark of the fine against the coarse (and two-step) signed distance, as in
    ``benchmarks/sdf_coarse_vs_fine.py``; rows go to the report's ``sdf_benchmark``
    section and to ``filename``."""
    import json

    from ..geometry import topology
    from ..geometry.sdf_measure import compare_coarse_fine
    from ..io.atomic import write_text_atomic

    for layer in ("surface", "coarse_surface"):
        surface = getattr(ctx, layer)
        if topology.boundary_loops(surface.faces):
            raise InputError(f"the {layer} layer has open ends: add cap_open_ends before measure_sdf", surface.name or layer)
    rows = compare_coarse_fine(ctx.surface, [ctx.coarse_surface], counts=points, seed=seed, case=ctx.surface.name, octree=octree)
    ctx.report.sections["sdf_benchmark"] = rows
    last = [r for r in rows if r["coarse_index"] == "bvh"][-1]
    ctx.count(qps_fine=last["qps_fine"], qps_coarse=last["qps_coarse"], speedup=last["speedup"], err_max_rel=last["err_max_rel"])
    if octree:
        tree = [r for r in rows if r["coarse_level"].endswith(", octree") and r["triangles_coarse"] == last["triangles_coarse"]][-1]
        ctx.count(qps_coarse_octree=tree["qps_coarse"], speedup_octree=tree["speedup"])
    path = ctx.output_path(filename)
    if path is not None:
        write_text_atomic(path, json.dumps(rows, indent=2))
