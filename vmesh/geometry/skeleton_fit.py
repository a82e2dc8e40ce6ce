"""How a skeleton fits its surface: nodes inside the wall, units, radii.

A centerline read from a file may not belong to the surface it comes with: it may be in
other units (cm against mm), be the centerline of another vessel, or carry radii in other
units; and a few of its nodes may graze or cross the wall (the chord of a sharp bend, a
centerline computed on a finer surface). :func:`centerline_fit` tells these apart from
the signed distance; :func:`ensure_inside` brings grazing nodes onto the vessel's side of
the wall, since every later stage needs its nodes strictly inside.

Pure functions of numpy arrays and a signed distance ``distance(points) -> (k,)``,
positive inside.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..skeleton import Skeleton
from .skeleton.clean import node_scale
from .skeleton.distance import ascend_distance

#: Scale factors between the usual length units (m, cm, mm, um): what a centerline in
#: other units than its surface is off by.
UNIT_FACTORS = (10.0, 100.0, 1000.0, 0.1, 0.01, 0.001)


@dataclass
class CenterlineFit:
    """How a centerline sits in a surface (:func:`centerline_fit`).

    Attributes
    ----------
    far_outside : float
        Share of the nodes farther outside the wall than their own radius.
    inside : float
        Share of the nodes inside the wall.
    scale : float or None
        A unit factor (:data:`UNIT_FACTORS`) that puts most nodes inside when the
        coordinates are multiplied by it, when most of them are outside as given.
    radius_ratio : float or None
        Median ratio of the given radii to the signed distance at the nodes inside
        (about 1 for radii of this surface).
    extent, surface_extent : float
        Largest bounding-box side of the centerline and of the surface.
    """

    far_outside: float
    inside: float
    scale: float | None = None
    radius_ratio: float | None = None
    extent: float = 0.0
    surface_extent: float = 0.0
    details: dict = field(default_factory=dict)


def _inside_share(distance, points: np.ndarray) -> float:
    return float(np.mean(np.asarray(distance(points), float) > 0)) if len(points) else 0.0


def centerline_fit(skeleton: Skeleton, distance, surface_bounds) -> CenterlineFit:
    """Measure how ``skeleton`` fits the surface of ``distance``.

    Most nodes more than their own radius outside the wall cannot be cleaned into place,
    nor a centerline 10 times smaller or larger than its surface: either the coordinates
    are in other units (then multiplying them by one of :data:`UNIT_FACTORS` makes the
    centerline span about the surface, with most nodes inside; units scale about the
    origin) or the centerline belongs to another vessel. The radii are compared with the
    signed distance at the nodes inside.
    """
    pts = skeleton.points
    d = np.asarray(distance(pts), float)
    scale = node_scale(skeleton)
    lo, hi = (np.asarray(b, float) for b in surface_bounds)
    fit = CenterlineFit(
        far_outside=float(np.mean(d < -scale)) if len(d) else 0.0,
        inside=float(np.mean(d > 0)) if len(d) else 0.0,
        extent=float(np.ptp(pts, axis=0).max()) if len(pts) else 0.0,
        surface_extent=float((hi - lo).max()),
    )
    ratio = fit.surface_extent / max(fit.extent, 1e-300)
    if fit.far_outside > 0.5 or not (0.25 <= ratio <= 4.0):
        # a factor fits when the scaled centerline spans about the surface and lies in it
        shares = {f: _inside_share(distance, pts * f) for f in UNIT_FACTORS if 0.5 <= ratio / f <= 4.0}
        fit.details["inside_when_scaled"] = shares
        good = {f: share for f, share in shares.items() if share > 0.5}
        if good:
            fit.scale = max(good, key=good.get)
    r = skeleton.radii
    known = (d > 0) & np.isfinite(r) & (r > 0)
    if known.sum() >= 3:
        fit.radius_ratio = float(np.median(r[known] / d[known]))
    return fit


def ensure_inside(
    skeleton: Skeleton, distance, gradient=None, depth: float = 0.1, include_ends: bool = False
) -> tuple[Skeleton, int, np.ndarray]:
    """Move nodes that graze or cross the wall up the signed distance.

    A node whose signed distance is below ``depth`` x its radius (endpoints only with
    ``include_ends``: they may sit on a cap, which is on the wall) walks up the signed
    distance towards its radius as depth, stopping on the medial ridge
    (:func:`~vmesh.geometry.skeleton.distance.ascend_distance`): onto the vessel's axis.

    Returns
    -------
    skeleton : Skeleton
        With the moved nodes; a moved node without a radius gets its new depth.
    n_moved : int
    stuck : (k,) int64
        Nodes that are still not inside (signed distance <= 0) after the walk.
    """
    if skeleton.n_nodes == 0:
        return skeleton.copy(), 0, np.zeros(0, np.int64)
    scale = node_scale(skeleton)
    d = np.asarray(distance(skeleton.points), float)
    check = np.ones(skeleton.n_nodes, bool) if include_ends else skeleton.degrees != 1
    low = check & (d < depth * scale)
    if not low.any():
        return skeleton.copy(), 0, np.zeros(0, np.int64)
    idx = np.flatnonzero(low)
    new, dn = ascend_distance(skeleton.points[idx], scale[idx], distance, gradient)
    better = dn > d[idx]
    points, radii = skeleton.points.copy(), skeleton.radii.copy()
    points[idx[better]] = new[better]
    moved = idx[better]
    depth_now = np.where(better, dn, d[idx])
    fix_r = better & (dn > 0) & ~(np.isfinite(radii[idx]) & (radii[idx] > 0))
    radii[idx[fix_r]] = dn[fix_r]
    stuck = idx[depth_now <= 0]
    return skeleton.copy(points=points, radii=radii), int(len(moved)), stuck.astype(np.int64)


def node_tangents(skeleton: Skeleton) -> np.ndarray:
    """Unit axis direction at every node: the principal direction of its segments (sign
    free, so segment orientation does not matter); zero for isolated nodes."""
    n = skeleton.n_nodes
    a, b = skeleton.edges.T
    u = skeleton.points[b] - skeleton.points[a]
    u /= np.maximum(np.linalg.norm(u, axis=1, keepdims=True), 1e-300)
    outer = u[:, :, None] * u[:, None, :]
    tensor = np.zeros((n, 3, 3))
    np.add.at(tensor, a, outer)
    np.add.at(tensor, b, outer)
    return np.linalg.eigh(tensor)[1][:, :, 2]


def section_radii(skeleton: Skeleton, distance, nodes: np.ndarray | None = None, caps=(), rays: int = 12) -> np.ndarray:
    """Radius of the vessel's cross-section at every node: the shortest of ``rays`` rays in
    the plane orthogonal to the axis to the wall (the inscribed circle).

    Next to an open end the signed distance measures the way to the cap, not to the wall
    (a node 0.01 before the cap of a 12 mm aorta has a signed distance of 0.01); rays in
    the section plane run parallel to the cap and meet the wall. Rays look as far as twice
    the widest signed distance on the node's branch. Only ``nodes`` (a boolean mask) are
    measured when given. A ray that ends on the face of one of ``caps`` (objects with
    ``center``, ``normal``, ``radius``: a section plane tilted against a cap meets it
    right next to the cap) does not count. NaN where no ray meets the wall, the node is
    outside or not asked.
    """
    from .skeleton.probe import distance_to_wall, plane_basis
    from .skeleton.graph import branch_paths

    n = skeleton.n_nodes
    d = np.asarray(distance(skeleton.points), float)
    reach = np.zeros(n)
    for path in branch_paths(n, skeleton.edges):
        np.maximum.at(reach, path, 2.0 * max(float(d[path].max()), 0.0))
    out = np.full(n, np.nan)
    ok = np.flatnonzero((d > 0) & (reach > 0) & (np.ones(n, bool) if nodes is None else np.asarray(nodes, bool)))
    if len(ok) == 0:
        return out
    e1, e2 = plane_basis(node_tangents(skeleton)[ok])
    ang = 2 * np.pi * np.arange(rays) / rays
    dirs = (np.cos(ang)[None, :, None] * e1[:, None, :] + np.sin(ang)[None, :, None] * e2[:, None, :]).reshape(-1, 3)
    origins = np.repeat(skeleton.points[ok], rays, axis=0)
    hit = distance_to_wall(distance, origins, dirs, np.repeat(reach[ok], rays), samples=8)
    ends = origins + np.where(np.isfinite(hit), hit, 0.0)[:, None] * dirs
    for cap in caps:
        rel = ends - np.asarray(cap.center, float)
        depth = rel @ np.asarray(cap.normal, float)
        lateral = np.linalg.norm(rel - depth[:, None] * np.asarray(cap.normal, float), axis=1)
        on_face = (np.abs(depth) < 0.05 * cap.radius) & (lateral < 1.05 * cap.radius)
        hit[on_face] = np.inf
    hit = hit.reshape(len(ok), rays).min(axis=1)
    out[ok] = np.where(np.isfinite(hit) & (hit > 0), hit, np.nan)
    return out
