"""Extract a centerline skeleton from a signed distance function.

Pipeline (all distances in the SDF's unit, the signed distance positive inside),
one module a stage:

1. **Voxelise** the inside of the vessel (:mod:`.voxelize`) on a grid whose spacing
   follows the smallest vessel radius (:func:`~.voxelize.estimate_min_radius`),
   evaluating the SDF hierarchically: a cell whose centre is farther from the
   surface than its own half-diagonal has one sign throughout (the SDF is
   1-Lipschitz), so only cells near the wall are refined
   (:func:`~.voxelize.inside_mask`). Memory is one byte per voxel.
2. **Thin** the mask to a one-voxel-wide curve skeleton (:mod:`.thin`):
   distance-ordered homotopic thinning (topology preserving: tubes become curves
   along the ridge of the distance, a ring keeps its cycle).
3. **Trace** the voxel skeleton into a graph (:mod:`.trace`): 26-connected voxels,
   clusters of junction voxels collapsed into one node, chains of degree-2 voxels
   into ordered branches.
4. **Clean** the graph (:class:`~.branch_graph.BranchGraph`, :func:`clean_branch_graph`):
   drop specks, prune spurs that are short relative to the radius of the vessel they
   sprout from, merge junctions closer than about a radius (a 5-furcation becomes
   one degree-5 node), collapse tiny cycles made by voxel noise (true cycles are
   long compared to the radius); split side sacs the parent's path runs through off
   it as branches of their own (:mod:`.sacs`).
5. **Place the ends** (:mod:`.ends`): an end is moved to the centre of the cap it
   belongs to when caps are known, otherwise the branch is extended along its end
   tangent to the surface: to the last full cross-section behind a flat end face
   (:func:`~.end_faces.flat_end_sections`), or into a rounded end (an aneurysm dome)
   down to a depth where the inscribed radius is ``end_depth`` x the end radius.
6. **Smooth, resample and centre** every branch (:mod:`.resample`): nodes spaced by
   a multiple of the local radius, kept clear of junctions (where the medial axis of
   a crotch is not the vessel axis), moved within their cross-section plane to the
   centre of the section (:func:`~.probe.center_in_cross_sections`), radius =
   distance to the wall.
"""

from __future__ import annotations

import time
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Callable

import numpy as np

from ...skeleton import Skeleton
from . import spur_wall
from .branch_graph import BranchGraph
from .ends import extend_left_ends, place_ends, spurs_at_flat_ends
from .probe import SdfFunction, evaluate_sdf
from .resample import resample_branches
from .sacs import split_side_sacs
from .thin import voxel_skeleton
from .trace import build_branch_graph, trace_branches, voxel_adjacency
from .voxelize import choose_spacing, estimate_min_radius, grid_for_bounds, inside_mask


#: A cycle of the voxel skeleton whose lumen is everywhere thinner than this fraction of
#: the thinnest vessel the voxels resolve (``voxels_per_radius`` voxels) and of the thinnest
#: vessel estimated on the surface (a grid coarsened by ``max_voxels`` resolves less than
#: the surface holds, and a loop of such vessels is anatomy) is a tunnel where
#: the wall pinches (touching vessels, a ragged rim), not a vessel: it is cut even where
#: the surface's genus counts it (:meth:`~.branch_graph.BranchGraph.break_pinched_cycles`).
PINCHED_LUMEN = 0.5


@dataclass
class ExtractionSettings:
    """Parameters of :func:`extract_skeleton` (lengths relative to the local radius)."""

    # duplicates: same shape as repair.RepairReport/RepairOptions: both are field lists, not shared logic
    spacing: float | None = None
    voxels_per_radius: float = 3.0
    max_voxels: int = 60_000_000
    spur_ratio: float = 2.0
    spur_wall: bool = True
    merge_ratio: float = 1.0
    cycle_ratio: float = 6.0
    node_spacing: float = 1.0
    junction_clearance: float = 1.5
    end_depth: float = 0.5
    smoothing: float = 0.5
    ridge_slope: float = 0.0  # thin again anchored at flat ridges the skeleton leaves out (:func:`~.thin.unexplained_ridge_anchors`; 0: off)


def surface_genus(vertices: np.ndarray, faces: np.ndarray) -> int | None:
    """Number of independent cycles of the solid bounded by a closed surface
    (its total genus, ``(2 * components - Euler characteristic) / 2``); ``None`` for
    an open surface, whose genus says nothing about the solid."""
    from .. import topology

    faces = np.asarray(faces, np.int64)
    if len(faces) == 0 or topology.boundary_loops(faces):
        return None
    components = topology.face_components(faces, len(vertices))[0]
    genus2 = 2 * components - topology.euler_characteristic(faces)
    return max(genus2 // 2, 0)


class _CountingSdf:
    """An SDF that counts the points it is evaluated at (for the report)."""

    def __init__(self, sdf: SdfFunction):
        self.sdf = sdf
        self.evaluations = 0

    def __call__(self, points):
        self.evaluations += len(points)
        return self.sdf(points)


@contextmanager
def _timed(timings: dict, stage: str):
    """Record the wall time of a stage in ``timings[stage]``."""
    clock = time.perf_counter()
    yield
    timings[stage] = time.perf_counter() - clock


def _voxel_size(sdf, bounds, min_radius, surface, caps, settings: ExtractionSettings, tick, stats: dict) -> float:
    """The voxel spacing: given, or from the (estimated) smallest vessel radius."""
    if settings.spacing is not None:
        spacing, limited = float(settings.spacing), False
    else:
        if min_radius is None:
            if surface is None:
                raise ValueError("extract_skeleton needs spacing, min_radius or a surface")
            tick(0.0, "estimating the smallest vessel radius")
            min_radius = estimate_min_radius(sdf, *surface)
            if caps:  # an open end is a vessel the estimate must resolve, however small its area
                min_radius = min(min_radius, min(float(c.radius) for c in caps))
        if not np.isfinite(min_radius) or min_radius <= 0:
            raise ValueError("could not estimate the vessel radius (is the surface closed?)")
        spacing, limited = choose_spacing(min_radius, bounds, settings.voxels_per_radius, settings.max_voxels)
        stats["min_radius"] = float(min_radius)
    stats["spacing"] = spacing
    stats["spacing_limited"] = limited
    return spacing


def _voxel_branch_graph(sdf, bounds, spacing: float, tick, stats: dict, timings: dict, ridge_slope: float = 0.0) -> BranchGraph:
    """Stages 1-3: voxelise, thin and trace into a raw branch graph."""
    with _timed(timings, "voxelise"):
        grid = grid_for_bounds(bounds, spacing)
        stats["grid"] = list(grid.shape)
        mask, mask_evaluations = inside_mask(sdf, grid, progress=lambda f, m: tick(0.05 + 0.45 * f, m))
        stats["sdf_evaluations_mask"] = int(mask_evaluations)
        stats["inside_voxels"] = int(mask.sum())
    with _timed(timings, "thin"):
        tick(0.5, f"thinning {stats['inside_voxels']} inside voxels")
        ijk = voxel_skeleton(mask, sdf, grid, ridge_slope=ridge_slope)
        del mask
        stats["skeleton_voxels"] = int(len(ijk))
    if len(ijk) == 0:
        raise ValueError("no voxel lies inside the surface: the vessel is thinner than the voxel size")
    with _timed(timings, "trace"):
        tick(0.65, f"tracing {len(ijk)} skeleton voxels")
        voxel_points = grid.points(ijk)
        voxel_radii = evaluate_sdf(sdf, voxel_points)
        traced = trace_branches(voxel_adjacency(ijk))
        graph = build_branch_graph(traced, voxel_points, voxel_radii)
        stats["raw_nodes"] = graph.graph.number_of_nodes()
        stats["raw_branches"] = graph.graph.number_of_edges()
    return graph


def mark_closed_stubs(graph: BranchGraph, spurs: list, stub: np.ndarray) -> None:
    """Mark the tips of the spur candidates held as side stubs (``stub``) ``closed_stub``: a
    closed end no cap's wall reaches, which place_ends extends to its own wall rather than
    to a neighbour's cap. A tip judged again and no longer a held stub (a flat end now, or
    not explaining wall) loses the mark."""
    for (_, _, _, tip, _), is_stub in zip(spurs, stub.tolist()):
        if is_stub:
            graph.graph.nodes[tip]["closed_stub"] = True
        else:
            graph.graph.nodes[tip].pop("closed_stub", None)


def clean_branch_graph(
    graph: BranchGraph, settings: ExtractionSettings, expected_cycles: int | None, sdf=None, spacing=None, caps=(), wall=None,
    min_radius: float | None = None,
) -> dict:
    """Stage 4: clean a raw branch graph until nothing changes (at most 20 rounds).

    One round drops specks, cuts the cycles too thin everywhere to be a vessel
    (``PINCHED_LUMEN``), cuts the cycles beyond ``expected_cycles`` (or, when it
    is unknown, collapses short cycles), merges close junctions and prunes spurs;
    removing one defect can expose another (a spur left after a merge), hence the
    rounds. Returns how many of each were removed. With ``sdf`` (and the voxel
    ``spacing``), a short terminal branch that ends at a flat end face (on none of
    ``caps``) is a vessel's end, not a spur, and stays (:func:`~.ends.spurs_at_flat_ends`),
    and a side sac the cleaned path runs through is split off it as a branch
    (:func:`~.sacs.split_side_sacs`; counted as ``side_sacs``). With ``wall`` (the
    surface's triangle centroids and areas, :func:`~.spur_wall.surface_samples`, or their
    :class:`~.spur_wall.Wall`), a
    candidate that alone explains wall the coverage verdict would call missing stays too
    (:func:`~.spur_wall.spurs_explaining_wall`: a side stub). ``min_radius`` (the thinnest
    vessel estimated on the surface) bounds the pinched-cycle cut where the grid, coarsened
    by ``max_voxels``, resolves less than the surface holds.
    """
    keep = None
    if sdf is not None:
        seen = {}  # the test per branch (tip and junction positions), over the rounds

        def keep(spurs):
            key = [tuple(np.r_[graph.pos(tip), graph.pos(base)].round(12)) for _, _, _, tip, base in spurs]
            todo = [i for i, k in enumerate(key) if k not in seen]
            for i, flat in zip(todo, spurs_at_flat_ends(graph, sdf, spacing, [spurs[i] for i in todo], list(caps or ()))):
                seen[key[i]] = bool(flat)
            held = np.array([seen[k] for k in key], bool)
            if wall is not None:  # judged against the whole round's rest, the wall's tree built once
                side = spur_wall.spurs_explaining_wall(graph, wall, spurs, spacing)
                mark_closed_stubs(graph, spurs, side & ~held)
                held |= side
            return held

    removed = {"specks": 0, "spurs": 0, "merged_junctions": 0, "small_cycles": 0, "pinched_cycles": 0, "bridges": 0}
    pinched = None
    if spacing:
        resolved = settings.voxels_per_radius * spacing
        pinched = PINCHED_LUMEN * (min(resolved, min_radius) if min_radius else resolved)
    graph.dissolve_all()
    for _ in range(20):
        step = {
            "specks": graph.drop_small_components(2.0 * settings.spur_ratio),
            "pinched_cycles": graph.break_pinched_cycles(pinched) if pinched else 0,
            "bridges": graph.break_extra_cycles(expected_cycles) if expected_cycles is not None else 0,
            "merged_junctions": graph.merge_junctions(settings.merge_ratio),
            "small_cycles": graph.collapse_small_cycles(settings.cycle_ratio) if expected_cycles is None else 0,
            "spurs": graph.prune_spurs(settings.spur_ratio, keep),
        }
        graph.dissolve_all()
        for key, value in step.items():
            removed[key] += value
        if not any(step.values()):
            break
    if sdf is not None:
        removed["side_sacs"] = split_side_sacs(graph, sdf, spacing)
    return removed


def extract_skeleton(
    sdf: SdfFunction,
    bounds,
    *,
    min_radius: float | None = None,
    surface=None,
    caps=None,
    expected_cycles: int | None = None,
    settings: ExtractionSettings | None = None,
    progress: Callable | None = None,
) -> tuple[Skeleton, dict]:
    """Extract the centerline skeleton of a vessel from its signed distance.

    Parameters
    ----------
    sdf : callable
        ``sdf(points (n, 3)) -> (n,)`` signed distance, positive inside.
    bounds : (lo, hi)
        Bounding box of the vessel.
    min_radius : float, optional
        Radius of the thinnest vessel to resolve; estimated from ``surface`` when
        not given (ignored when ``settings.spacing`` is set).
    surface : (vertices, faces), optional
        The closed surface: for the radius estimate, and its genus is the number
        of cycles the skeleton keeps.
    caps : sequence, optional
        Open-end caps (objects with ``center``, ``normal``, ``radius``).
    expected_cycles : int, optional
        Number of independent cycles of the vessel (default: the genus of
        ``surface`` when it is closed). Extra cycles, made where the voxel mask
        bridges two close vessels, are cut at their narrowest branch; without it
        cycles shorter than ``cycle_ratio`` radii are collapsed instead.
    settings : ExtractionSettings, optional
    progress : callable, optional
        ``progress(fraction, message)``.

    Returns
    -------
    skeleton : Skeleton
    stats : dict
        Spacing, grid size, SDF evaluations, voxel counts, what cleaning removed
        and the time of each stage.
    """
    settings = settings or ExtractionSettings()
    tick = progress or (lambda fraction, message="": None)
    sdf = _CountingSdf(sdf)
    timings, stats = {}, {}
    bounds = tuple(np.asarray(b, float) for b in bounds)
    with _timed(timings, "radius_estimate"):
        spacing = _voxel_size(sdf, bounds, min_radius, surface, caps, settings, tick, stats)
    graph = _voxel_branch_graph(sdf, bounds, spacing, tick, stats, timings, settings.ridge_slope)

    with _timed(timings, "clean"):
        tick(0.75, "cleaning the skeleton graph")
        if expected_cycles is None and surface is not None:
            expected_cycles = surface_genus(*surface)
        stats["expected_cycles"] = expected_cycles
        wall = spur_wall.Wall(spur_wall.surface_samples(*surface, caps)) if surface is not None and settings.spur_wall else None
        stats.update(clean_branch_graph(graph, settings, expected_cycles, sdf, spacing, caps, wall, stats.get("min_radius")))
        stats["centred_junctions"] = graph.center_junctions(sdf, spacing)
    with _timed(timings, "ends"):
        tick(0.85, "placing the ends")
        # spur_wall=false: the extraction before the rule, the tail measured over the whole window
        stats["ends"] = place_ends(graph, sdf, spacing, caps=caps, end_depth=settings.end_depth, outside_junction=settings.spur_wall)
        if wall is not None:  # a held stub whose end runs in a neighbour's lumen: its wall is the neighbour's
            stats["stubs_in_neighbours"], left = spur_wall.drop_stubs_in_neighbours(graph, sdf, spacing)
            if left:  # a junction whose every sibling was dropped ends its vessel there
                stats["left_ends"] = extend_left_ends(graph, sdf, left, spacing, caps, settings.end_depth, settings.spur_wall)
    with _timed(timings, "resample"):
        tick(0.9, "resampling and centring the branches")
        skeleton = resample_branches(
            graph,
            sdf,
            spacing,
            node_spacing=settings.node_spacing,
            junction_clearance=settings.junction_clearance,
            smoothing=settings.smoothing,
        )
    order = {n: i for i, n in enumerate(graph.graph.nodes)}
    stats["cap_of_node"] = {
        order[n]: data["end"][1] for n, data in graph.graph.nodes(data=True) if data.get("end", ("",))[0] == "cap"
    }
    stats["sdf_evaluations"] = int(sdf.evaluations)
    stats["timings"] = {k: round(v, 4) for k, v in timings.items()}
    stats.update({k: v for k, v in skeleton.summary().items()})
    tick(1.0, f"skeleton: {skeleton.n_nodes} nodes")
    return skeleton, stats
