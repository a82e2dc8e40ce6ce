"""Smoothing, resampling and centring the branches (stage 6).

Nodes are spaced by a multiple of the local radius and kept clear of junctions
(where the medial axis of a crotch is not the vessel axis), then moved within
their cross-section plane to the centre of the section
(:func:`~.probe.center_in_cross_sections`); a node's radius is its distance to the
wall.
"""

from __future__ import annotations

import numpy as np

from ...skeleton import Skeleton
from .branch_graph import BranchGraph
from .probe import SdfFunction, _arclength, center_in_cross_sections, evaluate_sdf


def smooth_polyline(points: np.ndarray, iterations: int) -> np.ndarray:
    """Laplacian smoothing (weights 1/4, 1/2, 1/4) with fixed end points.

    ``iterations`` passes smooth like a Gaussian of standard deviation
    ``sqrt(iterations / 2)`` point spacings.
    """
    p = np.array(points, float)
    for _ in range(int(iterations)):
        if len(p) < 3:
            break
        p[1:-1] = 0.5 * p[1:-1] + 0.25 * (p[:-2] + p[2:])
    return p



def _station_positions(s: np.ndarray, step: np.ndarray, a: float, b: float, keep_a: bool, keep_b: bool) -> np.ndarray:
    """Arclengths of nodes on ``[a, b]`` spaced by the local ``step(s)``.

    Nodes are equally spaced in ``u = integral ds / step``; ``keep_a`` / ``keep_b``
    say whether a node sits exactly at ``a`` / ``b`` (junction clearance) or
    whether the interval ends at an existing node (an end of the skeleton).
    """
    if b < a:
        return np.zeros(0)
    u = np.concatenate([[0.0], np.cumsum(np.diff(s) * 0.5 * (1 / step[1:] + 1 / step[:-1]))])
    ua, ub = np.interp([a, b], s, u)
    if keep_a and keep_b and ub - ua < 0.5:
        return np.array([0.5 * (a + b)])
    n = max(1, int(round(ub - ua)))
    j = np.arange(0 if keep_a else 1, n + 1 if keep_b else n)
    return np.interp(ua + (ub - ua) * j / n, u, s)



def junction_clearances(graph: BranchGraph, factor: float, cap: float = 4.0) -> dict:
    """How far from each junction the first node of each of its branches must be.

    At least ``factor`` junction radii; further where a branch leaves another at
    a small angle ``theta``: its cross-section overlaps the other vessel until
    about ``(r_branch + r_other) / sin(theta)`` from the junction (a thin side
    branch leaving a wide trunk, two daughters of a narrow bifurcation). At most
    ``cap`` junction radii. Keys are ``(junction, u, v, key)``; a loop at a
    junction has ``"first"`` / ``"last"`` appended for its two ends.
    """
    out = {}
    for node in graph.graph.nodes:
        if graph.degree(node) < 3:
            continue
        r_j = graph.radius(node)
        arms = []  # (key, direction, radius)
        for u, v, k in graph.graph.edges(node, keys=True):
            ends = ["first", "last"] if u == v else [None]
            for end in ends:
                pts, rad = graph.polyline(u, v, k, start=node)
                if end == "last":
                    pts, rad = pts[::-1], rad[::-1]
                s = _arclength(pts)
                near = (s >= r_j) & (s <= 3.0 * r_j)
                if near.sum() >= 2:
                    direction = pts[near][-1] - pts[near][0]
                    radius = float(np.median(rad[near]))
                else:
                    direction = pts[min(len(pts) - 1, np.searchsorted(s, 3.0 * r_j))] - pts[0]
                    radius = float(np.median(rad))
                direction = direction / max(np.linalg.norm(direction), 1e-300)
                key = (node, u, v, k) if end is None else (node, u, v, k, end)
                arms.append((key, direction, radius))
        for key, d, r in arms:
            need = factor * r_j
            for other, d_o, r_o in arms:
                if other == key:
                    continue
                cos = float(np.clip(d @ d_o, -1.0, 1.0))
                if cos > 0:  # diverging at less than 90 degrees
                    need = max(need, min((r + r_o) / max(np.sqrt(1 - cos * cos), 1e-6), cap * r_j))
            out[key] = need
    return out



def _center_loop_cuts(graph: BranchGraph, sdf: SdfFunction, spacing: float) -> None:
    """Centre the node where a cycle without junctions was cut (a voxel position)."""
    g = graph.graph
    # a cut cycle is one node whose single branch is a loop (a node between two
    # branches, e.g. where a cap branch was attached to an end, is no cut)
    cuts = [n for n in g.nodes if g.degree(n) == 2 and g.number_of_edges(n, n) == 1]
    if not cuts:
        return
    tangents, radii = [], []
    for n in cuts:
        u, v, k = next(iter(g.edges(n, keys=True)))
        pts, rad = graph.polyline(u, v, k)
        window = max(3, len(pts) // 20)
        t = pts[min(window, len(pts) - 1)] - pts[-1 - min(window, len(pts) - 1)]
        tangents.append(t / max(np.linalg.norm(t), 1e-300))
        radii.append(max(float(np.median(rad)), spacing))
    centres, _ = center_in_cross_sections(sdf, np.array([graph.pos(n) for n in cuts]), np.array(tangents), np.array(radii))
    depth = evaluate_sdf(sdf, centres)
    for n, c, d in zip(cuts, centres, depth):
        if d > graph.radius(n):
            graph.graph.nodes[n]["pos"] = c
            graph.graph.nodes[n]["r"] = float(d)



def resample_branches(
    graph: BranchGraph,
    sdf: SdfFunction,
    spacing: float,
    node_spacing: float = 1.0,
    junction_clearance: float = 1.5,
    smoothing: float = 0.5,
) -> Skeleton:
    """Turn a cleaned :class:`BranchGraph` into a :class:`~vmesh.skeleton.Skeleton`.

    Every branch polyline is smoothed over ``smoothing`` x the local radius,
    resampled with nodes ``node_spacing`` x the local radius apart, starting
    ``junction_clearance`` x the junction radius away from a junction (inside a
    crotch the medial axis runs between the daughter vessels, not along them),
    and each new node is centred in its cross-section
    (:func:`center_in_cross_sections`); its radius is its distance to the wall.
    """
    g = graph.graph
    _center_loop_cuts(graph, sdf, spacing)
    node_ids = {n: i for i, n in enumerate(g.nodes)}
    points = [graph.pos(n) for n in g.nodes]
    radii = [graph.radius(n) for n in g.nodes]
    tags = []
    for n in g.nodes:
        end = g.nodes[n].get("end")
        kind = {"cap": "cap_end", "flat": "flat_end", "rounded": "rounded_end"}.get(end[0]) if end else None
        tags.append(("vessel", kind) if kind else ("vessel",))
    clearance = junction_clearances(graph, junction_clearance)
    stations, tangents, guesses, owners = [], [], [], []
    for u, v, k in graph.branches():
        start = g.edges[u, v, k]["start"]
        end = graph.other(u, v, start)
        pts, rad = graph.polyline(u, v, k, start=start)
        r_typical = float(np.median(rad))
        iterations = int(np.clip(2.0 * (smoothing * r_typical / spacing) ** 2, 1, 400))
        smooth = smooth_polyline(pts, iterations)
        smooth_r = smooth_polyline(rad[:, None], iterations)[:, 0]
        s = _arclength(smooth)
        if s[-1] <= 0:
            owners.append((start, end, None))
            continue
        step = np.maximum(node_spacing * np.maximum(smooth_r, spacing), 2 * spacing)
        clear_a = clearance.get((start, u, v, k), 0.0)
        clear_b = clearance.get((end, u, v, k), 0.0)
        if start == end:  # a loop leaves and enters its junction: both clearances apply
            clear_a, clear_b = clearance.get((start, u, v, k, "first"), clear_a), clearance.get((start, u, v, k, "last"), clear_b)
        at = _station_positions(s, step, clear_a, s[-1] - clear_b, clear_a > 0, clear_b > 0)
        at = at[(at > 1e-9 * s[-1]) & (at < s[-1] * (1 - 1e-9))]
        if start == end and len(at) < 2:  # a loop needs two interior nodes
            at = s[-1] * np.array([1 / 3, 2 / 3])
        elif len(at) == 0 and any(
            o[:2] in ((start, end), (end, start)) for o in owners if o[2] is None
        ):  # a second direct edge between the same nodes needs a node
            at = np.array([0.5 * s[-1]])
        derivative = np.gradient(smooth, s, axis=0) if len(s) > 2 else np.repeat(smooth[[-1]] - smooth[[0]], len(s), 0)
        p = np.stack([np.interp(at, s, smooth[:, c]) for c in range(3)], axis=1)
        t = np.stack([np.interp(at, s, derivative[:, c]) for c in range(3)], axis=1)
        t /= np.maximum(np.linalg.norm(t, axis=1, keepdims=True), 1e-300)
        stations.append(p)
        tangents.append(t)
        guesses.append(np.interp(at, s, smooth_r))
        owners.append((start, end, len(at) if len(at) else None))
    if stations:
        p = np.concatenate(stations)
        t = np.concatenate(tangents)
        r_guess = np.concatenate(guesses)
        centred, section = center_in_cross_sections(sdf, p, t, np.maximum(r_guess, spacing))
        r_centred = evaluate_sdf(sdf, centred)
        r_initial = evaluate_sdf(sdf, p)
        # keep the centred point unless centring left the vessel
        use = r_centred >= 0.5 * np.maximum(r_initial, 0)
        final = np.where(use[:, None], centred, p)
        final_r = np.where(use, r_centred, r_initial)
        final_r = np.where(final_r > 0, final_r, r_guess)
        # next to an end face the inscribed sphere touches the face, not the wall:
        # there the radius of the cross-section is the vessel's
        ends = np.array([graph.pos(n) for n in g.nodes if g.degree(n) == 1]).reshape(-1, 3)
        if len(ends):
            from scipy.spatial import cKDTree

            to_end = cKDTree(ends).query(final)[0]
            near_end = np.isfinite(section) & (to_end < 1.2 * np.nan_to_num(section)) & (final_r < section)
            final_r = np.where(near_end, section, final_r)
    else:
        final, final_r = np.zeros((0, 3)), np.zeros(0)
    edges = []
    offset = len(points)
    cursor = 0
    for start, end, count in owners:
        count = count or 0
        chain = [node_ids[start]] + list(range(offset + cursor, offset + cursor + count)) + [node_ids[end]]
        edges.extend(zip(chain[:-1], chain[1:]))
        cursor += count
    all_points = np.concatenate([np.array(points).reshape(-1, 3), final])
    all_radii = np.concatenate([np.array(radii, float), final_r])
    all_tags = tags + [("vessel",)] * len(final)
    return Skeleton(all_points, all_radii, np.array(edges, np.int64).reshape(-1, 2), all_tags)

