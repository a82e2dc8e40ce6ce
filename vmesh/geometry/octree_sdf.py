"""Octree of candidate triangles: a fast signed distance checked against the exact one.

A BVH query (:mod:`vmesh.geometry.bvh`) must prove that no other triangle is closer,
and near a vessel's centreline a whole ring of wall is almost equally close. A mesher
queries the same region of space millions of times, so most of that search can be done
once, when the structure is built:

* an adaptive octree covers the vessel and a margin outside it;
* each leaf keeps the exact closest triangle of each point of its 3×3×3 lattice;
* a query walks down to its leaf, tests the triangles of the 8 lattice points around
  its half-size sub-cell (about 5 distinct ones), and then walks over the surface while
  the closest point lies on an edge or a corner (which finds the triangle right below a
  point near the wall even when no lattice point chose it). The answer is a point *on
  the surface* and the feature holding it, signed exactly as the BVH query's.

**Checks.** A cell becomes a leaf only where the query gives the exact signed distance,
to within ``max_error`` local radii, at the centres of its 8 sub-cells, and where it is
no larger than ``max_cell`` local radii (the local radius is the inward chord at the
lattice points' closest faces, :func:`~vmesh.geometry.sdf.local_radius`). Cells near the
medial axis, where closest points of neighbouring lattice points lie far apart, are
checked at 18 more points. Otherwise a cell is split, down to ``min_cell`` local radii.
Cells that never pass, cells far outside the vessel and cells at creases of the wall
(cap rims, the crotch of a junction: a point there has two local minima, one on each
side) keep the exact BVH query. The bound is checked at sample points, not proved
between them: ``benchmarks/sdf_coarse_vs_fine.py`` measures it at 10^6 mesher-like
points (1.8 % of the local radius at most on the real cases' fine surfaces, the rare
points between check points near the centreline; the median is 0).

Because every answer is the closest point of *some* triangle, projected points lie on
the surface exactly; only the choice of triangle is approximate, and a wrong choice can
only make the distance longer.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import bvh as _bvh
from .bvh import _nb, _point_triangle, _sign_one
from .sdf import SignedDistance, SurfaceQueries

# offsets in a cell, in quarter cells: the 27 lattice points (0, 1/2, 1) and 8 checks (1/4, 3/4)
_OFF27 = np.stack(np.meshgrid([0, 2, 4], [0, 2, 4], [0, 2, 4], indexing="ij"), axis=-1).reshape(-1, 3)
_OFF8 = np.stack(np.meshgrid([1, 3], [1, 3], [1, 3], indexing="ij"), axis=-1).reshape(-1, 3)
# extra checks of cells near the medial axis: the quarter-lattice points inside the cell
# that are neither lattice points nor _OFF8 (sub-cell face centres and edge midpoints)
_Q = np.stack(np.meshgrid(*[np.arange(1, 4)] * 3, indexing="ij"), axis=-1).reshape(-1, 3)
_OFF_MEDIAL = _Q[(_Q % 2).any(axis=1) & ~(_Q % 2).all(axis=1)]
_CHILD = np.stack(np.meshgrid([0, 1], [0, 1], [0, 1], indexing="ij"), axis=-1).reshape(-1, 3)  # octant k = 4x + 2y + z
_MAX_DEPTH = 18
_CORNER = np.array([0, 1, 3, 4, 9, 10, 12, 13], np.int64)  # lattice index steps to a sub-cell's 8 corners
# near the medial axis: closest points of neighbouring lattice points this many spacings apart
_MEDIAL_SPREAD = 3.0
# a crease: lattice faces turned this far from their mean normal, in a cell this close to
# the wall (local radii)
_CREASE_COS = np.cos(np.radians(40.0))
_CREASE_NEAR = 0.25


@dataclass(frozen=True)
class _Octree:
    """The octree's arrays: root cube ``root_lo + [0, root_size]^3``, ``depth`` levels below
    it; per node its first child (-1: a leaf; children of one parent are consecutive, in
    octant order) and its row of ``cand`` (-1: no candidates, the exact query answers);
    ``cand`` holds the closest faces of each leaf's 3x3x3 lattice."""

    root_lo: np.ndarray
    root_size: float
    depth: int
    child: np.ndarray
    slot: np.ndarray
    cand: np.ndarray


@dataclass
class OctreeStats:
    """What building the octree found: leaves with candidates, leaves that keep the exact
    query, cells checked near the medial axis, cells left exact at creases, distinct
    candidate triangles per leaf, per level (leaves, exact leaves, cells split), build time."""

    n_leaves: int
    n_exact_leaves: int
    n_medial_checked: int
    n_creased: int
    candidates_mean: float
    level_counts: list
    build_s: float = 0.0


@dataclass(frozen=True)
class _TriangleArrays:
    """Per-face triangle data in face order (the BVH's arrays are in its leaf order) and
    the surface adjacency the query kernels walk over (:func:`surface_adjacency`)."""

    a: np.ndarray
    ab: np.ndarray
    ac: np.ndarray
    faces: np.ndarray
    edge_nb: np.ndarray
    vptr: np.ndarray
    vfaces: np.ndarray

    @classmethod
    def of(cls, sdf) -> "_TriangleArrays":
        """The arrays of a :class:`~vmesh.geometry.sdf.SignedDistance`'s surface."""
        tri = sdf.vertices[sdf.faces]
        a = np.ascontiguousarray(tri[:, 0])
        ab = np.ascontiguousarray(tri[:, 1] - tri[:, 0])
        ac = np.ascontiguousarray(tri[:, 2] - tri[:, 0])
        return cls(a, ab, ac, np.ascontiguousarray(sdf.faces), *surface_adjacency(sdf.faces, len(sdf.vertices)))

    def kernel_args(self) -> tuple:
        """The arrays in the order the query kernels take them."""
        return self.a, self.ab, self.ac, self.faces, self.edge_nb, self.vptr, self.vfaces


class OctreeSignedDistance(SurfaceQueries):
    """Signed distance of a :class:`~vmesh.geometry.sdf.SignedDistance` answered from an
    octree of verified candidate triangles (module docstring), with the exact BVH query
    where the octree has no answer.

    Parameters
    ----------
    sdf : SignedDistance
        The exact signed distance of the surface (coarse or fine).
    max_error : float
        Largest distance error of a leaf at its check points, in local radii.
    max_cell, min_cell : float
        Largest and smallest leaf edge, in local radii.
    margin : float
        How far outside the vessel the octree reaches, in local radii (beyond it the
        exact query answers).
    face_radius : (m,) array, optional
        Local radius per face (default: :func:`~vmesh.geometry.sdf.local_radius` at the
        face centroids, caps, where ``wall_faces`` leaves them out, from their nearest wall
        faces).
    wall_faces : (m,) bool array, optional

    Attributes
    ----------
    Those of ``sdf`` (``vertices``, ``faces``, ``n_faces``, ``bounds``, ``diagonal``,
    ``sign_method``, ...), plus ``exact`` (the wrapped SDF), ``tree`` (the octree's
    arrays) and ``stats`` (:class:`OctreeStats`: ``n_leaves``, leaves with candidates;
    ``n_exact_leaves``, leaves that keep the BVH query; ``n_medial_checked`` and
    ``n_creased``, cells checked near the medial axis, cells left exact at creases;
    ``candidates_mean``, distinct triangles per leaf; ``level_counts``, per octree level:
    leaves, exact leaves, cells split; ``build_s``). ``n_leaves``, ``n_exact_leaves`` and
    ``candidates_mean`` are properties too.

    The octree pays off for large batches near the wall (projections, distance fields on
    grids): about 5-7x the BVH's points per second on the real cases. Line casts
    (:meth:`intersect_lines`) and winding numbers go to the exact surface.

    Examples
    --------
    >>> fast = OctreeSignedDistance(SignedDistance.from_surface(coarse))   # doctest: +SKIP
    >>> closest, d, face = fast.project(points)                            # doctest: +SKIP
    """

    def __init__(self, sdf, max_error: float = 0.002, max_cell: float = 0.5, min_cell: float = 1 / 32, margin: float = 0.5, face_radius=None, wall_faces=None):
        import time

        t0 = time.perf_counter()
        if not isinstance(sdf, SignedDistance):
            raise TypeError(f"OctreeSignedDistance wraps a SignedDistance, got {type(sdf).__name__}")
        if not 0 < max_error < 1:
            raise ValueError(f"max_error must lie in (0, 1), got {max_error}")
        if not 0 < min_cell <= max_cell:
            raise ValueError(f"need 0 < min_cell <= max_cell, got {min_cell}, {max_cell}")
        self.exact = sdf
        self.max_error, self.max_cell, self.min_cell = float(max_error), float(max_cell), float(min_cell)
        self.face_radius = _face_radius(sdf, wall_faces) if face_radius is None else np.asarray(face_radius, np.float64).reshape(-1)
        if len(self.face_radius) != sdf.n_faces or not np.all(self.face_radius > 0):
            raise ValueError(f"face_radius needs one positive radius per face ({sdf.n_faces})")
        self._mesh = _TriangleArrays.of(sdf)
        r_min, r_max = float(self.face_radius.min()), float(self.face_radius.max())
        lo, hi = sdf.bounds
        centre = 0.5 * (lo + hi)
        root_size = float(np.max(hi - lo) + 2 * margin * r_max)
        depth = int(min(_MAX_DEPTH, max(1, np.ceil(np.log2(root_size / (min_cell * r_min))))))
        self.margin = float(margin)
        self.tree, self.stats = self._build(centre - 0.5 * root_size, root_size, depth)
        self.stats.build_s = time.perf_counter() - t0

    # the exact SDF's surface and attributes (the SurfaceQuery interface and the report's)
    @property
    def vertices(self):
        """Vertices of the surface (of the exact distance)."""
        return self.exact.vertices

    @property
    def faces(self):
        """Triangles of the (outward-oriented) surface (of the exact distance)."""
        return self.exact.faces

    @property
    def bounds(self):
        """Bounding box ``(lo, hi)`` (of the exact distance)."""
        return self.exact.bounds

    @property
    def diagonal(self):
        """Bounding-box diagonal (of the exact distance)."""
        return self.exact.diagonal

    @property
    def sign_method(self):
        """The sign method in use (of the exact distance)."""
        return self.exact.sign_method

    @property
    def name(self):
        """Where the surface came from (of the exact distance)."""
        return self.exact.name

    @property
    def flipped(self):
        """True when the input faces were flipped outward (of the exact distance)."""
        return self.exact.flipped

    @property
    def closed(self):
        """True when the surface has no boundary edge (of the exact distance)."""
        return self.exact.closed

    @property
    def face_normals(self):
        """Unit face normals (of the exact distance)."""
        return self.exact.face_normals

    @property
    def vertex_normals(self):
        """Angle-weighted vertex pseudonormals (of the exact distance)."""
        return self.exact.vertex_normals

    @property
    def n_suspect_faces(self):
        """Faces whose pseudonormal sign is not trusted (of the exact distance)."""
        return self.exact.n_suspect_faces

    @property
    def degenerate_faces(self):
        """Boolean mask of zero-area faces (of the exact distance)."""
        return self.exact.degenerate_faces

    @property
    def n_faces(self) -> int:
        return self.exact.n_faces

    @property
    def fine(self) -> "OctreeSignedDistance":
        """This distance: it answers on its own surface without a coarse search in front
        (:class:`~vmesh.geometry.surface_query.SurfaceQuery`); ``exact`` is its BVH fallback."""
        return self

    @property
    def coarse(self) -> "OctreeSignedDistance":
        """This distance (:class:`~vmesh.geometry.surface_query.SurfaceQuery`)."""
        return self

    @property
    def n_leaves(self) -> int:
        """Leaves with candidate triangles (``stats.n_leaves``)."""
        return self.stats.n_leaves

    @property
    def n_exact_leaves(self) -> int:
        """Leaves that keep the exact BVH query (``stats.n_exact_leaves``)."""
        return self.stats.n_exact_leaves

    @property
    def candidates_mean(self) -> float:
        """Distinct candidate triangles per leaf (``stats.candidates_mean``)."""
        return self.stats.candidates_mean

    # duplicates: properties and __repr__ shaped like SignedDistance's: each names its own statistics
    def __repr__(self) -> str:
        return f"OctreeSignedDistance({self.n_faces} triangles, {self.n_leaves} leaves, {self.candidates_mean:.1f} candidates per leaf, max_error {self.max_error:g} R)"

    # -- construction --------------------------------------------------------
    def _build(self, root_lo: np.ndarray, root_size: float, depth: int):
        """The octree over the cube ``root_lo + [0, root_size]^3`` and its statistics."""
        sdf = self.exact
        unit = root_size / 2.0 ** (depth + 2)  # lattice step: a quarter of the finest cell
        child, slot, cand = [np.full(1, -1, np.int64)], [np.full(1, -1, np.int64)], []
        n_nodes, n_slots, n_medial, n_creased = 1, 0, 0, 0
        ijk = np.zeros((1, 3), np.int64)  # cells of the current level, in cell units
        level_counts = []
        for level in range(depth + 1):
            half = 2 ** (depth + 1 - level)  # half a cell at this level, in lattice units
            size = 2 * half * unit
            base = ijk * (2 * half)
            n = len(ijk)
            # the centre alone tells cells far outside (exact leaves) and cells larger than
            # max_cell (split) apart from those worth the 3x3x3 lattice
            _, d_c, f_c = sdf.project(root_lo + (base + half) * unit)
            r_est = self.face_radius[f_c]
            far = d_c < -(self.margin * r_est + 0.87 * size)
            look = np.flatnonzero(~far & (size <= self.max_cell * r_est))
            ok = np.zeros(n, bool)
            crease_exact = np.zeros(n, bool)
            if len(look):
                lattice = np.concatenate([base[look, None, :] + _OFF27[None] * (half // 2), base[look, None, :] + _OFF8[None] * (half // 2)], axis=1)
                uniq, inverse = np.unique(_pack(lattice.reshape(-1, 3)), return_inverse=True)
                c_u, d_u, f_u = sdf.project(root_lo + _unpack(uniq) * unit)
                inverse = inverse.reshape(len(look), 35)
                d, f = d_u[inverse], f_u[inverse]
                r_cell = self.face_radius[f[:, :27]].min(axis=1)
                r_est[look] = r_cell
                test = np.flatnonzero(size <= self.max_cell * r_cell)
                # Near the medial axis the closest points of neighbouring lattice points lie
                # far apart and the answer changes fast: such cells are checked at 18 more
                # points inside the sub-cells. Cells at the wall whose faces turn (cap rims,
                # the crotch of a junction) keep the exact query: a point there can have two
                # local minima, one on each side of the crease, that the walk cannot cross.
                c = c_u[inverse[test, :27]].reshape(-1, 3, 3, 3, 3)
                spread = np.zeros(len(test))
                for ax in range(3 if len(test) else 0):
                    jump = np.take(c, [0, 1], axis=ax + 1) - np.take(c, [1, 2], axis=ax + 1)
                    spread = np.maximum(spread, np.linalg.norm(jump, axis=-1).reshape(len(test), 18).max(axis=1))
                nrm = sdf.face_normals[f[test, :27]]
                mean = nrm.sum(axis=1)
                mean /= np.maximum(np.linalg.norm(mean, axis=1), 1e-300)[:, None]
                creased = (np.einsum("ijk,ik->ij", nrm, mean).min(axis=1) < _CREASE_COS) & (np.abs(d[test, :27]).min(axis=1) < _CREASE_NEAR * r_cell[test])
                passed = self._verify(root_lo, base[look[test]], _OFF8, half // 2, f[test, :27], d[test, 27:].ravel(), r_cell[test], unit) & ~creased
                medial = np.flatnonzero(passed & (spread > _MEDIAL_SPREAD * (size / 2)))
                if len(medial):
                    cells = test[medial]
                    extra = base[look[cells], None, :] + _OFF_MEDIAL[None] * (half // 2)
                    ukeys, uinv = np.unique(_pack(extra.reshape(-1, 3)), return_inverse=True)
                    _, d_extra, _ = sdf.project(root_lo + _unpack(ukeys) * unit)
                    passed[medial] = self._verify(root_lo, base[look[cells]], _OFF_MEDIAL, half // 2, f[cells, :27], d_extra[uinv.ravel()], r_cell[cells], unit)
                    n_medial += len(medial)
                keep = test[passed]
                ok[look[keep]] = True
                crease_exact[look[test[creased]]] = True
                n_creased += int(creased.sum())
                # leaves keep the closest faces of their 3x3x3 lattice
                if len(keep):
                    cand.append(f[keep, :27].astype(np.int32))
                    slot[level][look[keep]] = n_slots + np.arange(len(keep))
                    n_slots += len(keep)
            exact_leaf = ~ok & (far | crease_exact | (level == depth) | (size / 2 < self.min_cell * r_est))
            split = np.flatnonzero(~ok & ~exact_leaf)
            level_counts.append((int(ok.sum()), int(exact_leaf.sum()), len(split)))
            if not len(split):
                break
            # children of one parent are numbered consecutively, in octant order
            child[level][split] = n_nodes + 8 * np.arange(len(split))
            n_nodes += 8 * len(split)
            ijk = (2 * ijk[split][:, None, :] + _CHILD[None]).reshape(-1, 3)
            child.append(np.full(len(ijk), -1, np.int64))
            slot.append(np.full(len(ijk), -1, np.int64))
        tree = _Octree(
            root_lo,
            root_size,
            depth,
            np.ascontiguousarray(np.concatenate(child)),
            np.ascontiguousarray(np.concatenate(slot)),
            np.ascontiguousarray(np.concatenate(cand)) if cand else np.zeros((0, 27), np.int32),
        )
        sample = tree.cand[:: max(1, n_slots // 2000)]
        mean = float(np.mean([len(np.unique(r)) for r in sample])) if n_slots else 0.0
        return tree, OctreeStats(n_slots, sum(c[1] for c in level_counts), n_medial, n_creased, mean, level_counts)

    def _verify(self, root_lo, base, offsets, quarter, lattice_faces, exact, r_cell, unit) -> np.ndarray:
        """True per cell where the query's answer at every check point (``offsets`` (c, 3),
        in quarter cells ``quarter`` lattice units, from each cell's corner ``base`` (k, 3))
        is within ``max_error`` radii of the ``exact`` signed distance (k c,); lattice
        unit ``unit``, origin ``root_lo``."""
        k, c = len(base), len(offsets)
        pts = np.ascontiguousarray((root_lo + (base[:, None, :] + offsets[None] * quarter) * unit).reshape(-1, 3))
        cell = np.repeat(np.arange(k), c)
        sub = np.ascontiguousarray(np.tile((offsets >= 2).astype(np.int64), (k, 1)))
        sq, face, closest, feature = _lattice_answers(pts, cell, sub, np.ascontiguousarray(lattice_faces, dtype=np.int32), *self._mesh.kernel_args())
        signed = self.exact.signs(pts, sq, face, closest, feature)[0]
        err = np.abs(signed - exact).reshape(k, c)
        return np.all(err <= self.max_error * r_cell[:, None], axis=1)

    # -- queries (project, distance, gradient, ... from SurfaceQueries) --------
    def winding_number(self, points) -> np.ndarray:
        """Winding number of the surface (:meth:`SignedDistance.winding_number`)."""
        return self.exact.winding_number(points)

    def ray_winding_number(self, points) -> np.ndarray:
        """Winding number of a closed oriented surface from rays (:meth:`SignedDistance.ray_winding_number`)."""
        return self.exact.ray_winding_number(points)

    def intersect_lines(self, points, directions, reach, side=None):
        """Exact line casts on the surface (:meth:`SignedDistance.intersect_lines`)."""
        return self.exact.intersect_lines(points, directions, reach, side)

    def pseudonormals(self, closest, face):
        """Outward pseudonormals at closest points (:meth:`SignedDistance.pseudonormals`)."""
        return self.exact.pseudonormals(closest, face)

    def _closest(self, p):
        sq, face, closest, _ = self._closest_feature(p)
        return sq, face, closest

    def _outside(self, p, closest, face, normal):
        return self.exact._outside(p, closest, face, normal)

    def _closest_feature(self, p: np.ndarray):
        """``(sq, face, closest, feature)`` like :meth:`TriangleBVH.closest`, input order."""
        ps, order = _morton_sorted(p)
        sq, face, closest, feature = self._closest_sorted(ps)[:4]
        if order is None:
            return sq, face, closest, feature
        return tuple(_unsort(order, sq, face, closest, feature))

    def _closest_sorted(self, p: np.ndarray):
        """Closest points, signed distances and normals of (Morton-sorted) points:
        ``(sq, face, closest, feature, signed, normal)``."""
        n = len(p)
        sq, face, closest, feature = np.empty(n), np.empty(n, np.int64), np.empty((n, 3)), np.empty(n, np.int8)
        signed, normal, unsure = np.empty(n), np.empty((n, 3)), np.zeros(n, np.bool_)
        if n == 0:
            return sq, face, closest, feature, signed, normal
        ex = self.exact
        kernel = _octree_kernel if n >= _bvh.PARALLEL_MIN else _octree_serial
        tree = self.tree
        kernel(p, tree.root_lo, tree.root_size, tree.child, tree.slot, tree.cand, *self._mesh.kernel_args(), sq, face, closest, feature,
               *ex.normals.kernel_arrays(), signed, normal, unsure)
        miss = np.flatnonzero(face < 0)
        if len(miss):  # outside the octree or in a leaf that keeps the exact query
            q = np.ascontiguousarray(p[miss])
            r = ex._tree.closest(q)
            sq[miss], face[miss], closest[miss], feature[miss] = r
            signed[miss], normal[miss], unsure[miss] = _bvh.pseudonormal_signs(q, r[0], r[2], r[1], r[3], ex.faces, *ex.normals.kernel_arrays())
        ex._resolve_unsure(p, signed, unsure)
        return sq, face, closest, feature, signed, normal

    def _query(self, p: np.ndarray):
        from .sdf import _non_finite, _query_finite

        bad = _non_finite(p)
        if bad is not None:
            return _query_finite(self._query, p, bad)
        ps, order = _morton_sorted(p)
        _, face, closest, _, signed, normal = self._closest_sorted(ps)
        if order is None:
            return closest, signed, face, normal
        return tuple(_unsort(order, closest, signed, face, normal))


def _morton_sorted(p: np.ndarray):
    """``(points in Morton order, order)``, or ``(p, None)`` for batches run serially.

    Consecutive queries then share leaves and triangles. The points are gathered into a
    contiguous copy first (parallel): the query kernel reading and writing through the
    order instead spent 40 % of its time waiting for memory."""
    if len(p) < _bvh.PARALLEL_MIN:
        return p, None
    order = _bvh.morton_order(p, bits=10)
    out = np.empty_like(p)
    _gather_rows(p, order, out)
    return out, order


@_nb.njit(parallel=True, cache=True)
def _gather_rows(p, order, out):
    for k in _nb.prange(order.shape[0]):
        i = order[k]
        out[k, 0], out[k, 1], out[k, 2] = p[i, 0], p[i, 1], p[i, 2]


def _unsort(order, *arrays):
    """Arrays of Morton-sorted results back in input order (``out[order] = a``, parallel)."""
    outs = []
    for a in arrays:
        out = np.empty_like(a)
        (_scatter_3 if a.ndim == 2 else _scatter_1)(order, a, out)
        outs.append(out)
    return outs


@_nb.njit(parallel=True, cache=True)
def _scatter_1(order, a, out):
    for k in _nb.prange(order.shape[0]):
        out[order[k]] = a[k]


@_nb.njit(parallel=True, cache=True)
def _scatter_3(order, a, out):
    for k in _nb.prange(order.shape[0]):
        i = order[k]
        out[i, 0], out[i, 1], out[i, 2] = a[k, 0], a[k, 1], a[k, 2]


def _face_radius(sdf, wall_faces=None) -> np.ndarray:
    """Local radius at every face centroid; cap faces take their nearest wall face's."""
    from scipy.spatial import cKDTree

    from .sdf import local_radius

    centroids = sdf.vertices[sdf.faces].mean(axis=1)
    wall = np.ones(sdf.n_faces, bool) if wall_faces is None else np.asarray(wall_faces, bool)
    radius = np.empty(sdf.n_faces)
    radius[wall] = local_radius(sdf, centroids[wall], sdf.face_normals[wall], wall_faces)
    if (~wall).any():
        _, near = cKDTree(centroids[wall]).query(centroids[~wall], workers=-1)
        radius[~wall] = radius[wall][near]
    return radius


def _pack(ijk: np.ndarray) -> np.ndarray:
    return (ijk[:, 0] << 42) | (ijk[:, 1] << 21) | ijk[:, 2]


def _unpack(keys: np.ndarray) -> np.ndarray:
    mask = (1 << 21) - 1
    return np.stack([keys >> 42, (keys >> 21) & mask, keys & mask], axis=1).astype(np.float64)


def surface_adjacency(faces: np.ndarray, n_vertices: int):
    """Neighbour across each local edge ``(m, 3)`` (-1 on open and non-manifold edges) and
    the faces around each vertex (CSR: ``ptr (n+1,)``, ``faces``)."""
    from .sdf import edge_table

    f = np.asarray(faces, np.int64)
    m = len(f)
    edge_of_half, faces_per_edge, _ = edge_table(f)
    order = np.argsort(edge_of_half, kind="stable")
    e_sorted = edge_of_half[order]
    pair = (e_sorted[1:] == e_sorted[:-1]) & (faces_per_edge[e_sorted[1:]] == 2)
    nb = np.full(3 * m, -1, np.int64)
    a, b = order[:-1][pair], order[1:][pair]
    nb[a], nb[b] = b // 3, a // 3
    vertex = f.ravel()
    vorder = np.argsort(vertex, kind="stable")
    ptr = np.zeros(n_vertices + 1, np.int64)
    np.cumsum(np.bincount(vertex, minlength=n_vertices), out=ptr[1:])
    return np.ascontiguousarray(nb.reshape(m, 3)), ptr, np.ascontiguousarray(vorder // 3)


@_nb.njit(inline="always", error_model="numpy")
def _walk(px, py, pz, best, bx, by, bz, bf, bt, A, AB, AC, faces, edge_nb, vptr, vfaces):
    """Greedy descent over the surface from triangle ``bt``: while the closest point lies
    on an edge or a corner, try the triangles across it. It stops at a local minimum of
    the distance, which near the wall is the global one: there a candidate list can miss
    the triangle right below the point."""
    for _ in range(256):
        if bt < 0 or bf == 0:
            break
        nbest, nx, ny, nz, nf, nt = best, bx, by, bz, bf, bt
        if bf < 4:
            t = edge_nb[bt, bf - 1]
            if t >= 0:
                d, cx, cy, cz, ft = _point_triangle(px, py, pz, A, AB, AC, t)
                if d < nbest:
                    nbest, nx, ny, nz, nf, nt = d, cx, cy, cz, ft, t
        else:
            v = faces[bt, bf - 4]
            for q in range(vptr[v], vptr[v + 1]):
                t = vfaces[q]
                if t == bt:
                    continue
                d, cx, cy, cz, ft = _point_triangle(px, py, pz, A, AB, AC, t)
                if d < nbest:
                    nbest, nx, ny, nz, nf, nt = d, cx, cy, cz, ft, t
        if nt == bt:
            break
        best, bx, by, bz, bf, bt = nbest, nx, ny, nz, nf, nt
    return best, bx, by, bz, bf, bt


@_nb.njit(inline="always", error_model="numpy")
def _subcell_answer(px, py, pz, cand, s, sx, sy, sz, A, AB, AC, faces, edge_nb, vptr, vfaces):
    """Closest point among the closest faces of the 8 lattice points around sub-cell
    ``(sx, sy, sz)`` of leaf ``s``, then the greedy walk."""
    best, bx, by, bz, bf, bt = np.inf, 0.0, 0.0, 0.0, 0, -1
    base = sx * 9 + sy * 3 + sz
    for k in range(8):
        t = cand[s, base + _CORNER[k]]
        seen = False
        for q in range(k):  # corners often share a face: test each once
            if cand[s, base + _CORNER[q]] == t:
                seen = True
                break
        if seen:
            continue
        d, cx, cy, cz, ft = _point_triangle(px, py, pz, A, AB, AC, t)
        if d < best:
            best, bx, by, bz, bf, bt = d, cx, cy, cz, ft, t
    return _walk(px, py, pz, best, bx, by, bz, bf, bt, A, AB, AC, faces, edge_nb, vptr, vfaces)


@_nb.njit(parallel=True, cache=True, error_model="numpy")
def _lattice_answers(points, cell, sub, lattice_faces, A, AB, AC, faces, edge_nb, vptr, vfaces):
    """The query's answer at check points of cells (point ``i`` lies in sub-cell
    ``sub[i]`` of cell ``cell[i]`` with lattice faces ``lattice_faces[cell[i]]``)."""
    n = points.shape[0]
    sq, face = np.empty(n), np.empty(n, np.int64)
    closest, feature = np.empty((n, 3)), np.empty(n, np.int8)
    for i in _nb.prange(n):
        best, bx, by, bz, bf, bt = _subcell_answer(points[i, 0], points[i, 1], points[i, 2], lattice_faces, cell[i], sub[i, 0], sub[i, 1], sub[i, 2], A, AB, AC, faces, edge_nb, vptr, vfaces)
        sq[i], face[i], feature[i] = best, bt, bf
        closest[i, 0], closest[i, 1], closest[i, 2] = bx, by, bz
    return sq, face, closest, feature


@_nb.njit(inline="always", error_model="numpy")
def _octree_one(i, points, root_lo, root_size, child, slot, cand, A, AB, AC, faces, edge_nb, vptr, vfaces, out_sq, out_face, out_c, out_feat, face_normals, edge_normals, vertex_normals, degenerate, suspect_vertex, out_signed, out_normal, out_unsure):
    px, py, pz = points[i, 0], points[i, 1], points[i, 2]
    x = (px - root_lo[0]) / root_size
    y = (py - root_lo[1]) / root_size
    z = (pz - root_lo[2]) / root_size
    out_face[i] = -1
    if not (0.0 <= x < 1.0 and 0.0 <= y < 1.0 and 0.0 <= z < 1.0):
        return
    node = 0
    while child[node] >= 0:
        # doubling and dropping the integer part is exact in binary floating point
        x += x
        y += y
        z += z
        ix = 1 if x >= 1.0 else 0
        iy = 1 if y >= 1.0 else 0
        iz = 1 if z >= 1.0 else 0
        x -= ix
        y -= iy
        z -= iz
        node = child[node] + 4 * ix + 2 * iy + iz
    s = slot[node]
    if s < 0:
        return
    sx = 1 if x + x >= 1.0 else 0  # x, y, z: position inside the leaf, in [0, 1)
    sy = 1 if y + y >= 1.0 else 0
    sz = 1 if z + z >= 1.0 else 0
    best, cx_, cy_, cz_, bf, bt = _subcell_answer(px, py, pz, cand, s, sx, sy, sz, A, AB, AC, faces, edge_nb, vptr, vfaces)
    out_sq[i], out_face[i], out_feat[i] = best, bt, bf
    out_c[i, 0], out_c[i, 1], out_c[i, 2] = cx_, cy_, cz_
    # the sign right away, exactly as the BVH query's results get it (bvh.pseudonormal_signs)
    _sign_one(i, points, out_sq, out_c, out_face, out_feat, faces, face_normals, edge_normals, vertex_normals, degenerate, suspect_vertex, out_signed, out_normal, out_unsure)


@_nb.njit(parallel=True, cache=True, error_model="numpy")
def _octree_kernel(points, root_lo, root_size, child, slot, cand, A, AB, AC, faces, edge_nb, vptr, vfaces, out_sq, out_face, out_c, out_feat, face_normals, edge_normals, vertex_normals, degenerate, suspect_vertex, out_signed, out_normal, out_unsure):
    for i in _nb.prange(points.shape[0]):
        _octree_one(i, points, root_lo, root_size, child, slot, cand, A, AB, AC, faces, edge_nb, vptr, vfaces, out_sq, out_face, out_c, out_feat, face_normals, edge_normals, vertex_normals, degenerate, suspect_vertex, out_signed, out_normal, out_unsure)


@_nb.njit(cache=True, error_model="numpy")
def _octree_serial(points, root_lo, root_size, child, slot, cand, A, AB, AC, faces, edge_nb, vptr, vfaces, out_sq, out_face, out_c, out_feat, face_normals, edge_normals, vertex_normals, degenerate, suspect_vertex, out_signed, out_normal, out_unsure):
    for i in range(points.shape[0]):
        _octree_one(i, points, root_lo, root_size, child, slot, cand, A, AB, AC, faces, edge_nb, vptr, vfaces, out_sq, out_face, out_c, out_feat, face_normals, edge_normals, vertex_normals, degenerate, suspect_vertex, out_signed, out_normal, out_unsure)
