"""Old import path of the skeleton kernels (graph structure, merging of overlapping
centerlines, cleaning, resampling and tagging), kept for the modules, tests and branches
that import it: the code lives in :mod:`vmesh.geometry.skeleton` (issue 20), one module a
concern: :mod:`~vmesh.geometry.skeleton.graph` (graph structure),
:mod:`~vmesh.geometry.skeleton.polylines` (building graphs from polylines),
:mod:`~vmesh.geometry.skeleton.distance` (signed distance helpers),
:mod:`~vmesh.geometry.skeleton.clean` (cleaning),
:mod:`~vmesh.geometry.skeleton.graft` (ends to caps, grafting),
:mod:`~vmesh.geometry.skeleton.sample` (resampling) and
:mod:`~vmesh.geometry.skeleton.tags` (branch tree, tags).

Every function is pure: it takes a :class:`~vmesh.skeleton.Skeleton` (or arrays) and
returns new arrays or a new skeleton, never modifying its input. Geometry work is
vectorised over nodes; only graph walks (one step per node, once) are Python loops.
"""

from .skeleton.graph import (
    END_TAGS,
    edge_lengths,
    arc_length,
    simplify_edges,
    _union,
    _adjacency_with_edge_ids,
    branch_paths,
    path_edge_ids,
    component_labels,
    _rebuild,
    contract_nodes,
    remove_nodes,
    _graph_distance,
    _true_runs,
)
from .skeleton.polylines import (
    merge_coincident_points,
    polylines_overlap,
    MergedCenterlines,
    merge_overlapping_polylines,
)
from .skeleton.distance import (
    distance_gradient,
    ascend_distance,
    estimate_radii,
    fill_missing_along_branches,
    pull_inside,
)
from .skeleton.graph import polyline_at as _polyline_at  # old private name, kept for old imports
from .skeleton.clean import (
    node_scale,
    merge_close_junctions,
    _pair_angle,
    separate_parallel_branches,
    _node_at_foot,
    reconnect_components,
    remove_spurs,
    trim_at_caps,
)
from .skeleton.graft import (
    match_ends_to_caps,
    extend_to_caps,
    graft_branches,
)
from .skeleton.sample import (
    _smooth_along,
    radius_features,
    resample_skeleton,
)
from .skeleton.tags import (
    BranchTree,
    choose_root,
    branch_tree,
    tag_nodes,
    nodes_in_sphere,
    sac_nodes,
    derive_edge_tags,
)

__all__ = [
    "END_TAGS",
    "edge_lengths",
    "arc_length",
    "simplify_edges",
    "_union",
    "_adjacency_with_edge_ids",
    "branch_paths",
    "path_edge_ids",
    "component_labels",
    "_rebuild",
    "contract_nodes",
    "remove_nodes",
    "_graph_distance",
    "_true_runs",
    "merge_coincident_points",
    "polylines_overlap",
    "MergedCenterlines",
    "merge_overlapping_polylines",
    "distance_gradient",
    "ascend_distance",
    "estimate_radii",
    "fill_missing_along_branches",
    "pull_inside",
    "node_scale",
    "merge_close_junctions",
    "_polyline_at",
    "_pair_angle",
    "separate_parallel_branches",
    "_node_at_foot",
    "reconnect_components",
    "remove_spurs",
    "trim_at_caps",
    "match_ends_to_caps",
    "extend_to_caps",
    "graft_branches",
    "_smooth_along",
    "radius_features",
    "resample_skeleton",
    "BranchTree",
    "choose_root",
    "branch_tree",
    "tag_nodes",
    "nodes_in_sphere",
    "sac_nodes",
    "derive_edge_tags",
]
