"""Deterministic synthetic blood-vessel surfaces with ground-truth skeletons.

Every case is a closed, manifold, outward-oriented triangle surface (binary PLY)
together with the skeleton it was built from (JSON).  Both come from the same
finely sampled smooth centre curves, so the skeleton is the true centerline of
the surface and can be used to score skeletonisation and meshing.

Cases (units mm)
----------------
``straight_tube``       straight vessel, r = 3, length 40.
``curved_tube``         150 degree bend, r = 2.5.
``y_bifurcation``       trunk r 3 into daughters r 2.4 / 2.0 at +-35 degrees.
``trifurcation``        trunk r 3 into three daughters (one node of degree 4).
``five_furcation``      nearly planar 5-furcation (one node of degree 5).
``two_junctions``       two bifurcation nodes 4 mm apart on a trunk of r 3.
``uneven_bifurcation``  trunk r 4, continuation r 3.8, side branch r 1.2.
``aneurysm``            bent vessel r 2 with a saccular aneurysm (R 3.5) on the
                        outer side of the bend; sac/neck nodes are tagged.
``coarctation``         aortic arch (r 12 -> 10) with three supra-aortic
                        branches and a 50 % diameter narrowing (tagged).
``cerebral_tree``       seeded, collision-free Murray-like tree (r 2 -> 0.5)
                        with 500-600 skeleton nodes, ~100k triangles.
``ring``                closed ring of vessels (circle-of-Willis-like) with 3
                        inlets and 3 outlets; surface of genus 1.

Files
-----
``data_synthetic/<case>/surface.ply``
    Binary little-endian PLY, float32 vertices and triangle faces, outward
    normals, flat open caps at every vessel end (planar discs perpendicular to
    the end segment, centred on the end node).
``data_synthetic/<case>/skeleton.json``
    ``{"name", "units": "mm", "nodes": [{"id", "xyz", "radius", "tags"}],
    "edges": [[i, j], ...]}``.  Ids run 0..n-1.  Node spacing is about
    1-1.5 x the local radius, junction nodes sit exactly at the branch points
    and end nodes exactly at the centres of the flat caps.  Tags: ``"vessel"``
    on every vessel node, ``"inlet"`` / ``"outlet"`` on capped end nodes,
    ``"neck"`` / ``"aneurysm"`` on the aneurysm branch and ``"coarctation"``
    on the nodes of the narrowing.

Every node lies inside the surface; end nodes lie on their cap (moving them
by 5 % of the radius into the vessel puts them inside).

Usage
-----
Regenerate the committed files (existing ones are kept unless ``--force``)::

    python data_synthetic/generate.py [--case NAME ...] [--force]
    python -m data_synthetic.generate [--case NAME ...] [--force]

All cases take about 35 s on two cores (``cerebral_tree`` about 18 s).  Each
run checks the result (closed, manifold, oriented, genus, nodes inside, flat
caps) and fails loudly otherwise.

From Python::

    from data_synthetic.generate import CASES, make_case, case_paths
    vertices, faces, skeleton = make_case("y_bifurcation", radius_scale=1.2)
    surface_ply, skeleton_json = case_paths("aneurysm")

``case_paths`` returns the committed files; a case missing from the checkout
is generated once into ``data_synthetic/cache/`` (git-ignored).
``make_case`` is deterministic: the same name, ``radius_scale`` and ``seed``
give the same arrays (and files) on the same platform.  ``radius_scale``
multiplies every radius while keeping the centre lines (and hence the
skeleton node positions) fixed -- except the aneurysm sac, which grows with
the vessel and moves outwards; ``seed`` only affects ``cerebral_tree``.  Large
scales can make neighbouring tree branches touch (checked up to 1.2).

Method
------
The surface is the zero level set of an implicit function: the smooth union
(polynomial smooth-min, blend width 0.3 x the smaller radius) of tapered
capsule chains along the finely sampled centre curves (hard union within one
vessel, so a vessel never bulges) and spheres for aneurysm sacs.  It is
sampled on a grid of spacing smallest radius / 6 (/ 4 for the tree), each
segment only in its bounding box, contoured with marching cubes and
Taubin-smoothed.  Capped tubes are built a little longer and then cut exactly
at the cap planes; the holes are closed by flat discs triangulated in
concentric rings (sharp rims).  Finally the mesh is decimated with topology
preserved (pymeshlab quadric edge collapse).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

DATA_DIR = Path(__file__).resolve().parent
CACHE_DIR = DATA_DIR / "cache"

CASES = [
    "straight_tube",
    "curved_tube",
    "y_bifurcation",
    "trifurcation",
    "five_furcation",
    "two_junctions",
    "uneven_bifurcation",
    "aneurysm",
    "coarctation",
    "cerebral_tree",
    "ring",
]

#: Cases whose files are not committed (generated into ``cache/`` on demand).
UNCOMMITTED: set[str] = set()

# Skeleton sampling: node spacing = SPACING x local radius, reduced on bends so
# that the chord deviates from the true axis by at most SAGITTA x radius.
SPACING = 1.25
SAGITTA = 0.05
# Smooth-union blend width relative to the smaller radius of a junction.
BLEND = 0.3
# "Far away" value of the implicit function (float32-safe, never reaches 0).
_BIG = np.float32(1e6)


# ----------------------------------------------------------------------------
# Curves
# ----------------------------------------------------------------------------

def _unit(v: np.ndarray) -> np.ndarray:
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _line(a: np.ndarray, b: np.ndarray, step: float) -> np.ndarray:
    """Points from ``a`` to ``b`` (both included) at most ``step`` apart."""
    n = max(1, int(np.ceil(np.linalg.norm(b - a) / step)))
    t = np.linspace(0.0, 1.0, n + 1)[:, None]
    return a + t * (b - a)


def fillet_polyline(ctrl, fillet, step: float) -> np.ndarray:
    """Sample a control polyline whose corners are rounded by circular arcs.

    Parameters
    ----------
    ctrl : array_like, shape (k, 3)
        Control points; the curve starts at ``ctrl[0]``, ends at ``ctrl[-1]``
        and is tangent to every leg.  End legs stay straight, so end tangents
        are exactly the first / last leg directions.
    fillet : float or sequence of float
        Arc radius at each inner corner (``k - 2`` values or one for all).
    step : float
        Maximal distance between consecutive output points.

    Returns
    -------
    numpy.ndarray, shape (n, 3)
        Points on the G1-continuous curve (exact: they lie on the lines/arcs).
    """
    ctrl = np.asarray(ctrl, dtype=float)
    radii = np.broadcast_to(np.asarray(fillet, dtype=float), (max(len(ctrl) - 2, 0),))
    out = [ctrl[:1]]
    cur = ctrl[0]
    for i in range(1, len(ctrl) - 1):
        a = _unit(ctrl[i] - ctrl[i - 1])
        b = _unit(ctrl[i + 1] - ctrl[i])
        cos = float(np.clip(a @ b, -1.0, 1.0))
        theta = np.arccos(cos)
        if theta < 1e-9:
            continue
        R = float(radii[i - 1])
        t = R * np.tan(theta / 2)
        if t > np.linalg.norm(ctrl[i] - cur) + 1e-9 or t > np.linalg.norm(ctrl[i + 1] - ctrl[i]) + 1e-9:
            raise ValueError(f"fillet radius {R} too large at corner {i}")
        p_in = ctrl[i] - a * t
        m = _unit(b - cos * a)                      # towards the arc centre
        centre = p_in + R * m
        out.append(_line(cur, p_in, step)[1:])
        n = max(2, int(np.ceil(R * theta / step)))
        phi = np.linspace(0.0, theta, n + 1)[1:, None]
        out.append(centre + R * (-np.cos(phi) * m + np.sin(phi) * a))
        cur = out[-1][-1]
    out.append(_line(cur, ctrl[-1], step)[1:])
    return np.concatenate(out)


def _arclength(pts: np.ndarray) -> np.ndarray:
    return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))])


# ----------------------------------------------------------------------------
# Case description
# ----------------------------------------------------------------------------

@dataclass
class VPath:
    """One smooth vessel centre curve (or a skeleton-only branch).

    ``pts`` is the fine polyline taken as the true axis; for a closed path the
    first point is repeated at the end.  ``rad`` is the radius at each point.
    ``start_on`` / ``end_on`` = (path index, arclength) make the first / last
    point the same skeleton node as that point of an earlier path (junctions).
    """

    pts: np.ndarray
    rad: np.ndarray
    closed: bool = False
    tube: bool = True
    cap_start: bool = False
    cap_end: bool = False
    tags: tuple = ("vessel",)
    start_on: tuple | None = None
    end_on: tuple | None = None
    keys: dict = field(default_factory=dict)          # extra keypoints: s -> tags
    node_s: np.ndarray | None = None                  # explicit node positions
    node_tags: list | None = None
    tag_fn: Callable | None = None                    # s -> extra tags
    blend: float | None = None                        # smooth-union width

    def __post_init__(self):
        self.pts = np.asarray(self.pts, dtype=float)
        self.rad = np.broadcast_to(np.asarray(self.rad, dtype=float), (len(self.pts),)).copy()
        self.s = _arclength(self.pts)

    @property
    def length(self) -> float:
        return float(self.s[-1])

    def point_at(self, s: float) -> np.ndarray:
        s = s % self.length if self.closed else s
        return np.array([np.interp(s, self.s, self.pts[:, k]) for k in range(3)])

    def radius_at(self, s: float) -> float:
        s = s % self.length if self.closed else s
        return float(np.interp(s, self.s, self.rad))


def make_path(ctrl, fillet, radius, step=None, **kw) -> VPath:
    """Path along a filleted control polyline.

    ``radius`` is a number, a callable of (arclength, total length) or a list of
    ``(fraction of length, radius)`` knots interpolated linearly.
    """
    if step is None:
        rmin = radius if np.isscalar(radius) else 1.0
        step = 0.3 * rmin
    pts = fillet_polyline(ctrl, fillet, step)
    s = _arclength(pts)
    if callable(radius):
        rad = radius(s, s[-1])
    elif np.isscalar(radius):
        rad = np.full(len(pts), float(radius))
    else:
        knots = np.asarray(radius, dtype=float)
        rad = np.interp(s / s[-1], knots[:, 0], knots[:, 1])
    return VPath(pts, rad, **kw)


@dataclass
class Sphere:
    centre: np.ndarray
    radius: float
    blend: float


@dataclass
class CaseSpec:
    name: str
    paths: list
    spheres: list = field(default_factory=list)
    target_faces: int = 10000
    euler: int = 2
    radius_scale: float = 1.0
    grid_per_radius: float = 6.0        # grid spacing = smallest radius / this


# ----------------------------------------------------------------------------
# Skeleton
# ----------------------------------------------------------------------------

def _piece_node_s(p: VPath, sa: float, sb: float, radius_scale: float = 1.0) -> np.ndarray:
    """Interior node positions (arclength) between keypoints ``sa`` < ``sb``."""
    L = p.length
    if p.closed:                                    # unroll one extra lap
        s_all = np.concatenate([p.s, p.s[1:] + L])
        pts = np.concatenate([p.pts, p.pts[1:]])
        rad = np.concatenate([p.rad, p.rad[1:]]) / radius_scale
    else:
        s_all, pts, rad = p.s, p.pts, p.rad / radius_scale
    # Discrete curvature at fine points: turning angle / local segment length.
    d = np.diff(pts, axis=0)
    seg = np.linalg.norm(d, axis=1)
    t = d / seg[:, None]
    ang = np.arccos(np.clip(np.einsum("ij,ij->i", t[:-1], t[1:]), -1, 1))
    kappa = np.zeros(len(pts))
    kappa[1:-1] = ang / (0.5 * (seg[:-1] + seg[1:]))
    kappa = np.maximum.reduce([kappa, np.roll(kappa, 1), np.roll(kappa, -1)])
    # Node spacing: SPACING x r, shortened on bends so the sagitta stays small.
    with np.errstate(divide="ignore"):
        h_bend = np.sqrt(8 * SAGITTA * rad / np.maximum(kappa, 1e-12))
    h = np.minimum(SPACING * rad, h_bend)
    inside = (s_all > sa) & (s_all < sb)
    s_loc = np.concatenate([[sa], s_all[inside], [sb]])
    h_loc = np.interp(s_loc, s_all, h)
    u = np.concatenate([[0.0], np.cumsum(np.diff(s_loc) * 0.5 * (1 / h_loc[1:] + 1 / h_loc[:-1]))])
    # Round towards more nodes so that bends never get too long a chord.
    n = max(1, int(np.ceil(u[-1] - 0.25)))
    return np.interp(np.arange(1, n) * u[-1] / n, u, s_loc)


def build_skeleton(name: str, paths: list, radius_scale: float = 1.0) -> tuple[dict, list]:
    """Coarse ground-truth skeleton of a case.

    Returns
    -------
    skeleton : dict
        The JSON structure (coordinates rounded to 1e-6 mm).
    chains : list of (path index, list of (node id, arclength))
        Node sequence along every path, used by the checks.

    Node spacing follows the radii divided by ``radius_scale``, so that scaled
    variants of a case share the same node positions.
    """
    keys = [dict() for _ in paths]
    alias = {}
    for i, p in enumerate(paths):
        if p.node_s is not None:
            for s, tg in zip(p.node_s, p.node_tags):
                keys[i].setdefault(float(s), []).extend(tg)
        elif not p.closed:
            keys[i].setdefault(0.0, [])
            keys[i].setdefault(p.length, [])
        for s, tg in p.keys.items():
            keys[i].setdefault(float(s), []).extend(tg)
    for i, p in enumerate(paths):
        for own_s, on in ((0.0, p.start_on), (p.length, p.end_on)):
            if on is not None:
                j, sj = on
                keys[j].setdefault(float(sj), [])
                alias[(i, own_s)] = (j, float(sj))

    nodes, index = [], {}

    def node(i: int, s: float) -> int:
        key = (i, s)
        while key in alias:
            key = alias[key]
        if key not in index:
            j, sj = key
            p = paths[j]
            tags = list(p.tags) + keys[j].get(sj, [])
            if p.tag_fn is not None:
                tags += p.tag_fn(sj)
            if not p.closed and ((sj == 0.0 and p.cap_start) or (sj == p.length and p.cap_end)):
                # Capped end: the first path's start and marked ends are inlets.
                tags.append("inlet" if "inlet" in tags or (j == 0 and sj == 0.0) else "outlet")
            seen = []
            for t in tags:                          # dedupe, keep order
                if t not in seen:
                    seen.append(t)
            index[key] = len(nodes)
            nodes.append({"id": len(nodes),
                          "xyz": [round(float(c), 6) for c in p.point_at(sj)],
                          "radius": round(p.radius_at(sj), 6),
                          "tags": seen})
        return index[key]

    edges, chains = [], []
    for i, p in enumerate(paths):
        ks = sorted(keys[i])
        ks_ext = ks + [ks[0] + p.length] if p.closed else ks
        chain = [(node(i, ks[0]), ks[0])]
        for a, b in zip(ks_ext[:-1], ks_ext[1:]):
            inner = [] if p.node_s is not None else _piece_node_s(p, a, b, radius_scale)
            for s in inner:
                s = float(s)
                chain.append((node(i, s - p.length if p.closed and s >= p.length else s), s))
            chain.append((node(i, ks[0] if p.closed and b == ks_ext[-1] else b), b))
        for (u, _), (v, _) in zip(chain[:-1], chain[1:]):
            edges.append([u, v])
        chains.append((i, chain))
    skel = {"name": name, "units": "mm", "nodes": nodes, "edges": edges}
    return skel, chains


# ----------------------------------------------------------------------------
# Implicit surface
# ----------------------------------------------------------------------------

def _smin(a: np.ndarray, b: np.ndarray, k: float) -> np.ndarray:
    """Polynomial smooth minimum (blend width ``k``)."""
    hh = np.maximum(k - np.abs(a - b), 0.0) / k
    return np.minimum(a, b) - (0.25 * k) * hh * hh


@dataclass
class _Grid:
    origin: np.ndarray
    h: float
    shape: tuple

    def box(self, lo: np.ndarray, hi: np.ndarray, within=None):
        """Index slices and coordinate axes of the samples inside [lo, hi].

        ``within`` (slices) further restricts the box.
        """
        i0 = np.maximum(np.floor((lo - self.origin) / self.h).astype(int), 0)
        i1 = np.minimum(np.ceil((hi - self.origin) / self.h).astype(int) + 1, self.shape)
        if within is not None:
            i0 = np.maximum(i0, [s.start for s in within])
            i1 = np.minimum(i1, [s.stop for s in within])
        if np.any(i1 <= i0):
            return None
        sl = tuple(slice(int(a), int(b)) for a, b in zip(i0, i1))
        ax = [self.origin[k] + self.h * np.arange(i0[k], i1[k]) for k in range(3)]
        return sl, (ax[0][:, None, None], ax[1][None, :, None], ax[2][None, None, :])


def _extension(p: VPath, h: float) -> tuple[np.ndarray, np.ndarray]:
    """Axis points and radii of a tube, prolonged straight past its capped ends.

    The surface is built for the prolonged tube and later cut exactly at the
    cap planes (:func:`_clip_and_cap`), which gives flat caps with sharp rims.
    """
    pts, rad = p.pts, p.rad
    if p.cap_start:
        n = _unit(pts[0] - pts[1])
        t = np.linspace(0.0, rad[0] + 4 * h, 9)[:0:-1, None]
        pts, rad = np.concatenate([pts[0] + t * n, pts]), np.concatenate([np.full(8, rad[0]), rad])
    if p.cap_end:
        n = _unit(pts[-1] - pts[-2])
        t = np.linspace(0.0, rad[-1] + 4 * h, 9)[1:, None]
        pts, rad = np.concatenate([pts, pts[-1] + t * n]), np.concatenate([rad, np.full(8, rad[-1])])
    return pts, rad


def _tube_field(grid: _Grid, pts, rad, pad: float, sl0):
    """Hard union of tapered capsules along a polyline (no bulges at joints).

    Evaluated on the sub-grid ``sl0``; each segment only in its own bounding box.
    """
    G = np.full(tuple(s.stop - s.start for s in sl0), _BIG, dtype=np.float32)
    off = np.array([s.start for s in sl0])
    for a, b, ra, rb in zip(pts[:-1], pts[1:], rad[:-1], rad[1:]):
        r = max(ra, rb) + pad
        got = grid.box(np.minimum(a, b) - r, np.maximum(a, b) + r, sl0)
        if got is None:
            continue
        sl, (X, Y, Z) = got
        loc = tuple(slice(s.start - o, s.stop - o) for s, o in zip(sl, off))
        ba = b - a
        px, py, pz = X - a[0], Y - a[1], Z - a[2]
        t = np.clip((px * ba[0] + py * ba[1] + pz * ba[2]) / (ba @ ba), 0.0, 1.0)
        d = np.sqrt((px - t * ba[0]) ** 2 + (py - t * ba[1]) ** 2 + (pz - t * ba[2]) ** 2)
        d -= ra + t * (rb - ra)
        np.minimum(G[loc], d.astype(np.float32), out=G[loc])
    return G


def implicit_grid(spec: CaseSpec, h: float):
    """Sample the implicit function of a case; returns (field, grid)."""
    tubes = [_extension(p, h) + (p,) for p in spec.paths if p.tube]
    lo = np.min([np.min(pts - rad[:, None], axis=0) for pts, rad, _ in tubes]
                + [s.centre - s.radius for s in spec.spheres], axis=0)
    hi = np.max([np.max(pts + rad[:, None], axis=0) for pts, rad, _ in tubes]
                + [s.centre + s.radius for s in spec.spheres], axis=0)
    # Fixed irrational-ish offset: keeps samples off symmetry planes.
    origin = lo - 4 * h + np.array([0.1234, 0.2345, 0.3456]) * h
    shape = tuple(int(v) for v in np.ceil((hi + 4 * h - origin) / h).astype(int) + 1)
    grid = _Grid(origin, h, shape)
    F = np.full(shape, _BIG, dtype=np.float32)
    for pts, rad, p in tubes:
        k = p.blend if p.blend is not None else BLEND * float(p.rad.min())
        pad = k + 2 * h
        rmax = float(rad.max()) + pad
        sl, _ = grid.box(pts.min(axis=0) - rmax, pts.max(axis=0) + rmax)
        F[sl] = _smin(F[sl], _tube_field(grid, pts, rad, pad, sl), k)
    for sp in spec.spheres:
        r = sp.radius + sp.blend + 2 * h
        sl, (X, Y, Z) = grid.box(sp.centre - r, sp.centre + r)
        c = sp.centre
        d = np.sqrt((X - c[0]) ** 2 + (Y - c[1]) ** 2 + (Z - c[2]) ** 2) - sp.radius
        F[sl] = _smin(F[sl], d.astype(np.float32), sp.blend)
    return F, grid


# ----------------------------------------------------------------------------
# Mesh processing and checks
# ----------------------------------------------------------------------------

def _edges(F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unique undirected edges and how many faces use each."""
    e = np.sort(F[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    uniq, counts = np.unique(e, axis=0, return_counts=True)
    return uniq, counts


def _components(nv: int, F: np.ndarray) -> np.ndarray:
    """Connected-component label of every face."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    e = F[:, [0, 1, 1, 2]].reshape(-1, 2)
    A = coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(nv, nv))
    _, lab = connected_components(A, directed=False)
    return lab[F[:, 0]]


def _vertex_fans(nv: int, F: np.ndarray) -> int:
    """Number of face fans around vertices of a closed, oriented mesh.

    Equals the number of used vertices exactly when every vertex is manifold
    (its faces form one disc).
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    src, dst = F.ravel(), F[:, [1, 2, 0]].ravel()
    key = src * nv + dst
    order = np.argsort(key)
    twin = order[np.searchsorted(key[order], dst * nv + src)]
    h = np.arange(len(src))
    nxt = 3 * (h // 3) + (h % 3 + 1) % 3            # corner of dst in the same face
    tnxt = 3 * (twin // 3) + (twin % 3 + 1) % 3     # corner of src in the twin face
    i = np.r_[h, nxt]
    j = np.r_[tnxt, twin]
    A = coo_matrix((np.ones(len(i)), (i, j)), shape=(len(h), len(h)))
    return int(connected_components(A, directed=False)[0])


def signed_volume(V: np.ndarray, F: np.ndarray) -> float:
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def _taubin(V, F, iters=10, lam=0.5, mu=-0.53):
    """Taubin smoothing (uniform Laplacian): removes marching-cubes facets, no shrink."""
    from scipy.sparse import coo_matrix
    e = F[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    n = len(V)
    A = coo_matrix((np.ones(2 * len(e)), (np.r_[e[:, 0], e[:, 1]], np.r_[e[:, 1], e[:, 0]])),
                   shape=(n, n)).tocsr()
    A.data[:] = 1.0                                 # duplicates summed -> binary
    deg = np.asarray(A.sum(axis=1)).ravel()
    for _ in range(iters):
        for f in (lam, mu):
            V = V + f * (A @ V / deg[:, None] - V)
    return V


def _caps(spec: CaseSpec):
    """(centre, outward normal, radius) of every flat cap."""
    out = []
    for p in spec.paths:
        if p.tube and p.cap_start:
            out.append((p.pts[0], _unit(p.pts[0] - p.pts[1]), p.rad[0]))
        if p.tube and p.cap_end:
            out.append((p.pts[-1], _unit(p.pts[-1] - p.pts[-2]), p.rad[-1]))
    return out


def _cap_frame(n):
    e1 = _unit(np.cross(n, [1.0, 0, 0] if abs(n[0]) < 0.9 else [0, 1.0, 0]))
    return e1, np.cross(n, e1)


def _zip_rings(A, a_ang, B, b_ang):
    """Triangles between two counter-clockwise rings (outer ``A``, inner ``B``)."""
    mA, mB = len(A), len(B)
    # Start B at the point angularly closest to A[0].
    j0 = int(np.argmin(np.abs(np.angle(np.exp(1j * (b_ang - a_ang[0]))))))
    B = np.roll(B, -j0)
    b_ang = np.roll(b_ang, -j0)
    b_ang = a_ang[0] + np.angle(np.exp(1j * (b_ang[0] - a_ang[0]))) + np.unwrap(b_ang - b_ang[0])
    a_ext = np.r_[a_ang, a_ang[0] + 2 * np.pi]
    b_ext = np.r_[b_ang, b_ang[0] + 2 * np.pi]
    tris, i, j = [], 0, 0
    while i < mA or j < mB:
        if j >= mB or (i < mA and a_ext[i + 1] <= b_ext[j + 1]):
            tris.append((A[i % mA], A[(i + 1) % mA], B[j % mB]))
            i += 1
        else:
            tris.append((A[i % mA], B[(j + 1) % mB], B[j % mB]))
            j += 1
    return tris


def _clip_and_cap(V, F, e, n, r, h):
    """Cut the prolonged tube end at the cap plane and close it with a flat disc.

    Only the part of the surface near this end (inside a cylinder of radius
    about ``r`` around the end axis) is cut.  The disc is triangulated with
    concentric rings down to a vertex at the cap centre ``e``; its rim is the
    exact cut of the tube wall, so the cap is planar up to its edge.
    """
    rel = V - e
    d = rel @ n
    radial = np.linalg.norm(rel - d[:, None] * n, axis=1)
    local = (radial < r + 3 * h) & (d > -3 * h) & (d < 3 * r + 8 * h)
    # Vertices very close to the plane go onto it: no slivers from the cut.
    snap = local & (np.abs(d) < 0.2 * h)
    V = V.copy()
    V[snap] -= d[snap, None] * n
    d = np.where(snap, 0.0, d)
    side = np.where(local, np.sign(d), -1).astype(int)
    fs = side[F]
    if np.any((fs.min(axis=1) == 0) & (fs.max(axis=1) == 0)):
        raise RuntimeError("face lying in a cap plane")
    keep = fs.max(axis=1) <= 0
    split = (fs.max(axis=1) > 0) & (fs.min(axis=1) < 0)
    new_pts, cut_id, new_faces = [], {}, []

    def cut(i, j):
        key = (min(i, j), max(i, j))
        if key not in cut_id:
            t = d[i] / (d[i] - d[j])
            p = V[i] + t * (V[j] - V[i])
            cut_id[key] = len(V) + len(new_pts)
            new_pts.append(p - ((p - e) @ n) * n)
        return cut_id[key]

    for f in F[split]:
        poly = []
        for k in range(3):
            a, b = f[k], f[(k + 1) % 3]
            if side[a] <= 0:
                poly.append(a)
            if side[a] * side[b] < 0:
                poly.append(cut(a, b))
        for k in range(1, len(poly) - 1):
            new_faces.append((poly[0], poly[k], poly[k + 1]))
    V = np.concatenate([V, np.array(new_pts).reshape(-1, 3)])
    F = np.concatenate([F[keep], np.array(new_faces, dtype=np.int64).reshape(-1, 3)])
    # The open boundary: directed edges without a twin, chained into one loop.
    # Only edges touching the cut region can be open (and their twins touch it).
    mark = np.concatenate([local, np.ones(len(new_pts), bool)])
    de = F[mark[F].any(axis=1)][:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    de = de[mark[de[:, 0]] | mark[de[:, 1]]]
    code = de[:, 0] * len(V) + de[:, 1]
    twin = np.isin(de[:, 1] * len(V) + de[:, 0], code)
    bnd = de[~twin]
    nxt = dict(zip(bnd[:, 0].tolist(), bnd[:, 1].tolist()))
    if len(nxt) != len(bnd) or len(bnd) < 6:
        raise RuntimeError("cap cut is not a simple loop")
    loop = [int(bnd[0, 0])]
    while nxt[loop[-1]] != loop[0]:
        loop.append(nxt[loop[-1]])
        if len(loop) > len(bnd):
            raise RuntimeError("cap cut is not a simple loop")
    if len(loop) != len(bnd):
        raise RuntimeError("cap cut has several loops")
    # Disc on the plane: counter-clockwise about n (outward normal).
    e1, e2 = _cap_frame(n)
    A = np.array(loop[::-1])                        # cap runs against the wall's loop
    q = V[A] - e
    ang = np.unwrap(np.arctan2(q @ e2, q @ e1))
    span = ang[-1] - ang[0]                         # one turn minus the closing step
    if np.any(np.diff(ang) <= 0) or not np.pi < span < 2 * np.pi:
        raise RuntimeError("cap rim is not a counter-clockwise loop around the end point")
    rho = float(np.linalg.norm(q, axis=1).mean())
    ell = float(np.linalg.norm(np.diff(V[np.r_[A, A[:1]]], axis=0), axis=1).mean())
    K = max(1, int(round(rho / ell)))
    rings, ring_ang, extra = [A], [ang], []
    base = len(V)
    for k in range(1, K):
        m = max(6, int(round(len(A) * (K - k) / K)))
        th = ang[0] + (np.arange(m) + 0.5 * k) * 2 * np.pi / m
        rr = rho * (K - k) / K
        extra.append(e + rr * (np.cos(th)[:, None] * e1 + np.sin(th)[:, None] * e2))
        rings.append(np.arange(base, base + m))
        ring_ang.append(th)
        base += m
    centre = base
    extra.append(e[None])
    tris = []
    for k in range(len(rings) - 1):
        tris += _zip_rings(rings[k], ring_ang[k], rings[k + 1], ring_ang[k + 1])
    last = rings[-1]
    tris += [(last[j], last[(j + 1) % len(last)], centre) for j in range(len(last))]
    V = np.concatenate([V] + extra)
    F = np.concatenate([F, np.array(tris, dtype=np.int64)])
    return V, F


def _compact(V, F):
    used = np.unique(F)
    remap = np.full(len(V), -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    return V[used], remap[F]


def _snap_caps(V, caps, h):
    """Put vertices that drifted off a cap plane (decimation) back onto it."""
    V = V.copy()
    for e, n, r in caps:
        d = (V - e) @ n
        radial = np.linalg.norm((V - e) - d[:, None] * n, axis=1)
        m = (np.abs(d) < 0.05 * h) & (radial < r + h)
        V[m] -= d[m, None] * n
    return V


def _decimate(V, F, target):
    import pymeshlab
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=V, face_matrix=F.astype(np.int32)))
    ms.meshing_decimation_quadric_edge_collapse(
        targetfacenum=int(target), qualitythr=0.5, preservenormal=True,
        preservetopology=True, optimalplacement=True, planarquadric=True,
        autoclean=True)
    ms.meshing_remove_unreferenced_vertices()
    m = ms.current_mesh()
    return np.asarray(m.vertex_matrix(), dtype=float), np.asarray(m.face_matrix(), dtype=np.int64)


def winding_numbers(V: np.ndarray, F: np.ndarray, Q: np.ndarray) -> np.ndarray:
    """Generalised winding number of points ``Q`` (exact solid-angle sum)."""
    V = np.asarray(V, float)
    out = np.zeros(len(Q))
    tri = V[F]
    for i0 in range(0, len(Q), 64):
        q = Q[i0:i0 + 64]
        a = tri[None, :, 0] - q[:, None]
        b = tri[None, :, 1] - q[:, None]
        c = tri[None, :, 2] - q[:, None]
        la, lb, lc = (np.linalg.norm(x, axis=2) for x in (a, b, c))
        num = np.einsum("qfi,qfi->qf", a, np.cross(b, c))
        den = (la * lb * lc + np.einsum("qfi,qfi->qf", a, b) * lc
               + np.einsum("qfi,qfi->qf", b, c) * la + np.einsum("qfi,qfi->qf", c, a) * lb)
        out[i0:i0 + 64] = np.arctan2(num, den).sum(axis=1) / (2 * np.pi)
    return out


def check_case(V, F, skel, spec: CaseSpec | None = None, euler: int | None = None) -> dict:
    """Validate a surface + skeleton; returns a report (raises on failure)."""
    problems = []
    edges, counts = _edges(F)
    if np.any(counts != 2):
        problems.append(f"{np.sum(counts == 1)} boundary / {np.sum(counts > 2)} non-manifold edges")
    # Consistent orientation: every directed edge appears exactly once.
    de = F[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    if len(np.unique(de, axis=0)) != len(de):
        problems.append("inconsistent face orientation")
    if not problems and _vertex_fans(len(V), F) != len(np.unique(F)):
        problems.append("non-manifold vertices")
    ncomp = len(np.unique(_components(len(V), F)))
    if ncomp != 1:
        problems.append(f"{ncomp} components")
    vol = signed_volume(V, F)
    if vol <= 0:
        problems.append("inward orientation")
    chi = len(np.unique(F)) - len(edges) + len(F)
    euler = spec.euler if euler is None and spec is not None else euler
    if euler is not None and chi != euler:
        problems.append(f"Euler characteristic {chi} != {euler}")
    nodes = skel["nodes"]
    X = np.array([n["xyz"] for n in nodes], float)
    deg = np.zeros(len(nodes), int)
    nbr = [[] for _ in nodes]
    for i, j in skel["edges"]:
        deg[i] += 1
        deg[j] += 1
        nbr[i].append(j)
        nbr[j].append(i)
    Q = X.copy()
    for i, n in enumerate(nodes):
        if "inlet" in n["tags"] or "outlet" in n["tags"]:
            # Capped end: nudge 5 % of the radius into the vessel.
            Q[i] += 0.05 * n["radius"] * _unit(X[nbr[i][0]] - X[i])
    try:
        import igl
        w = igl.fast_winding_number(np.asarray(V, float), np.asarray(F, np.int64), Q)
    except Exception:                               # pragma: no cover - igl missing
        w = winding_numbers(V, F, Q)
    if np.any(w < 0.9):
        problems.append(f"{np.sum(w < 0.9)} skeleton nodes outside the surface")
    # Flat caps: a planar disc of vertices at every end node.
    cap_err = 0.0
    for i, n in enumerate(nodes):
        if "inlet" in n["tags"] or "outlet" in n["tags"]:
            nrm = _unit(X[i] - X[nbr[i][0]])
            d = (V - X[i]) @ nrm
            radial = np.linalg.norm((V - X[i]) - d[:, None] * nrm, axis=1)
            on = (np.abs(d) < 1e-3 * n["radius"] + 2e-5) & (radial < 1.2 * n["radius"])
            if on.sum() < 6 or radial[on].max() < 0.8 * n["radius"]:
                problems.append(f"node {i}: no flat cap")
            else:
                cap_err = max(cap_err, abs(radial[on].max() / n["radius"] - 1))
    report = {"faces": len(F), "vertices": len(V), "nodes": len(nodes),
              "edges": len(skel["edges"]), "components": ncomp, "volume": round(vol, 3),
              "euler": int(chi), "min_winding": round(float(w.min()), 4),
              "cap_rim_error": round(cap_err, 3), "max_degree": int(deg.max())}
    if problems:
        raise RuntimeError(f"{skel['name']}: " + "; ".join(problems))
    return report


def axis_deviation(spec: CaseSpec, chains) -> float:
    """Max distance (in local radii) from the fine axis to the skeleton polyline."""
    worst = 0.0
    for i, chain in chains:
        p = spec.paths[i]
        if not p.tube:
            continue
        for (_, sa), (_, sb) in zip(chain[:-1], chain[1:]):
            a, b = p.point_at(sa), p.point_at(sb)
            if p.closed:
                ss = np.concatenate([p.s, p.s[1:] + p.length])
                pts = np.concatenate([p.pts, p.pts[1:]])
            else:
                ss, pts = p.s, p.pts
            m = (ss > sa) & (ss < sb)
            if not m.any():
                continue
            q, r = pts[m], np.interp(ss[m], ss, np.concatenate([p.rad, p.rad[1:]]) if p.closed else p.rad)
            ba = b - a
            t = np.clip((q - a) @ ba / (ba @ ba), 0, 1)
            d = np.linalg.norm(q - (a + t[:, None] * ba), axis=1)
            worst = max(worst, float(np.max(d / r)))
    return worst


# ----------------------------------------------------------------------------
# Cases
# ----------------------------------------------------------------------------

def _dir(azim_deg, elev_deg=0.0):
    a, e = np.radians(azim_deg), np.radians(elev_deg)
    return np.array([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)])


def _straight_tube(rs, rng):
    p = make_path([[0, 0, 0], [40, 0, 0]], [], 3.0 * rs, cap_start=True, cap_end=True)
    return CaseSpec("straight_tube", [p], target_faces=6000)


def _curved_tube(rs, rng):
    # 150 degree bend of bend radius 11 with 8 mm straight ends.
    R, theta, straight = 11.0, np.radians(150), 8.0
    t = R * np.tan(theta / 2)
    c = np.array([0.0, 0, 0])
    d2 = np.array([np.cos(theta), np.sin(theta), 0])
    ctrl = [c - (t + straight) * np.array([1, 0, 0]), c, c + (t + straight) * d2]
    p = make_path(ctrl, R, 2.5 * rs, cap_start=True, cap_end=True)
    return CaseSpec("curved_tube", [p], target_faces=8000)


def _furcation(name, rs, r_trunk, daughters, target, trunk_len=20.0):
    """Trunk along +x ending at the origin, daughters ``(direction, r, length)``."""
    J = np.zeros(3)
    trunk = make_path([[-trunk_len, 0, 0], J], [], r_trunk * rs, cap_start=True)
    paths = [trunk]
    for d, r, L, bend in daughters:
        d = _unit(d)
        if bend:
            # Bend back towards +x after 12 mm: vessel-like, straight end.
            q = J + 12 * d
            ctrl = [J, q, q + (L - 12) * _unit(np.array([1.0, 0, 0]) + 0.35 * _unit(d - [d[0], 0, 0]))]
            p = make_path(ctrl, 10.0, r * rs, cap_end=True, start_on=(0, trunk.length))
        else:
            p = make_path([J, J + L * d], [], r * rs, cap_end=True, start_on=(0, trunk.length))
        p.blend = BLEND * r * rs
        paths.append(p)
    return CaseSpec(name, paths, target_faces=target)


def _y_bifurcation(rs, rng):
    return _furcation("y_bifurcation", rs, 3.0,
                      [(_dir(35), 2.4, 26, True), (_dir(-35), 2.0, 26, True)], 10000)


def _trifurcation(rs, rng):
    ds = [np.array([np.cos(np.radians(35)), np.sin(np.radians(35)) * np.cos(a),
                    np.sin(np.radians(35)) * np.sin(a)]) for a in np.radians([90, 210, 330])]
    return _furcation("trifurcation", rs, 3.0,
                      [(ds[0], 2.2, 24, False), (ds[1], 2.0, 24, False), (ds[2], 1.9, 24, False)],
                      12000)


def _five_furcation(rs, rng):
    # Daughters in the xy-plane, tilted out of it by at most 4 degrees.
    return _furcation("five_furcation", rs, 3.2,
                      [(_dir(62, 3), 2.0, 24, False), (_dir(21, -4), 1.8, 26, False),
                       (_dir(-21, 4), 1.8, 26, False), (_dir(-62, -3), 2.0, 24, False)],
                      14000, trunk_len=22.0)


def _two_junctions(rs, rng):
    # One vessel r 3 -> 2.8 with a side branch at J1 and a bifurcation at J2,
    # 4 mm (1.33 x trunk radius) further on.
    gap = 4.0
    J1, J2 = np.zeros(3), np.array([gap, 0, 0])
    trunk = make_path([[-20, 0, 0], J2], [], lambda s, L: rs * np.interp(s, [0, 20, L], [3.0, 3.0, 2.8]),
                      step=0.5, cap_start=True)
    s1 = 20.0
    side = make_path([J1, J1 + 10 * _dir(55), J1 + 10 * _dir(55) + 12 * _dir(25)], 8.0, 1.8 * rs,
                     cap_end=True, start_on=(0, s1), blend=BLEND * 1.8 * rs)
    # The second bifurcation opens in the xz-plane, away from the side branch.
    da = np.array([np.cos(np.radians(35)), 0, np.sin(np.radians(35))])
    db = np.array([np.cos(np.radians(35)), 0, -np.sin(np.radians(35))])
    d1 = make_path([J2, J2 + 24 * da], [], 2.2 * rs, cap_end=True, start_on=(0, trunk.length),
                   blend=BLEND * 2.2 * rs)
    d2 = make_path([J2, J2 + 24 * db], [], 2.0 * rs, cap_end=True, start_on=(0, trunk.length),
                   blend=BLEND * 2.0 * rs)
    trunk.keys[s1] = []
    return CaseSpec("two_junctions", [trunk, side, d1, d2], target_faces=12000)


def _uneven_bifurcation(rs, rng):
    # Main vessel r 4 -> 3.8 straight through the junction, thin side branch.
    main = make_path([[-25, 0, 0], [30, 0, 0]], [],
                     lambda s, L: rs * np.interp(s, [0, 25, 35, L], [4.0, 4.0, 3.8, 3.8]),
                     step=0.5, cap_start=True, cap_end=True)
    sJ = 25.0
    J = main.point_at(sJ)
    d = _dir(70, 15)
    q = J + 12 * d
    side = make_path([J, q, q + 14 * _unit(d + [0.5, 0, 0.2])], 8.0, 1.2 * rs, cap_end=True,
                     start_on=(0, sJ), blend=BLEND * 1.2 * rs)
    main.keys[sJ] = []
    return CaseSpec("uneven_bifurcation", [main, side], target_faces=12000)


def _aneurysm(rs, rng):
    r = 2.0 * rs
    R_bend, theta = 12.0, np.radians(120)
    t = R_bend * np.tan(theta / 2)
    c = np.zeros(3)
    d2 = np.array([np.cos(theta), np.sin(theta), 0.0])
    vessel = make_path([c - (t + 10) * np.array([1.0, 0, 0]), c, c + (t + 10) * d2], R_bend,
                       lambda s, L: rs * np.interp(s, [0, L], [2.0, 1.9]),
                       step=0.5, cap_start=True, cap_end=True)
    # Junction at the middle of the arc; the sac sits on the outer side.
    s_arc0 = 10.0
    sJ = s_arc0 + 0.5 * R_bend * theta
    J = vessel.point_at(sJ)
    # Arc centre lies on the inner side, R_bend from the axis.
    m = _unit(d2 - np.cos(theta) * np.array([1.0, 0, 0]))
    arc_c = c - t * np.array([1.0, 0, 0]) + R_bend * m
    out = _unit(J - arc_c)
    rJ = vessel.radius_at(sJ)
    R_sac = 1.75 * r
    D = rJ + 0.8 * R_sac                             # sac centre distance from axis
    C = J + D * out
    r_neck = float(np.sqrt(R_sac ** 2 - (D - rJ) ** 2))
    N = J + rJ * out
    T = C + 0.5 * R_sac * out
    pts = np.array([J, N, C, T])
    sac_path = VPath(pts, [rJ, r_neck, R_sac, np.sqrt(0.75) * R_sac], tube=False, tags=(),
                     start_on=(0, sJ))
    sac_path.node_s = sac_path.s.copy()
    sac_path.node_tags = [[], ["neck"], ["aneurysm"], ["aneurysm"]]
    vessel.keys[sJ] = []
    spheres = [Sphere(C, R_sac, BLEND * min(rJ, r_neck))]
    return CaseSpec("aneurysm", [vessel, sac_path], spheres, target_faces=14000)


def _coarctation(rs, rng):
    # Ascending aorta up z, arch over to x = 56 (slightly out of plane), descending.
    R_arch = 28.0
    ctrl = [[0, -6, 0], [0, -6, 70], [56, 6, 70], [56, 6, -95]]
    pts0 = fillet_polyline(ctrl, R_arch, 0.5)
    s0 = _arclength(pts0)
    # End of the arch: where the curve is straight again going down.
    tang = np.diff(pts0, axis=0)
    down = np.where(_unit(tang)[:, 2] < -0.9999)[0]
    s_arch_end = float(s0[down[0]])
    s_c, w = s_arch_end + 22.0, 26.0               # coarctation centre and width

    def radius(s, L):
        base = np.interp(s, [0, 45, s_arch_end, L], [12.0, 11.0, 10.0, 10.0])
        x = np.clip((s - s_c) / w, -0.5, 0.5)
        return rs * base * (1 - 0.5 * np.cos(np.pi * x) ** 2)

    def coarct_tags(s):
        return ["coarctation"] if abs(s - s_c) < 0.3 * w else []

    aorta = make_path(ctrl, R_arch, radius, step=0.5, cap_start=True, cap_end=True,
                      tag_fn=coarct_tags)
    aorta.keys[s_c] = []
    # Supra-aortic branches from the top of the arch, 16 mm apart along it.
    top = int(np.argmax(aorta.pts[:, 2]))
    s_top = float(aorta.s[top])
    arch_centre = np.array([28.0, 0.0, 42.0])
    paths = [aorta]
    for ds, r, lateral in ((-16.0, 5.0, [-6, -3, 0]), (0.0, 3.5, [2, 0, 0]), (16.0, 4.0, [8, 4, 0])):
        sJ = s_top + ds
        J = aorta.point_at(sJ)
        tg = _unit(aorta.point_at(sJ + 0.5) - aorta.point_at(sJ - 0.5))
        u = J - arch_centre
        u = _unit(u - (u @ tg) * tg)
        q = J + 20 * u
        ctrl_b = [J, q, q + np.array(lateral, float) + [0, 0, 38]]
        b = make_path(ctrl_b, 14.0, lambda s, L, r=r: rs * np.interp(s, [0, L], [r, 0.9 * r]),
                      step=0.5, cap_end=True, start_on=(0, sJ), blend=BLEND * r * rs)
        aorta.keys[sJ] = []
        paths.append(b)
    return CaseSpec("coarctation", paths, target_faces=20000)


def _ring(rs, rng):
    Rr, r_ring = 10.0, 1.2
    phi = np.linspace(0, 2 * np.pi, 241)
    circle = np.stack([Rr * np.cos(phi), Rr * np.sin(phi), np.zeros_like(phi)], axis=1)
    circle[-1] = circle[0]
    ring = VPath(circle, r_ring * rs, closed=True)
    ring.blend = BLEND * r_ring * rs
    paths = [ring]
    L = ring.length

    def s_of(deg):
        return float(np.interp(np.radians(deg), phi, ring.s))

    for deg in (55.0, 125.0, 270.0):                 # inlets from below, r 1.6 -> 1.4
        sJ = s_of(deg)
        J = ring.point_at(sJ)
        rad = _unit(J * [1, 1, 0])
        ctrl = [J + 6 * rad + [0, 0, -22], J + 6 * rad + [0, 0, -6], J]
        p = make_path(ctrl, 5.0, lambda s, Lp: rs * np.interp(s, [0, Lp], [1.6, 1.4]),
                      step=0.3, cap_start=True, end_on=(0, sJ), blend=BLEND * r_ring * rs)
        p.keys[0.0] = ["inlet"]
        ring.keys[sJ] = []
        paths.append(p)
    for deg in (0.0, 90.0, 180.0):                   # outlets outwards, then up
        sJ = s_of(deg) % L
        J = ring.point_at(sJ)
        rad = _unit(J * [1, 1, 0])
        q = J + 8 * rad
        ctrl = [J, q, q + 6 * rad + [0, 0, 12]]
        p = make_path(ctrl, 5.0, 1.0 * rs, step=0.3, cap_end=True, start_on=(0, sJ),
                      blend=BLEND * rs)
        ring.keys[sJ] = []
        paths.append(p)
    return CaseSpec("ring", paths, target_faces=16000, euler=0)


# ----------------------------------------------------------------------------
# Cerebral-like tree
# ----------------------------------------------------------------------------

def _branch_curve(J, d, L, r0, r1, Rc, bend, step, head=0.0):
    """Arc of radius ``Rc`` from ``J`` along ``d`` (bending towards ``bend``),
    ending in a straight tail of 2 ``r1`` (so that a leaf's cap is square to
    its last skeleton segment), optionally starting with a straight ``head``.
    Returns points, radii and end tangent."""
    tail = 2.0 * r1
    arc_len = max(L - tail - head, 0.5 * L)
    m = _unit(bend - (bend @ d) * d)
    phi = arc_len / Rc
    n = max(2, int(np.ceil(arc_len / step)))
    f = np.linspace(0, phi, n + 1)[:, None]
    arc = J + Rc * (np.sin(f) * d + (1 - np.cos(f)) * m)
    if head > 0:
        nh = max(1, int(np.ceil(head / step)))
        arc = np.concatenate([J + np.linspace(0, head, nh + 1)[:-1, None] * d, arc + head * d])
    t_end = np.cos(phi) * d + np.sin(phi) * m
    nt = max(1, int(np.ceil(tail / step)))
    tl = arc[-1] + np.linspace(0, tail, nt + 1)[1:, None] * t_end
    pts = np.concatenate([arc, tl])
    s = _arclength(pts)
    return pts, r0 + (r1 - r0) * s / s[-1], t_end


def _tree_paths(seed: int, node_target=(500, 600)):
    """Grow a seeded, collision-free, Murray-like tree.

    Breadth-first growth from a root of radius 2 (going up +z from the origin)
    inside a sphere of radius 32.  Every bud splits into two children with
    Murray radii ``rp**3 = r1**3 + r2**3`` (random asymmetry, no child below
    0.5 mm) at Murray's optimal angles; each child is a gentle arc ending in a
    straight tail.  Of 32 random split candidates the one with the largest
    clearance is kept; a candidate is rejected when any of its points (and the
    prolongation the surface is cut from) comes closer to another vessel than
    the sum of radii + 0.5 mm.  Growth stops at about 540 skeleton nodes; if the
    tree dies out earlier, it is regrown with longer branches.

    Returns
    -------
    list of (points, radii, parent index)
    """
    from scipy.spatial import cKDTree

    c_dom, r_dom = np.array([0.0, 0.0, 30.0]), 32.0
    r_root, r_min, r_split, margin = 2.0, 0.5, 0.6, 0.5

    def node_count(pts, rad):                       # nodes a branch adds (not its start)
        p = VPath(pts, rad)
        return len(_piece_node_s(p, 0.0, p.length)) + 1

    for attempt in range(12):
        rng = np.random.default_rng([seed, attempt])
        len_fac = 9.0 + attempt                     # branch length = len_fac * r**0.7
        pts, rad, t_end = _branch_curve(np.zeros(3), np.array([0.0, 0, 1]), 14.0, r_root, 1.9,
                                        40.0, np.array([1.0, 0.3, 0]), 0.3, head=2 * r_root)
        branches = [(pts, rad, -1)]
        occ_p, occ_r, occ_o = [pts], [rad], [np.zeros(len(pts), int)]
        n_nodes = 1 + node_count(pts, rad)
        queue = deque([(0, t_end)])
        while queue and n_nodes < node_target[0] + 40:
            bi, T = queue.popleft()
            J, rp = branches[bi][0][-1], branches[bi][1][-1]
            if rp < r_split:
                continue                            # too thin to split: leaf
            P, Rr, O = np.concatenate(occ_p), np.concatenate(occ_r), np.concatenate(occ_o)
            tree = cKDTree(P)
            kq = min(12, len(P))
            u = _unit(np.cross(T, [0.3, 0.5, 0.8]))
            v = np.cross(T, u)
            best = None
            for _ in range(32):
                lam = rng.uniform(0.45, 1.0)
                r1 = rp / (1 + lam ** 3) ** (1 / 3)
                r2 = max(lam * r1, r_min)
                r1 = max(r1, r_min)
                c1 = np.clip((rp ** 4 + r1 ** 4 - r2 ** 4) / (2 * rp ** 2 * r1 ** 2), -1, 1)
                c2 = np.clip((rp ** 4 + r2 ** 4 - r1 ** 4) / (2 * rp ** 2 * r2 ** 2), -1, 1)
                th1 = np.clip(np.arccos(c1) + rng.uniform(-0.1, 0.1), np.radians(15), np.radians(75))
                th2 = np.clip(np.arccos(c2) + rng.uniform(-0.1, 0.1), np.radians(25), np.radians(80))
                psi = rng.uniform(0, 2 * np.pi)
                w = np.cos(psi) * u + np.sin(psi) * v     # normal of the split plane
                kids, score = [], np.inf
                for r_c, th, sgn in ((r1, th1, 1), (r2, th2, -1)):
                    d = np.cos(th) * T + sgn * np.sin(th) * w
                    L0 = r_c ** 0.7 * rng.uniform(0.6, 1.2) * len_fac
                    r_end = max(r_c * rng.uniform(0.96, 1.0), r_min)
                    # Bend away from the sibling; near the domain boundary bend
                    # towards its centre and shorten instead.
                    rand = _unit(np.cross(d, rng.normal(size=3)))
                    away = _unit(rand + 0.8 * sgn * w)
                    inward = _unit(0.7 * _unit(c_dom - J) + 0.3 * rand)
                    Rc = rng.uniform(5.0, 14.0) * r_c
                    for fL, bend in ((1.0, away), (1.0, inward), (0.75, inward), (0.55, inward)):
                        cp, cr, ct = _branch_curve(J, d, fL * L0, r_c, r_end, Rc, bend, 0.3 * r_end)
                        dom = r_dom - np.max(np.linalg.norm(cp - c_dom, axis=1) + cr)
                        if dom > 0 and np.all(cp[:, 2] > cr + 1):
                            break
                    else:
                        break
                    # Check the prolonged tube too (the surface is cut from it).
                    ext = ct * np.linspace(0.2, 2 * r_end + 0.5, 6)[:, None]
                    cp_chk = np.concatenate([cp, cp[-1] + ext])
                    cr_chk = np.concatenate([cr, np.full(6, r_end)])
                    # Near the junction only the parent may be close.
                    far = np.linalg.norm(cp_chk - J, axis=1) > 1.5 * (rp + r_c) + margin
                    dist, idx = tree.query(cp_chk, k=kq)
                    gap = dist - cr_chk[:, None] - Rr[idx]
                    gap[~far] = np.where(O[idx[~far]] == bi, np.inf, gap[~far])
                    g = float(gap.min())
                    for _, _, _, kp, kr in kids:        # the sibling, away from J
                        dd = np.linalg.norm(cp_chk[far][:, None] - kp[None], axis=2)
                        if dd.size:
                            g = min(g, float((dd - cr_chk[far][:, None] - kr[None]).min()))
                    if g < margin:
                        break
                    score = min(score, min(g, 3.0) + 0.01 * min(dom, 10.0))
                    kids.append((cp, cr, ct, cp_chk, cr_chk))
                if len(kids) == 2 and (best is None or score > best[0]):
                    best = (score, kids)
            if best is None:
                continue                            # no room: leaf
            add = sum(node_count(k[0], k[1]) for k in best[1])
            if n_nodes + add > node_target[1] - 5:
                continue
            for cp, cr, ct, cp_chk, cr_chk in best[1]:
                branches.append((cp, cr, bi))
                occ_p.append(cp_chk)
                occ_r.append(cr_chk)
                occ_o.append(np.full(len(cp_chk), len(branches) - 1))
                queue.append((len(branches) - 1, ct))
            n_nodes += add
        if node_target[0] <= n_nodes <= node_target[1]:
            return branches
    raise RuntimeError(f"could not grow a tree with {node_target} nodes (seed {seed})")


def _cerebral_tree(rs, rng, seed=0):
    branches = _tree_paths(seed)
    has_kids = {b[2] for b in branches}
    paths = []
    for i, (pts, rad, parent) in enumerate(branches):
        p = VPath(pts, rad * rs, cap_start=(parent < 0), cap_end=(i not in has_kids),
                  start_on=None if parent < 0 else (parent, float(_arclength(branches[parent][0])[-1])))
        p.blend = BLEND * float(rad.min()) * rs
        paths.append(p)
    return CaseSpec("cerebral_tree", paths, target_faces=100000, grid_per_radius=4.0)


_BUILDERS = {
    "straight_tube": _straight_tube,
    "curved_tube": _curved_tube,
    "y_bifurcation": _y_bifurcation,
    "trifurcation": _trifurcation,
    "five_furcation": _five_furcation,
    "two_junctions": _two_junctions,
    "uneven_bifurcation": _uneven_bifurcation,
    "aneurysm": _aneurysm,
    "coarctation": _coarctation,
    "cerebral_tree": None,
    "ring": _ring,
}


def case_spec(name: str, radius_scale: float = 1.0, seed: int = 0) -> CaseSpec:
    """Geometric description (centre curves, radii, caps) of a case."""
    if name not in _BUILDERS:
        raise ValueError(f"unknown case {name!r}; choose from {', '.join(CASES)}")
    if name == "cerebral_tree":
        spec = _cerebral_tree(float(radius_scale), None, seed)
    else:
        spec = _BUILDERS[name](float(radius_scale), np.random.default_rng(seed))
    spec.radius_scale = float(radius_scale)
    return spec


# ----------------------------------------------------------------------------
# Surface generation
# ----------------------------------------------------------------------------

def surface_from_spec(spec: CaseSpec, verbose: bool = False):
    """Closed outward triangle surface of a case (vertices, faces)."""
    from skimage.measure import marching_cubes

    rmin = min([float(p.rad.min()) for p in spec.paths if p.tube] + [s.radius for s in spec.spheres])
    h = rmin / spec.grid_per_radius
    t0 = time.perf_counter()
    Fld, grid = implicit_grid(spec, h)
    t1 = time.perf_counter()
    V, F, _, _ = marching_cubes(Fld, level=0.0, spacing=(h, h, h), allow_degenerate=False)
    del Fld
    V = V.astype(np.float64) + grid.origin
    F = F.astype(np.int64)
    t2 = time.perf_counter()
    # Keep the largest piece (guards against specks), orient outwards.
    lab = _components(len(V), F)
    if lab.max() > 0:
        F = F[lab == np.bincount(lab).argmax()]
    V, F = _compact(V, F)
    if signed_volume(V, F) < 0:
        F = F[:, ::-1].copy()
    V = _taubin(V, F)
    caps = _caps(spec)
    for e, n, r in caps:
        V, F = _clip_and_cap(V, F, e, n, r, h)
    V, F = _compact(V, F)
    n_mc = len(F)
    if len(F) > spec.target_faces:
        V, F = _decimate(V, F, spec.target_faces)
    V = _snap_caps(V, caps, h)
    if signed_volume(V, F) < 0:
        F = F[:, ::-1].copy()
    t3 = time.perf_counter()
    if verbose:
        print(f"  grid {grid.shape} h={h:.3f}: field {t1 - t0:.1f}s, marching cubes "
              f"{t2 - t1:.1f}s ({n_mc} faces), smooth+decimate {t3 - t2:.1f}s -> {len(F)} faces")
    return V, F


def make_case(name: str, radius_scale: float = 1.0, seed: int = 0, verbose: bool = False):
    """Build one synthetic case in memory.

    Parameters
    ----------
    name : str
        One of :data:`CASES`.
    radius_scale : float
        Factor applied to every radius (centre lines unchanged).
    seed : int
        Seed of the random tree (only ``cerebral_tree`` is random).
    verbose : bool
        Print timings.

    Returns
    -------
    vertices : numpy.ndarray, shape (n, 3), float64
        Surface vertices (mm), rounded to float32 precision like the PLY file.
    faces : numpy.ndarray, shape (m, 3), int64
        Triangles, counter-clockwise seen from outside.
    skeleton : dict
        Ground-truth skeleton in the JSON format described in the module doc.
    """
    spec = case_spec(name, radius_scale, seed)
    skel, _ = build_skeleton(name, spec.paths, spec.radius_scale)
    V, F = surface_from_spec(spec, verbose=verbose)
    V = V.astype(np.float32).astype(np.float64)
    return V, F, skel


# ----------------------------------------------------------------------------
# Files
# ----------------------------------------------------------------------------

def ply_bytes(V: np.ndarray, F: np.ndarray, comment: str = "") -> bytes:
    """Binary little-endian PLY with float32 vertices and int32 triangles."""
    V32 = np.ascontiguousarray(V, dtype="<f4")
    face = np.empty(len(F), dtype=[("n", "u1"), ("i", "<i4", (3,))])
    face["n"] = 3
    face["i"] = F
    header = ("ply\nformat binary_little_endian 1.0\n"
              + (f"comment {comment}\n" if comment else "")
              + f"element vertex {len(V32)}\nproperty float x\nproperty float y\nproperty float z\n"
              + f"element face {len(F)}\nproperty list uchar int vertex_indices\nend_header\n")
    return header.encode("ascii") + V32.tobytes() + face.tobytes()


def read_ply(path) -> tuple[np.ndarray, np.ndarray]:
    """Read a PLY written by :func:`ply_bytes` (vertices float64, faces int64)."""
    data = Path(path).read_bytes()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    head = data[:end].decode("ascii").split("\n")
    nv = int(next(line.split()[2] for line in head if line.startswith("element vertex")))
    nf = int(next(line.split()[2] for line in head if line.startswith("element face")))
    V = np.frombuffer(data, dtype="<f4", count=3 * nv, offset=end).reshape(nv, 3)
    face = np.frombuffer(data, dtype=[("n", "u1"), ("i", "<i4", (3,))], count=nf, offset=end + 12 * nv)
    return V.astype(np.float64), face["i"].astype(np.int64)


def skeleton_text(skel: dict) -> str:
    """The skeleton as JSON text, one node per line (deterministic)."""
    lines = ["{", f'  "name": {json.dumps(skel["name"])},', f'  "units": {json.dumps(skel["units"])},',
             '  "nodes": [']
    nodes = [json.dumps(n) for n in skel["nodes"]]
    lines += ["    " + n + ("," if i < len(nodes) - 1 else "") for i, n in enumerate(nodes)]
    lines.append("  ],")
    e = [json.dumps(x) for x in skel["edges"]]
    rows = [", ".join(e[i:i + 12]) for i in range(0, len(e), 12)]
    lines.append('  "edges": [')
    lines += ["    " + r + ("," if i < len(rows) - 1 else "") for i, r in enumerate(rows)]
    lines += ["  ]", "}", ""]
    return "\n".join(lines)


def write_case(name: str, out_dir: Path, radius_scale: float = 1.0, seed: int = 0,
               verbose: bool = False) -> dict:
    """Generate, check and write one case; returns a report."""
    t0 = time.perf_counter()
    spec = case_spec(name, radius_scale, seed)
    skel, chains = build_skeleton(name, spec.paths, spec.radius_scale)
    V, F = surface_from_spec(spec, verbose=verbose)
    V = V.astype(np.float32).astype(np.float64)
    report = check_case(V, F, skel, spec)
    report["axis_deviation"] = round(axis_deviation(spec, chains), 4)
    out_dir.mkdir(parents=True, exist_ok=True)
    surf, sk = out_dir / "surface.ply", out_dir / "skeleton.json"
    surf.write_bytes(ply_bytes(V, F, f"vmesh synthetic case {name}"))
    sk.write_text(skeleton_text(skel))
    report["bytes"] = surf.stat().st_size + sk.stat().st_size
    report["seconds"] = round(time.perf_counter() - t0, 1)
    return report


def case_paths(name: str) -> tuple[Path, Path]:
    """Paths of a case's surface (PLY) and skeleton (JSON).

    Returns the committed files; a case that is missing (or not committed) is
    generated once into ``data_synthetic/cache/<name>/``.
    """
    if name not in CASES:
        raise ValueError(f"unknown case {name!r}; choose from {', '.join(CASES)}")
    for base in (DATA_DIR / name, CACHE_DIR / name):
        surf, sk = base / "surface.ply", base / "skeleton.json"
        if surf.exists() and sk.exists():
            return surf, sk
    write_case(name, CACHE_DIR / name)
    return CACHE_DIR / name / "surface.ply", CACHE_DIR / name / "skeleton.json"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description="Generate the synthetic vessel cases of data_synthetic/.")
    ap.add_argument("--case", nargs="+", action="extend", choices=CASES, metavar="NAME",
                    help="case(s) to generate (default: all)")
    ap.add_argument("--force", action="store_true", help="overwrite existing files")
    ap.add_argument("--quiet", action="store_true")
    args = ap.parse_args(argv)
    names = args.case or CASES
    for name in names:
        out = (CACHE_DIR if name in UNCOMMITTED else DATA_DIR) / name
        if not args.force and (out / "surface.ply").exists() and (out / "skeleton.json").exists():
            if not args.quiet:
                print(f"{name}: exists (use --force to regenerate)")
            continue
        if not args.quiet:
            print(f"{name}:")
        rep = write_case(name, out, verbose=not args.quiet)
        if not args.quiet:
            print("  " + ", ".join(f"{k}={v}" for k, v in rep.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
