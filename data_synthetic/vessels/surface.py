"""Triangle surface of a vessel tree, its end styles and the defects of real segmentations.

The surface is the zero level set of the smooth union (blend 0.3 x the smaller radius) of
one field per branch (hard union of tapered capsules along its axis), spheres for aneurysm
sacs, and for flat or open ends a half-space at the end plane intersected with that branch
only. It is sampled on a grid (spacing = smallest radius / ``grid_per_radius``, coarsened
to stay under ``max_voxels``), contoured with skimage's marching cubes, Taubin-smoothed and
decimated (pymeshlab). Open ends are made by removing the flat cap faces; ragged ends by
also removing wall triangles a random depth behind the cut.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from ..generate import _Grid, _smin, _taubin, _tube_field, signed_volume
from .tree import Tree, unit

_BIG = np.float32(1e6)


def end_caps(tree: Tree) -> list[tuple[int, np.ndarray, np.ndarray, float]]:
    """(branch, end point, outward normal, radius) of every free vessel end (roots and tips)."""
    ends = []
    for k, b in enumerate(tree.branches):
        if not b.tube:
            continue
        if b.parent < 0:
            ends.append((k, b.pts[0], unit(b.pts[0] - b.pts[1]), float(b.rad[0])))
        if b.end_on is None and not tree.end_children(k):
            ends.append((k, b.pts[-1], unit(b.pts[-1] - b.pts[-2]), float(b.rad[-1])))
    return ends


def _prolong(b, caps, h):
    """A branch axis prolonged straight past its capped ends (cut later at the end plane)."""
    pts, rad = b.pts, b.rad
    for e, n, r in caps:
        ext = e + np.linspace(0.0, r + 4 * h, 6)[1:, None] * n
        if np.allclose(e, pts[0]):
            pts, rad = np.r_[ext[::-1], pts], np.r_[np.full(5, rad[0]), rad]
        else:
            pts, rad = np.r_[pts, ext], np.r_[rad, np.full(5, rad[-1])]
    return pts, rad


def implicit_field(tree: Tree, end_style: str, h: float):
    """The implicit function on a grid (negative inside) and the grid."""
    caps = {}
    if end_style in ("open", "flat"):
        for k, e, n, r in end_caps(tree):
            caps.setdefault(k, []).append((e, n, r))
    tubes = [(k, *_prolong(b, caps.get(k, []), h)) for k, b in enumerate(tree.branches) if b.tube]
    lo = np.min([np.min(p - r[:, None], axis=0) for _, p, r in tubes] + [c - R for c, R, _ in tree.sacs], axis=0)
    hi = np.max([np.max(p + r[:, None], axis=0) for _, p, r in tubes] + [c + R for c, R, _ in tree.sacs], axis=0)
    origin = lo - 4 * h + np.array([0.1234, 0.2345, 0.3456]) * h
    shape = tuple(int(v) for v in np.ceil((hi + 4 * h - origin) / h).astype(int) + 1)
    grid = _Grid(origin, h, shape)
    F = np.full(shape, _BIG, dtype=np.float32)
    for k, pts, rad in tubes:
        blend = 0.3 * float(tree.branches[k].rad.min())
        pad = blend + 2 * h
        rmax = float(rad.max()) + pad
        sl, (X, Y, Z) = grid.box(pts.min(axis=0) - rmax, pts.max(axis=0) + rmax)
        G = _tube_field(grid, pts, rad, pad, sl)
        for e, n, _ in caps.get(k, []):  # flat end: this branch only, cut at its end plane
            plane = (X - e[0]) * n[0] + (Y - e[1]) * n[1] + (Z - e[2]) * n[2]
            G = np.maximum(G, plane.astype(np.float32))
        F[sl] = _smin(F[sl], G, blend)
    for c, R, blend in tree.sacs:
        r = R + blend + 2 * h
        sl, (X, Y, Z) = grid.box(c - r, c + r)
        d = np.sqrt((X - c[0]) ** 2 + (Y - c[1]) ** 2 + (Z - c[2]) ** 2) - R
        F[sl] = _smin(F[sl], d.astype(np.float32), blend)
    return F, grid


def grid_spacing(tree: Tree, grid_per_radius: float, max_voxels: float) -> float:
    """Grid spacing: smallest tube radius / ``grid_per_radius``, coarser if the bounding box
    would hold more than ``max_voxels`` samples, but never beyond radius / 1.8 (a thinner
    grid would lose the thinnest vessels)."""
    P, R, _ = tree.points()
    h = float(R.min()) / grid_per_radius
    ext = np.ptp(P, axis=0) + 2 * R.max() + 8 * h
    return max(h, min(float(np.prod(ext) / max_voxels) ** (1 / 3), float(R.min()) / 1.8))


def contour(F, grid, staircase: bool, smooth_iters: int = 10):
    """Marching cubes (binary field for a staircase surface), outward orientation and
    ``smooth_iters`` Taubin steps (none for a staircase)."""
    from skimage.measure import marching_cubes

    vol = np.where(F < 0, np.float32(-1), np.float32(1)) if staircase else F
    V, T, _, _ = marching_cubes(vol, 0.0, spacing=(grid.h,) * 3, allow_degenerate=False)
    V = V + grid.origin
    T = T.astype(np.int64)
    if signed_volume(V, T) < 0:
        T = T[:, ::-1].copy()
    if not staircase and smooth_iters:
        V = _taubin(V, T, iters=smooth_iters)
    return V, T


def remove_faces(V, T, drop):
    """Surface without the faces ``drop`` (mask), unused vertices removed."""
    T = T[~drop]
    used = np.unique(T)
    remap = np.full(len(V), -1, np.int64)
    remap[used] = np.arange(len(used))
    return V[used], remap[T]


def cap_faces(V, T, caps, tol):
    """Faces on the flat end discs (centre, normal, radius): all corners on the plane."""
    on = np.zeros(len(T), bool)
    for e, n, r in caps:
        d = (V - e) @ n
        radial = np.linalg.norm((V - e) - d[:, None] * n, axis=1)
        pv = (np.abs(d) < tol * r) & (radial < 1.6 * r)
        on |= pv[T].all(axis=1)
    return on


def snap_to_caps(V, caps, tol):
    """Put vertices that drifted off a flat end plane (smoothing, decimation) back onto it."""
    V = V.copy()
    for e, n, r in caps:
        d = (V - e) @ n
        radial = np.linalg.norm((V - e) - d[:, None] * n, axis=1)
        m = (np.abs(d) < tol * r) & (radial < 1.6 * r)
        V[m] -= d[m, None] * n
    return V


def ragged_cut(V, T, caps, rng, depth=0.6):
    """Remove wall faces behind each open end to a random depth (0..``depth`` radii) that
    varies around the rim: open, ragged ends like those of a hand-cut segmentation."""
    drop = np.zeros(len(T), bool)
    C = V[T].mean(axis=1)
    for e, n, r in caps:
        d = (C - e) @ n
        rel = (C - e) - d[:, None] * n
        radial = np.linalg.norm(rel, axis=1)
        e1 = unit(np.cross(n, [1.0, 0, 0] if abs(n[0]) < 0.9 else [0, 1.0, 0]))
        th = np.arctan2(rel @ np.cross(n, e1), rel @ e1)
        k = np.arange(1, 4)
        a, ph = rng.uniform(0, 1, 3) / k, rng.uniform(0, 2 * np.pi, 3)
        wave = (np.sin(np.outer(th, k) + ph) * a).sum(axis=1)
        cut = depth * r * (wave - wave.min()) / max(np.ptp(wave), 1e-9)
        drop |= (radial < 1.6 * r) & (d > -cut) & (d < 0.5 * r)
    return remove_faces(V, T, drop)


def punch_holes(V, T, count, axis_pts, axis_rad, avoid, rng):
    """Remove ``count`` small wall patches (radius 0.2-0.4 local radii) away from the
    points ``avoid`` (ends, junctions); returns the surface and the hole centres."""
    kd = cKDTree(axis_pts)
    dist, j = kd.query(V)
    r_loc = axis_rad[j]
    far = np.ones(len(V), bool)
    if len(avoid):
        da, _ = cKDTree(np.asarray(avoid)).query(V)
        far = da > 3 * r_loc
    cand = np.flatnonzero(far)
    centres = []
    drop = np.zeros(len(T), bool)
    C = V[T].mean(axis=1)
    for v in rng.choice(cand, size=min(count, len(cand)), replace=False) if len(cand) else []:
        rho = rng.uniform(0.2, 0.4) * r_loc[v]
        drop |= np.linalg.norm(C - V[v], axis=1) < rho
        centres.append(V[v])
    V, T = remove_faces(V, T, drop)
    return V, T, centres


def flip_patch(V, T, rng, axis_pts, axis_rad):
    """Reverse the faces of one wall patch (1-3 local radii across): inconsistent orientation."""
    C = V[T].mean(axis=1)
    c = C[rng.integers(len(C))]
    _, j = cKDTree(axis_pts).query(c)
    m = np.linalg.norm(C - c, axis=1) < rng.uniform(1, 3) * axis_rad[j]
    T = T.copy()
    T[m] = T[m][:, ::-1]
    return T


def noise_field(shape, h, scale, amplitude, rng):
    """Smooth random field (correlation length ``scale``, standard deviation ``amplitude``)."""
    from scipy.ndimage import gaussian_filter

    g = gaussian_filter(rng.standard_normal(shape).astype(np.float32), sigma=max(scale / h, 1.0))
    return (amplitude / max(float(g.std()), 1e-12)) * g


def smooth(V, T, iters: int = 10):
    """Taubin smoothing (no shrinking): removes the marching-cubes facets."""
    return _taubin(V, T, iters=iters)


def decimate(V, T, target):
    """Quadric decimation to ``target`` faces (topology and open boundaries kept)."""
    import pymeshlab

    if len(T) <= target:
        return V, T
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=V, face_matrix=T.astype(np.int32)))
    ms.meshing_decimation_quadric_edge_collapse(targetfacenum=int(target), qualitythr=0.5, preservenormal=True,
                                                preserveboundary=True, boundaryweight=2.0, preservetopology=True,
                                                optimalplacement=True, planarquadric=True, autoclean=True)
    ms.meshing_remove_unreferenced_vertices()
    m = ms.current_mesh()
    return np.asarray(m.vertex_matrix(), dtype=float), np.asarray(m.face_matrix(), dtype=np.int64)
