"""Tracing a vessel from its cap to the skeleton along the vessel's axis.

A vessel thinner than the voxels (or than its neighbours, whose spurs are pruned) can be
missing from a thinned skeleton; when it bends, no straight line from the skeleton to its
cap stays inside it. Marching from the cap, one re-centred cross-section after another,
follows it however it bends until it meets the skeleton.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree


def march_to_skeleton(
    sdf,
    start: np.ndarray,
    direction: np.ndarray,
    radius: float,
    targets: np.ndarray,
    target_radii: np.ndarray,
    step: float = 0.5,
    max_length: float = 60.0,
) -> tuple[np.ndarray, int] | None:
    """Axis of a vessel from ``start`` (on its cap) until it reaches the skeleton.

    Each step moves ``step`` x the local radius along the current direction, centres the
    point in the cross-section there and takes the direction from the previous point; the
    march ends at the first point within a skeleton point's radius of it (inside that
    vessel's lumen).

    Parameters
    ----------
    sdf : callable
        Signed distance, positive inside.
    start, direction : (3,) arrays
        The cap centre and the inward unit normal of the cap.
    radius : float
        Cap radius (the first cross-section's expected radius).
    targets, target_radii : arrays
        Skeleton points and their radii.
    step : float
        Step length, × local radius.
    max_length : float
        Longest march, × ``radius``.

    Returns
    -------
    (path, target) or None
        The points marched from the cap (first: the start) and the index of the target
        point reached; ``None`` when the march leaves the vessel or goes too far.
    """
    from .probe import center_in_cross_sections, evaluate_sdf

    tree = cKDTree(np.asarray(targets, float))
    r_max = float(np.max(target_radii))
    p = np.asarray(start, float)
    t = np.asarray(direction, float) / np.linalg.norm(direction)
    r = float(radius)
    path, travelled = [p], 0.0
    while travelled < max_length * radius:
        h = step * r
        q, section = center_in_cross_sections(sdf, (p + h * t)[None], t[None], np.array([r]))
        q = q[0]
        depth = float(evaluate_sdf(sdf, q[None])[0])
        if depth <= 0:
            return None
        for k in tree.query_ball_point(q, r_max):
            if np.linalg.norm(targets[k] - q) < target_radii[k]:
                return np.array(path + [q]), int(k)
        move = q - p
        travelled += float(np.linalg.norm(move))
        if np.linalg.norm(move) > 1e-12:
            t = move / np.linalg.norm(move)
        # the section's radius where it is measured, the inscribed sphere's otherwise
        r = float(section[0]) if np.isfinite(section[0]) else depth
        r = min(max(r, 0.25 * radius), 4.0 * radius)
        path.append(q)
        p = q
    return None


def attach_by_march(graph, cap, index: int, spacing: float, sdf, where: list, pts: np.ndarray) -> bool:
    """Add to the extraction's branch graph the branch to ``cap`` marched along its vessel
    from the cap to the skeleton (``where``/``pts``: the graph's branch points and nodes);
    ``False`` when the march fails."""
    from .ends import _straight
    from .probe import evaluate_sdf

    radii = evaluate_sdf(sdf, pts)  # the inscribed spheres: the lumen around each skeleton point
    found = march_to_skeleton(sdf, cap.center, -np.asarray(cap.normal, float), float(cap.radius), pts, radii)
    if found is None:
        return False
    path, k = found
    location = where[k]
    base = location[1] if location[0] == "node" else graph.split(*location[1:])
    end = graph.add_node(np.asarray(cap.center, float), float(cap.radius), end=("cap", index))
    pieces = [_straight(graph.pos(base), path[-1], spacing), path[::-1][:-1]]
    line = np.concatenate([q for q in pieces if len(q)])
    graph.add_branch(base, end, line, np.full(len(line), float(cap.radius)))
    return True
