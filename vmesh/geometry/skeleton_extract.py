"""Old import path of the skeleton extraction, kept for the modules and branches that
import it: the code lives in :mod:`vmesh.geometry.skeleton`, one module a stage of
:mod:`~vmesh.geometry.skeleton.extract`."""

from scipy.sparse.csgraph import connected_components, dijkstra

from .skeleton.probe import (
    _arclength,
    center_in_cross_sections,
    distance_to_wall,
    evaluate_sdf,
    maximise_sdf,
    _OFFSETS26,
    plane_basis,
    sdf_gradient,
    SdfFunction,
)
from .skeleton.voxelize import (
    choose_spacing,
    estimate_min_radius,
    fill_cavities,
    grid_for_bounds,
    inside_mask,
    VoxelGrid,
)
from .skeleton.thin import (
    _ADJ26,
    _ADJ6,
    _FACES,
    _flood,
    _lowest_bit,
    _N18,
    _neighbourhood_tables,
    simple_points,
    thin_to_curves,
    voxel_skeleton,
)
from .skeleton.trace import (
    build_branch_graph,
    _group,
    _HALF_NEIGHBOURHOOD,
    trace_branches,
    TracedSkeleton,
    voxel_adjacency,
)
from .skeleton.branch_graph import (
    BranchGraph,
)
from .skeleton.end_faces import (
    end_face_normals,
    flat_end_sections,
)
from .skeleton.ends import (
    _attach_cap,
    _end_tangent,
    _extend,
    _extend_to_wall,
    _match_caps,
    _on_cap_face,
    place_ends,
    _straight,
    _trim_end,
)
from .skeleton.resample import (
    _center_loop_cuts,
    junction_clearances,
    resample_branches,
    smooth_polyline,
    _station_positions,
)
from .skeleton.extract import (
    extract_skeleton,
    ExtractionSettings,
    surface_genus,
)

__all__ = [
    "connected_components",
    "dijkstra",
    "_arclength",
    "center_in_cross_sections",
    "distance_to_wall",
    "evaluate_sdf",
    "maximise_sdf",
    "_OFFSETS26",
    "plane_basis",
    "sdf_gradient",
    "SdfFunction",
    "choose_spacing",
    "estimate_min_radius",
    "fill_cavities",
    "grid_for_bounds",
    "inside_mask",
    "VoxelGrid",
    "_ADJ26",
    "_ADJ6",
    "_FACES",
    "_flood",
    "_lowest_bit",
    "_N18",
    "_neighbourhood_tables",
    "simple_points",
    "thin_to_curves",
    "voxel_skeleton",
    "build_branch_graph",
    "_group",
    "_HALF_NEIGHBOURHOOD",
    "trace_branches",
    "TracedSkeleton",
    "voxel_adjacency",
    "BranchGraph",
    "end_face_normals",
    "flat_end_sections",
    "_attach_cap",
    "_end_tangent",
    "_extend",
    "_extend_to_wall",
    "_match_caps",
    "_on_cap_face",
    "place_ends",
    "_straight",
    "_trim_end",
    "_center_loop_cuts",
    "junction_clearances",
    "resample_branches",
    "smooth_polyline",
    "_station_positions",
    "extract_skeleton",
    "ExtractionSettings",
    "surface_genus",
]
