"""Signed distance helpers for skeletons: distance gradients, ascending to the axis,
radii from the distance, filling missing values along branches, pulling nodes inside
(moved from :mod:`vmesh.geometry.skeleton_ops`, issue 20)."""

from __future__ import annotations

import numpy as np

from ...skeleton import Skeleton
from .graph import arc_length, branch_paths, component_labels, remove_nodes
from .probe import distance_to_wall, evaluate_sdf


def distance_gradient(distance, points: np.ndarray, step: np.ndarray | float) -> np.ndarray:
    """Unit gradient of a distance function by central differences (one batched call).

    Parameters
    ----------
    distance : callable (k, 3) -> (k,)
    points : (m, 3)
    step : float or (m,) array
        Difference step per point.
    """
    points = np.asarray(points, float)
    m = len(points)
    h = np.broadcast_to(np.asarray(step, float), (m,))
    offsets = np.eye(3)[None, :, :] * h[:, None, None]  # (m, 3, 3)
    probes = np.concatenate([points[:, None, :] + offsets, points[:, None, :] - offsets], axis=1)
    d = np.asarray(distance(probes.reshape(-1, 3)), float).reshape(m, 6)
    g = (d[:, :3] - d[:, 3:]) / (2.0 * h[:, None])
    norm = np.linalg.norm(g, axis=1, keepdims=True)
    return np.divide(g, norm, out=np.zeros_like(g), where=norm > 0)


def ascend_distance(
    points: np.ndarray,
    target: np.ndarray,
    distance,
    gradient=None,
    iterations: int = 40,
) -> tuple[np.ndarray, np.ndarray]:
    """Move points up a signed distance (positive inside) until it reaches ``target`` or
    stops increasing (the medial ridge).

    Steps follow the gradient, start at half the missing depth and halve whenever a
    step would not increase the distance.

    Parameters
    ----------
    points : (m, 3)
    target : (m,) array
        Wanted distance (e.g. a fraction of the node radius).
    distance : callable (k, 3) -> (k,)
    gradient : callable (k, 3) -> (k, 3), optional
        Gradient of ``distance``; central differences otherwise.

    Returns
    -------
    points : (m, 3)
    distance : (m,) distance at the returned points
    """
    p = np.array(points, float).reshape(-1, 3)
    target = np.broadcast_to(np.asarray(target, float), (len(p),)).copy()
    d = np.asarray(distance(p), float)
    scale = np.maximum(np.abs(target - d), 1e-9)
    step = 0.5 * scale + np.maximum(-d, 0.0)  # at least reach the wall from outside
    active = d < target
    for _ in range(iterations):
        idx = np.flatnonzero(active)
        if len(idx) == 0:
            break
        if gradient is not None:
            g = np.asarray(gradient(p[idx]), float)
            g /= np.maximum(np.linalg.norm(g, axis=1, keepdims=True), 1e-300)
        else:
            g = distance_gradient(distance, p[idx], 1e-2 * scale[idx])
        trial = p[idx] + step[idx, None] * g
        dt = np.asarray(distance(trial), float)
        better = dt > d[idx]
        p[idx[better]] = trial[better]
        d[idx[better]] = dt[better]
        step[idx[~better]] *= 0.5
        active[idx] = (d[idx] < target[idx]) & (step[idx] > 1e-4 * scale[idx])
    return p, d


def estimate_radii(skeleton: Skeleton, distance=None, overwrite: bool = False) -> tuple[Skeleton, int]:
    """Fill missing radii: from the signed distance at each node where one is given, then
    by arc-length interpolation along each branch for whatever is still missing.

    Parameters
    ----------
    skeleton : Skeleton
    distance : callable (k, 3) -> (k,), optional
        Signed distance to the wall, positive inside (the inscribed sphere radius at a
        centerline point). Nodes where it is not positive are left for interpolation.
    overwrite : bool
        Recompute every radius from ``distance``, not only the missing ones.

    Returns
    -------
    skeleton : Skeleton
    n_filled : int
        Number of nodes whose radius changed.
    """
    radii = skeleton.radii.copy()
    todo = np.ones(len(radii), bool) if overwrite else ~(np.isfinite(radii) & (radii > 0))
    if distance is not None and todo.any():
        d = np.asarray(distance(skeleton.points[todo]), float)
        radii[todo] = np.where(d > 0, d, np.nan)
    radii = fill_missing_along_branches(skeleton.n_nodes, skeleton.edges, skeleton.points, radii)
    changed = ~np.isclose(radii, skeleton.radii, equal_nan=True)
    return skeleton.copy(radii=radii), int(changed.sum())


def fill_missing_along_branches(n_nodes: int, edges: np.ndarray, points: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Interpolate NaN node values linearly in arc length along branches; nodes of a
    branch without any value get the median of their connected component (or of all)."""
    values = np.asarray(values, float).copy()
    missing = ~np.isfinite(values)
    if not missing.any() or not (~missing).any():
        return values
    for _ in range(2):  # a second pass reaches branches whose only known values were key nodes filled in pass one
        for path in branch_paths(n_nodes, edges):
            v = values[path]
            bad = ~np.isfinite(v)
            if not bad.any() or bad.all():
                continue
            s = arc_length(points[path])
            v[bad] = np.interp(s[bad], s[~bad], v[~bad])
            values[path] = v
    still = ~np.isfinite(values)
    if still.any():
        label = component_labels(n_nodes, edges)
        for c in np.unique(label[still]):
            known = (label == c) & np.isfinite(values)
            values[(label == c) & still] = np.median(values[known]) if known.any() else np.nanmedian(values)
    return values


def pull_inside(
    skeleton: Skeleton, distance, gradient=None, tolerance: float = 0.02, mode: str = "pull", keep=None
) -> tuple[Skeleton, int, int]:
    """Bring back nodes that lie outside the domain (signed distance below
    ``-tolerance`` x radius).

    ``mode="pull"`` walks them up the signed distance towards the medial ridge (towards
    their own radius as depth) and drops those still outside; an end node outside goes
    back along its branch instead (:func:`_ends_back_along_branch`), where it can, unless
    ``keep`` (a node mask: ends that belong to caps) holds it. ``"drop"`` removes them straight
    away. Junctions are never dropped (they are pulled). Removed stretches of a branch are
    bridged so the graph stays connected.

    Returns
    -------
    skeleton : Skeleton
    n_pulled, n_dropped : int
    """
    r = skeleton.radii
    scale = np.where(np.isfinite(r) & (r > 0), r, np.nanmedian(r) if np.isfinite(r).any() else 1.0)
    d = np.asarray(distance(skeleton.points), float)
    outside = d < -tolerance * scale
    deg = skeleton.degrees
    held = np.zeros(len(d), bool) if keep is None else np.asarray(keep, bool)
    if not outside.any():
        return skeleton.copy(), 0, 0
    points = skeleton.points.copy()
    n_pulled = 0
    cut = np.zeros(len(points), bool)
    if mode == "pull":
        # only ends outside: an end inside, even on its end face, stays (moved back, it left
        # the slab behind it out of the mesh where the face is a filled open end; docs/coverage.md)
        n_pulled, cut = _ends_back_along_branch(skeleton, distance, d, scale, outside & (deg == 1) & ~held, points)
        outside &= ~cut
        ends = np.flatnonzero(outside & (deg == 1))
        outside[ends] = np.asarray(distance(points[ends]), float) < -tolerance * scale[ends]
    pull = outside & ((mode == "pull") | (deg >= 3))
    if pull.any():
        idx = np.flatnonzero(pull)
        new, dn = ascend_distance(points[idx], scale[idx], distance, gradient)
        ok = dn >= 0
        points[idx[ok]] = new[ok]
        n_pulled += int(ok.sum())
        outside[idx[ok]] = False
        # a junction that cannot be brought inside still stays (its branches hang on it)
        outside[idx[~ok & (deg[idx] >= 3)]] = False
    moved = skeleton.copy(points=points)
    n_dropped = int(outside.sum()) + int(cut.sum())  # the branch nodes an end went back past too
    drop = outside | cut
    return (remove_nodes(moved, drop) if drop.any() else moved), n_pulled, n_dropped


def _ends_back_along_branch(skeleton: Skeleton, distance, d, scale, ends, points) -> tuple[int, np.ndarray]:
    """Move end nodes that lie outside back along their branch to the last full
    cross-section behind where the branch leaves the surface, as the extraction places an
    end behind a flat end face (:func:`~.end_faces.flat_end_sections`: a quarter radius
    behind a clean face, up to a radius behind a rough, terraced or rounded one), centred.

    An end just past a closed end walked up the signed distance to its radius' depth
    stops a radius short of an end face no cap was found on (a terraced one), and the
    mesh with it. ``points`` is updated in place; the branch nodes the new end passes are
    returned in the mask (to be removed, bridged). Ends whose branch has no node inside,
    or whose new place would pass the branch's other end, are left to the walk up the
    signed distance. The branch's axis stands in for the face normal (a tilted face is set
    back along the axis), and the end keeps its radius (the builder measures its section).
    """
    from .end_faces import flat_end_sections

    cut = np.zeros(len(points), bool)
    idx = np.flatnonzero(ends)
    if len(idx) == 0:
        return 0, cut
    paths = {}  # end node -> its branch, from the end
    for q in branch_paths(skeleton.n_nodes, skeleton.edges):
        if q[0] != q[-1]:
            paths[int(q[0])], paths[int(q[-1])] = q, q[::-1]
    picked, faces, normals = [], [], []
    starts, steps = [], []  # per end: the branch's first node inside and the way out to its node outside
    for e in idx.tolist():
        path = paths.get(e)
        inside = np.flatnonzero(d[path] > 0) if path is not None else []
        if len(inside) == 0:
            continue
        k = int(inside[0])  # >= 1: the end itself is outside
        picked.append((e, path, k))
        starts.append(points[path[k]])
        steps.append(points[path[k - 1]] - points[path[k]])
    if not picked:
        return 0, cut
    # where each branch leaves the surface: one ray from its first node inside to its last
    # outside, sampled at 16 steps with a linear interpolation at the crossing
    starts, steps = np.array(starts), np.array(steps)
    span = np.linalg.norm(steps, axis=1)
    ways = steps / np.maximum(span, 1e-300)[:, None]
    leave = distance_to_wall(distance, starts, ways, span, samples=16, bisections=0)
    kept = []
    for (e, path, k), start, way, t in zip(picked, starts, ways, leave):
        if not np.isfinite(t):
            continue
        face = start + t * way
        far = np.linalg.norm(points[path[k:]] - face, axis=1) >= scale[e]  # the axis over about a radius
        axis = face - points[path[k + int(np.argmax(far)) if far.any() else -1]]
        norm = np.linalg.norm(axis)
        if norm > 0:
            kept.append((e, path))
            faces.append(face)
            normals.append(axis / norm)
    picked = kept
    if not picked:
        return 0, cut
    faces, normals = np.array(faces), np.array(normals)
    r = scale[[p[0] for p in picked]]
    centres, section, _ = flat_end_sections(distance, faces, normals, normals, r)
    depth = evaluate_sdf(distance, centres)  # the signed distance at each new end
    n = 0
    for i, (e, path) in enumerate(picked):
        end = centres[i]
        beyond = (points[path] - end) @ normals[i] > -1e-9 * r[i]
        if beyond[-1] or not np.isfinite(section[i]) or depth[i] <= 0:
            continue  # the branch is shorter than the way back, or no section there
        first = int(np.argmin(beyond[1:])) + 1  # the first node behind the new end stays
        cut[path[1:first]] = True
        points[e] = end
        n += 1
    return n, cut
