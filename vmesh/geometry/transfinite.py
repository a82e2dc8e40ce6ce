"""Transfinite meshing of a block structure into one conforming hexahedral mesh.

Every block is filled with a structured lattice of nodes:

1. **Edges.** Block edges are grouped into classes that must carry the same number of
   elements (the four parallel edges of every block, transitively); each class gets
   the largest count its members ask for. Nodes are distributed along each edge
   (uniform, or geometric towards the wall in the boundary layer), mesh order ``p``
   adds Gauss-Lobatto or equispaced nodes inside each element, and edges on the wall
   are moved onto the surface (along the wall normal: an exact line cast on the surface's
   BVH, :meth:`~vmesh.geometry.sdf.SignedDistance.intersect_lines`), projected and
   re-spaced by arc length.
2. **Faces.** Coons patches from the four edges of each block face; faces on the wall
   are moved onto it along their normals and projected again.
3. **Blocks.** Transfinite interpolation from the six faces fills each block.

Nodes on shared corners, edges and faces are numbered once through the block
topology (a canonical orientation per edge and face), so the mesh is conforming by
construction, not by merging nearby points. All work is vectorised over groups of
edges, faces and blocks of the same size; the maps, the boundary-layer re-spacing and the
connectivity are compiled kernels (numba) running in parallel over lattices.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba as nb
import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from ..blocks import (
    AXIS_ALONG,
    AXIS_AROUND,
    AXIS_CORE,
    AXIS_LAYER,
    AXIS_RING,
    FACE_INTERIOR,
    FACE_WALL,
    HEX_CORNERS,
    HEX_EDGES,
    BlockStructure,
)
from . import bvh  # noqa: F401  (chooses numba's threading layer before the first parallel kernel)

# local faces in HEX_FACES order: (fixed axis, fixed value); free axes are the other two, ascending
FACE_AXES = [(0, 0), (0, 1), (1, 0), (1, 1), (2, 0), (2, 1)]
#: wall edge nodes follow their ray to the wall only when it is at most this many times
#: longer than their distance to the wall (otherwise the closest point is used)
RAY_TRUST = 1.5
#: rays search the wall up to this many times the node's distance to it (and a radius at most):
#: a wall much farther along the normal than the closest wall point lies beyond a concavity
RAY_SEARCH = 32.0
#: wall-face nodes whose ray finds no wall within a radius are projected only when they are
#: closer to the wall than this fraction of the radius (otherwise they span an opening)
OPENING_DEPTH = 0.25
_CORNER_INDEX = {tuple(c): n for n, c in enumerate(HEX_CORNERS.tolist())}


@dataclass
class Refinement:
    """Element counts and grading.

    Attributes
    ----------
    around, core, ring, layer : int
        Elements per block edge around the circumference, across the core, across
        the ring and across the boundary layer.
    element_length : float
        Target element length along the skeleton, relative to the local radius.
    first_layer : float or None
        First boundary-layer element thickness relative to the local radius
        (``None``: uniform spacing), or absolute when ``first_layer_absolute``.
    growth : float or None
        Alternatively, the ratio between consecutive boundary-layer elements.
    order : int
        Mesh order p (1 = linear hexahedra).
    nodes : str
        ``"gauss_lobatto"`` or ``"equispaced"`` positions of high-order nodes.
    """

    around: int = 2
    core: int = 2
    ring: int = 2
    layer: int = 2
    element_length: float = 0.6
    first_layer: float | None = None
    growth: float | None = None
    order: int = 1
    nodes: str = "gauss_lobatto"
    first_layer_absolute: bool = False

    def first_height(self, radius):
        """First boundary-layer element thickness where the local radius is ``radius``."""
        radius = np.asarray(radius, float)
        return np.full(radius.shape, self.first_layer) if self.first_layer_absolute else self.first_layer * radius


# ---------------------------------------------------------------------------
# 1-D node distributions
# ---------------------------------------------------------------------------
def gauss_lobatto_points(p: int) -> np.ndarray:
    """The ``p + 1`` Gauss-Lobatto-Legendre points mapped to [0, 1]."""
    if p <= 1:
        return np.array([0.0, 1.0])
    from numpy.polynomial import legendre

    inner = legendre.Legendre.basis(p).deriv().roots()
    return (np.concatenate([[-1.0], np.sort(inner.real), [1.0]]) + 1.0) / 2.0


def reference_points(p: int, kind: str = "gauss_lobatto") -> np.ndarray:
    """Positions of the ``p + 1`` nodes of a 1-D element of order p on [0, 1]."""
    return gauss_lobatto_points(p) if kind == "gauss_lobatto" else np.linspace(0.0, 1.0, p + 1)


def geometric_ratio(first: np.ndarray, length: np.ndarray, n: int) -> np.ndarray:
    """Ratio q with ``first * (q**n - 1) / (q - 1) = length`` for arrays of edges.

    Returns 1 where uniform spacing already gives elements thinner than ``first``.
    Solved per edge by Newton steps on ``1 + q + ... + q**(n-1)`` (see :func:`_ratio`).
    """
    first, length = np.broadcast_arrays(np.asarray(first, float), np.asarray(length, float))
    out = _ratio_kernel(np.ascontiguousarray(first).ravel(), np.ascontiguousarray(length).ravel(), int(n))
    return out.reshape(first.shape)


def element_boundaries(n: int, ratio: np.ndarray | float = 1.0) -> np.ndarray:
    """(m, n + 1) normalised element boundaries; element sizes grow by ``ratio`` from t = 0."""
    ratio = np.atleast_1d(np.asarray(ratio, float))
    sizes = ratio[:, None] ** np.arange(n)[None, :]
    t = np.concatenate([np.zeros((len(ratio), 1)), np.cumsum(sizes, axis=1)], axis=1)
    return t / t[:, -1:]


def with_order(t: np.ndarray, p: int, kind: str) -> np.ndarray:
    """Insert the high-order nodes of every element: (m, n + 1) -> (m, n p + 1)."""
    if p == 1:
        return t
    ref = reference_points(p, kind)[:-1]
    a, b = t[:, :-1], t[:, 1:]
    inner = a[:, :, None] + (b - a)[:, :, None] * ref[None, None, :]
    return np.concatenate([inner.reshape(len(t), -1), t[:, -1:]], axis=1)


# ---------------------------------------------------------------------------
# block topology: unique edges, edge classes, unique faces
# ---------------------------------------------------------------------------
@dataclass
class Topology:
    edges: np.ndarray  # (E, 2) global vertex ids, ascending
    block_edge: np.ndarray  # (nb, 12) unique edge id of each local edge
    edge_class: np.ndarray  # (E,) class id
    faces: np.ndarray  # (F, 4) canonical corners: origin, s-neighbour, t-neighbour, far corner
    block_face: np.ndarray  # (nb, 6) unique face id of each local face
    face_boundary: np.ndarray  # (F,) -1 interior, 0 wall, k open end


def block_topology(blocks: BlockStructure) -> Topology:
    """Unique edges and faces of a block structure with canonical orientations."""
    H = blocks.hexes
    nb = len(H)
    pairs = H[:, HEX_EDGES]  # (nb, 12, 2)
    key = np.sort(pairs, axis=2).reshape(-1, 2)
    # unique rows through one integer key per row (lexicographic like np.unique(axis=0),
    # which sorts structured rows an order of magnitude slower)
    nv = int(H.max()) + 1 if nb else 1
    ukey, inv = np.unique(key[:, 0] * nv + key[:, 1], return_inverse=True)
    edges = np.stack([ukey // nv, ukey % nv], axis=1)
    block_edge = inv.reshape(nb, 12)
    # parallel edges of a block share a class: connect edge 4a to 4a+1..4a+3
    src = block_edge[:, [0, 0, 0, 4, 4, 4, 8, 8, 8]].ravel()
    dst = block_edge[:, [1, 2, 3, 5, 6, 7, 9, 10, 11]].ravel()
    E = len(edges)
    g = sp.coo_matrix((np.ones(len(src)), (src, dst)), shape=(E, E))
    _, edge_class = connected_components(g, directed=False)

    grids = np.stack([_face_corner_grid(f) for f in range(6)])  # (6, 2, 2) local corners
    corner_ids = H[:, grids.reshape(6, 4)]  # (nb, 6, 4) as (pp, qq) = (0,0),(0,1),(1,0),(1,1)
    fkey = np.sort(corner_ids, axis=2).reshape(-1, 4)
    first, finv = _unique_rows(fkey[:, 0] * nv + fkey[:, 1], fkey[:, 2] * nv + fkey[:, 3])
    block_face = finv.reshape(nb, 6)
    g4 = corner_ids.reshape(-1, 4)[first]  # a representative corner grid per unique face
    faces = canonical_faces(g4)
    fb = np.full(len(first), FACE_INTERIOR, np.int64)
    bf = blocks.face_boundary.reshape(-1)
    on_boundary = bf != FACE_INTERIOR
    fb[finv.ravel()[on_boundary]] = bf[on_boundary]
    return Topology(edges, block_edge, edge_class, faces, block_face, fb)


def _unique_rows(major: np.ndarray, minor: np.ndarray):
    """First occurrence and inverse of the unique pairs (major, minor), in lexicographic
    order (as ``np.unique(..., axis=0, return_index=True, return_inverse=True)``)."""
    order = np.lexsort((minor, major))  # stable: the first of equal rows is their first occurrence
    a, b = major[order], minor[order]
    new = np.ones(len(order), bool)
    new[1:] = (a[1:] != a[:-1]) | (b[1:] != b[:-1])
    inv = np.empty(len(order), np.int64)
    inv[order] = np.cumsum(new) - 1
    return order[new], inv


def _face_corner_grid(f: int) -> np.ndarray:
    """Local corners of face f as a 2x2 grid indexed by its free axes (p, q)."""
    a, v = FACE_AXES[f]
    p, q = [x for x in range(3) if x != a]
    grid = np.empty((2, 2), np.int64)
    for pp in range(2):
        for qq in range(2):
            ijk = [0, 0, 0]
            ijk[a], ijk[p], ijk[q] = v, pp, qq
            grid[pp, qq] = _CORNER_INDEX[tuple(ijk)]
    return grid


def canonical_faces(g: np.ndarray) -> np.ndarray:
    """Canonical corners (origin, s-neighbour, t-neighbour, far) of faces given as corner ids
    at local (0,0), (0,1), (1,0), (1,1): the origin is the smallest id and the s axis points
    to its smaller neighbour, so every block sharing a face agrees on its orientation."""
    g = np.asarray(g, np.int64).reshape(-1, 2, 2)
    m = len(g)
    flat = np.argmin(g.reshape(m, 4), axis=1)
    pp, qq = flat // 2, flat % 2
    r = np.arange(m)
    origin = g[r, pp, qq]
    a = g[r, 1 - pp, qq]
    b = g[r, pp, 1 - qq]
    far = g[r, 1 - pp, 1 - qq]
    s_first = a < b
    return np.stack([origin, np.where(s_first, a, b), np.where(s_first, b, a), far], axis=1)


# ---------------------------------------------------------------------------
# the mesher
# ---------------------------------------------------------------------------
@dataclass
class StructuredMesh:
    """Output of :func:`mesh_blocks` (see :class:`vmesh.mesh.HexMesh` for the public class)."""

    points: np.ndarray  # (n, 3)
    cells: np.ndarray  # (m, (p+1)^3) node ids in tensor order (i fastest)
    order: int
    cell_block: np.ndarray  # (m,) block id
    boundary_faces: np.ndarray  # (k, (p+1)^2) node ids in tensor order, outward
    boundary_ids: np.ndarray  # (k,) 0 wall, j open end j
    boundary_cells: np.ndarray  # (k,) element of each boundary face
    on_wall: np.ndarray  # (n,) bool: node projected onto the wall
    block_counts: np.ndarray  # (nb, 3) elements per block along i, j, k


def requested_counts(blocks: BlockStructure, topo: Topology, ref: Refinement) -> np.ndarray:
    """Elements per unique edge class (the maximum any member edge asks for)."""
    V = blocks.vertices
    length = np.linalg.norm(V[topo.edges[:, 1]] - V[topo.edges[:, 0]], axis=1)
    by_kind = {AXIS_AROUND: ref.around, AXIS_CORE: ref.core, AXIS_RING: ref.ring, AXIS_LAYER: ref.layer}
    nb = blocks.n_blocks
    axis_of_edge = np.repeat(np.arange(3), 4)
    kind = blocks.axis_kind[:, axis_of_edge]  # (nb, 12)
    e = topo.block_edge
    req = np.ones((nb, 12), np.int64)
    for k, n in by_kind.items():
        req[kind == k] = n
    along = kind == AXIS_ALONG
    r = np.repeat(blocks.block_radius[:, None], 12, axis=1)
    req[along] = np.maximum(1, np.ceil(length[e[along]] / (ref.element_length * r[along]) - 1e-9)).astype(np.int64)
    n_class = topo.edge_class.max() + 1 if len(topo.edge_class) else 0
    counts = np.ones(n_class, np.int64)
    np.maximum.at(counts, topo.edge_class[e.ravel()], req.ravel())
    return counts


def mesh_blocks(blocks: BlockStructure, project, ref: Refinement, progress=None, signed_distance=None, intersect_lines=None) -> StructuredMesh:
    """Fill every block with a transfinite lattice of nodes; see the module docstring.

    Parameters
    ----------
    blocks : BlockStructure
    project : callable
        ``project(points (n, 3)) -> closest wall points (n, 3)``.
    ref : Refinement
    progress : callable, optional
        ``progress(fraction, message)``.
    signed_distance : callable, optional
        ``signed_distance(points) -> (n,)``, positive inside. When given, the interior nodes
        of wall faces are moved onto the wall along the patch normal (a ray) before the final
        closest-point projection: closest points fold at concave places such as the crotch
        of a junction, rays along the normal do not. Face nodes whose ray finds no wall
        within a radius (a face over the mouth of a vessel without skeleton) stay on their
        patch and are not marked as wall nodes; edge nodes whose ray runs past a concavity
        (much longer than their wall distance) use the closest point.
    intersect_lines : callable, optional
        ``intersect_lines(points, directions, reach, side=None) -> (moved, hit)``: the nearest
        crossing of each line with the wall within ``|t| <= reach``, at ``t * side >= 0`` (e.g.
        :meth:`~vmesh.geometry.sdf.SignedDistance.intersect_lines`, an exact ray cast). Without
        it the rays search the zero of ``signed_distance`` (:func:`ray_to_surface`).
    """
    if signed_distance is not None and intersect_lines is None:
        intersect_lines = lambda x, d, r, side=None: ray_to_surface(x, d, signed_distance, r, return_hit=True)  # noqa: E731
    tick = progress or (lambda f, m="": None)
    p = int(ref.order)
    V = blocks.vertices.copy()
    # block corners may have been placed with a coarse SDF: put them on this wall
    if blocks.vertex_on_surface.any():
        V[blocks.vertex_on_surface] = project(V[blocks.vertex_on_surface])
    H = blocks.hexes
    topo = block_topology(blocks)
    counts = requested_counts(blocks, topo, ref)
    n_edge = counts[topo.edge_class]  # elements per unique edge
    N_edge = n_edge * p  # lattice intervals per unique edge
    # block lattice sizes along i, j, k (edges 0, 4, 8 run along i, j, k)
    block_n = n_edge[topo.block_edge[:, [0, 4, 8]]]
    block_N = block_n * p

    wall_face = topo.face_boundary == FACE_WALL
    # edges lying on the wall: edges of wall faces
    fc = topo.faces
    wall_edges_pairs = np.concatenate(
        [np.sort(fc[wall_face][:, [0, 1]], 1), np.sort(fc[wall_face][:, [2, 3]], 1), np.sort(fc[wall_face][:, [0, 2]], 1), np.sort(fc[wall_face][:, [1, 3]], 1)]
    )
    E = len(topo.edges)
    edge_on_wall = np.zeros(E, bool)
    if len(wall_edges_pairs):
        idx = _row_lookup(topo.edges, wall_edges_pairs)
        edge_on_wall[idx[idx >= 0]] = True

    # --- numbering -------------------------------------------------------
    nv = len(V)
    edge_off = nv + np.concatenate([[0], np.cumsum(N_edge - 1)])[:-1]
    n_after_edges = nv + int((N_edge - 1).sum())
    F = len(fc)
    face_Ns = N_edge[_row_lookup(topo.edges, np.sort(fc[:, [0, 1]], 1))]
    face_Nt = N_edge[_row_lookup(topo.edges, np.sort(fc[:, [0, 2]], 1))]
    face_off = n_after_edges + np.concatenate([[0], np.cumsum((face_Ns - 1) * (face_Nt - 1))])[:-1]
    n_after_faces = n_after_edges + int(((face_Ns - 1) * (face_Nt - 1)).sum())
    vol_sizes = np.prod(block_N - 1, axis=1)
    vol_off = n_after_faces + np.concatenate([[0], np.cumsum(vol_sizes)])[:-1]
    n_nodes = n_after_faces + int(vol_sizes.sum())
    X = np.full((n_nodes, 3), np.nan)
    on_wall = np.zeros(n_nodes, bool)
    X[:nv] = V
    on_wall[:nv] = blocks.vertex_on_surface

    # --- edges -------------------------------------------------------------
    tick(0.05, "edges")
    wall_end_first = blocks.vertex_on_surface[topo.edges[:, 0]]
    wall_end_last = blocks.vertex_on_surface[topo.edges[:, 1]]
    edge_kind = np.full(E, -1)
    edge_radius = np.zeros(E)
    axis_of_edge = np.repeat(np.arange(3), 4)
    edge_kind[topo.block_edge.ravel()] = blocks.axis_kind[:, axis_of_edge].ravel()
    edge_radius[topo.block_edge.ravel()] = np.repeat(blocks.block_radius, 12)
    edge_normal = _wall_edge_normals(blocks, topo, V, wall_face) if signed_distance is not None else None
    for n in np.unique(n_edge):
        sel = np.flatnonzero(n_edge == n)
        a, b = V[topo.edges[sel, 0]], V[topo.edges[sel, 1]]
        length = np.linalg.norm(b - a, axis=1)
        ratio = np.ones(len(sel))
        graded = (edge_kind[sel] == AXIS_LAYER) & (wall_end_first[sel] ^ wall_end_last[sel])
        if graded.any() and n > 1 and (ref.first_layer or ref.growth):
            if ref.first_layer:
                q = geometric_ratio(ref.first_height(edge_radius[sel][graded]), length[graded], int(n))
            else:
                q = np.full(graded.sum(), float(ref.growth))
            # sizes grow away from the wall: from t = 0 when the wall is at the first vertex
            ratio[graded] = np.where(wall_end_first[sel][graded], q, 1.0 / q)
        t = with_order(element_boundaries(int(n), ratio), p, ref.nodes)  # (m, N+1)
        pts = a[:, None, :] + t[:, :, None] * (b - a)[:, None, :]
        wall = edge_on_wall[sel]
        if wall.any():
            if edge_normal is not None and pts.shape[1] > 2:  # edges of one linear element have no inner nodes
                inner_pts = pts[wall, 1:-1]
                k = inner_pts.shape[1]
                flat = inner_pts.reshape(-1, 3)
                f0 = signed_distance(flat)
                # the edge normal points out of the vessel: inside nodes move outward, outside ones inward
                reach = np.minimum(np.repeat(edge_radius[sel[wall]], k), RAY_SEARCH * np.abs(f0))
                moved, _ = intersect_lines(flat, np.repeat(edge_normal[sel[wall]], k, axis=0), reach, np.where(f0 >= 0, 1, -1))
                # A ray much longer than the distance to the wall has passed a concave place (the
                # saddle beside a junction, a vessel mouth) and lands far from where the edge
                # runs; the closest point is nearer and keeps the edge on its side of the fold.
                far = np.linalg.norm(moved - flat, axis=1) > RAY_TRUST * np.abs(f0) + 1e-9
                moved[far] = flat[far]
                pts[wall, 1:-1] = moved.reshape(-1, k, 3)
            pts[wall] = _project_curves(pts[wall], t[wall], project)
        inner = pts[:, 1:-1].reshape(-1, 3)
        ids = (edge_off[sel][:, None] + np.arange(int(n) * p - 1)[None, :]).ravel()
        X[ids] = inner
        on_wall[ids] = np.repeat(wall, int(n) * p - 1)

    # --- faces (Coons patches) --------------------------------------------------
    face_radius = np.zeros(F)
    face_radius[topo.block_face.ravel()] = np.repeat(blocks.block_radius, 6)
    face_out = _wall_face_outward(blocks, topo, V)
    tick(0.3, "faces")
    for Ns, Nt in sorted(set(zip(face_Ns.tolist(), face_Nt.tolist()))):
        sel = np.flatnonzero((face_Ns == Ns) & (face_Nt == Nt))
        if Ns < 2 or Nt < 2:
            continue
        grid = _face_lattice_ids(fc[sel], Ns, Nt, topo, edge_off, N_edge)  # (m, Ns+1, Nt+1), interior -1
        m = len(sel)
        inner_ids = face_off[sel][:, None] + np.arange((Ns - 1) * (Nt - 1))[None, :]
        grid[:, 1:-1, 1:-1] = inner_ids.reshape(m, Ns - 1, Nt - 1)
        P = X[grid]  # boundary known; interior filled in place (a fresh array)
        _coons_kernel(P)
        if ref.first_layer:
            for axis, (c0, c1) in ((1, (0, 1)), (2, (0, 2))):
                e = _row_lookup(topo.edges, np.sort(fc[sel][:, [c0, c1]], 1))
                layer = edge_kind[e] == AXIS_LAYER
                if layer.any():
                    wall_first = blocks.vertex_on_surface[fc[sel][layer, c0]]
                    h1 = ref.first_height(edge_radius[e[layer]])
                    _regrade_inplace(P, axis, layer, wall_first, h1, int(n_edge[e[layer][0]]), p, ref.nodes)
        wall = wall_face[sel]
        if wall.any():
            Pw = P[wall]
            interior = Pw[:, 1:-1, 1:-1].reshape(-1, 3)
            hit = np.ones(len(interior), bool)
            if signed_distance is not None:
                normal = _patch_normals(Pw)  # (k, Ns-1, Nt-1, 3)
                # oriented out of the vessel: inside nodes move outward, outside ones inward
                flip = np.einsum("ijkl,il->ijk", normal, face_out[sel[wall]]) < 0
                normal = np.where(flip[..., None], -normal, normal).reshape(-1, 3)
                reach = np.repeat(face_radius[sel][wall], (Ns - 1) * (Nt - 1))
                f0 = signed_distance(interior)
                interior, hit = intersect_lines(interior, normal, np.minimum(reach, RAY_SEARCH * np.abs(f0)), np.where(f0 >= 0, 1, -1))
                # no wall along the normal within a radius: the face spans an opening (the mouth
                # of a vessel without skeleton). The closest wall point is then on the opening's
                # rim, far to the side, and would fold the layer: keep the patch point instead.
                # Points already close to the wall are projected as before.
                hit |= np.abs(f0) < OPENING_DEPTH * reach
            projected = project(interior)
            P[wall, 1:-1, 1:-1] = np.where(hit[:, None], projected, interior).reshape(-1, Ns - 1, Nt - 1, 3)
        X[inner_ids.ravel()] = P[:, 1:-1, 1:-1].reshape(-1, 3)
        wall_nodes = np.repeat(wall, (Ns - 1) * (Nt - 1))
        if wall.any():
            wall_nodes[wall_nodes] = hit
        on_wall[inner_ids.ravel()] = wall_nodes

    # --- blocks (transfinite interpolation) --------------------------------------
    tick(0.6, "blocks")
    lattices = {}
    groups = {}
    for b, key in enumerate(map(tuple, block_N.tolist())):
        groups.setdefault(key, []).append(b)
    for key, members in groups.items():
        members = np.asarray(members)
        L = _block_lattice_ids(members, key, H, topo, edge_off, N_edge, face_off, face_Ns, face_Nt, vol_off)
        I, J, K = key
        if I > 1 and J > 1 and K > 1:
            m = len(members)
            layer = np.zeros((m, 3), bool)
            wall_first = np.zeros((m, 3), bool)
            h1 = np.zeros((m, 3))
            if ref.first_layer:
                layer[:] = blocks.axis_kind[members] == AXIS_LAYER
                for axis in range(3):
                    c1 = [1, 3, 4][axis]  # corner next to corner 0 along this axis
                    wall_first[:, axis] = blocks.vertex_on_surface[H[members, 0]] & ~blocks.vertex_on_surface[H[members, c1]]
                    h1[:, axis] = ref.first_height(blocks.block_radius[members])
            n3 = np.array([k // p for k in key])
            layer &= n3[None, :] >= 2  # one element across: nothing to re-space
            # per axis: which lattice lines along it are interior (before and after the axis)
            masks = []
            for axis in range(3):
                dims = (I + 1, J + 1, K + 1)
                for part in (dims[:axis], dims[axis + 1 :]):
                    inner = np.zeros(part, bool)
                    inner[tuple(slice(1, -1) for _ in part)] = True
                    masks.append(inner.ravel())
            _fill_blocks_kernel(X, L, layer, wall_first, h1, n3, reference_points(p, ref.nodes)[:-1].copy(), *masks)
        lattices[key] = (members, L)
    if np.isnan(X).any():
        raise RuntimeError("transfinite meshing left nodes unset (inconsistent block topology)")

    # --- elements and boundary faces ------------------------------------------
    tick(0.85, "connectivity")
    cell_block, bfaces, bids, bcells = [], [], [], []
    n_total = sum(len(members) * int(np.prod([k // p for k in key])) for key, (members, _) in lattices.items())
    all_cells = np.empty((n_total, (p + 1) ** 3), np.int64)
    n_cells = 0
    for key, (members, L) in lattices.items():
        ni, nj, nk = (k // p for k in key)
        # element (ei, ej, ek) spans lattice [ei p : ei p + p + 1] etc., nodes in tensor order
        n_here = len(members) * nk * nj * ni
        _cells_kernel(L, p, all_cells[n_cells : n_cells + n_here])
        elem_index = n_cells + np.arange(n_here).reshape(len(members), nk, nj, ni)
        cell_block.append(np.repeat(members, nk * nj * ni))
        # boundary faces of these blocks
        fbound = blocks.face_boundary[members]
        for f in range(6):
            has = np.flatnonzero(fbound[:, f] != FACE_INTERIOR)
            if len(has) == 0:
                continue
            face_nodes, face_elems = _element_faces(L[has], elem_index[has], f, p, (ni, nj, nk))
            bfaces.append(face_nodes)
            bcells.append(face_elems)
            bids.append(np.repeat(fbound[has, f], face_nodes.shape[0] // len(has)))
        n_cells += len(members) * nk * nj * ni
    tick(1.0, "done")
    return StructuredMesh(
        points=X,
        cells=all_cells,
        order=p,
        cell_block=np.concatenate(cell_block),
        boundary_faces=np.concatenate(bfaces) if bfaces else np.zeros((0, (p + 1) ** 2), np.int64),
        boundary_ids=np.concatenate(bids) if bids else np.zeros(0, np.int64),
        boundary_cells=np.concatenate(bcells) if bcells else np.zeros(0, np.int64),
        on_wall=on_wall,
        block_counts=block_n,
    )


def regrade_lines(P: np.ndarray, axis: int, wall_first: np.ndarray, h1: np.ndarray, n: int, p: int, kind: str) -> np.ndarray:
    """Re-space the interior lattice lines of ``P`` (m, ..., 3) along ``axis`` so that the
    first element at the wall end has thickness ``h1`` (absolute, per lattice).

    Coons and transfinite interpolation carry the *relative* spacing of the block edges into
    the interior, which thickens the first layer wherever the boundary layer is thicker than
    at the block corners; re-spacing every line by arc length keeps it at ``h1`` everywhere.
    Nodes only slide along their lattice lines, and the lattice boundary is left untouched.
    """
    res = np.array(P, float, order="C", copy=True)
    _regrade_inplace(res, axis, np.ones(len(res), bool), wall_first, h1, n, p, kind)
    return res


def _regrade_inplace(P: np.ndarray, axis: int, selected: np.ndarray, wall_first: np.ndarray, h1: np.ndarray, n: int, p: int, kind: str) -> None:
    """:func:`regrade_lines` in place on the lattices ``P[selected]`` (C-contiguous ``P``);
    ``wall_first`` and ``h1`` are given per selected lattice."""
    if n < 2 or not np.any(selected):
        return
    m = P.shape[0]
    dims = P.shape[1:-1]
    k = dims[axis - 1]
    before, after = dims[: axis - 1], dims[axis:]
    # lines whose other lattice indices are all interior (the boundary is left untouched)
    inner_before = np.zeros(before, bool)
    inner_before[tuple(slice(1, -1) for _ in before)] = True
    inner_after = np.zeros(after, bool)
    inner_after[tuple(slice(1, -1) for _ in after)] = True
    sel = np.flatnonzero(selected)
    wall_first_all = np.zeros(m, bool)
    wall_first_all[sel] = np.asarray(wall_first, bool)
    h1_all = np.zeros(m)
    h1_all[sel] = h1
    view = P.reshape(m, inner_before.size, k, inner_after.size, 3)  # a view: P is C-contiguous
    _regrade_kernel(view, sel, inner_before.ravel(), inner_after.ravel(), wall_first_all, h1_all, int(n), reference_points(p, kind)[:-1].copy())


def _row_lookup(table: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """Index of each of ``rows`` in the sorted unique ``table`` (-1 when absent)."""
    if len(rows) == 0:
        return np.zeros(0, np.int64)
    n = int(max(table.max(), rows.max())) + 1
    tk = table[:, 0] * n + table[:, 1]
    rk = rows[:, 0] * n + rows[:, 1]
    pos = np.searchsorted(tk, rk)
    pos = np.clip(pos, 0, len(tk) - 1)
    return np.where(tk[pos] == rk, pos, -1)


def _edge_line(edges: np.ndarray, eids: np.ndarray, from_v: np.ndarray, edge_off, N_edge, N: int) -> np.ndarray:
    """Node ids (m, N + 1) of unique edges ``eids`` walked starting at vertex ``from_v``."""
    lo, hi = edges[eids, 0], edges[eids, 1]
    inner = edge_off[eids][:, None] + np.arange(N - 1)[None, :]
    forward = from_v == lo
    inner = np.where(forward[:, None], inner, inner[:, ::-1])
    start = np.where(forward, lo, hi)
    end = np.where(forward, hi, lo)
    return np.concatenate([start[:, None], inner, end[:, None]], axis=1)


def _face_lattice_ids(fc: np.ndarray, Ns: int, Nt: int, topo: Topology, edge_off, N_edge) -> np.ndarray:
    """(m, Ns+1, Nt+1) node ids of canonical faces; interior left at -1."""
    m = len(fc)
    grid = np.full((m, Ns + 1, Nt + 1), -1, np.int64)
    o, a, b, d = fc.T
    eid = lambda u, v: _row_lookup(topo.edges, np.sort(np.stack([u, v], 1), 1))  # noqa: E731
    grid[:, :, 0] = _edge_line(topo.edges, eid(o, a), o, edge_off, N_edge, Ns)
    grid[:, :, Nt] = _edge_line(topo.edges, eid(b, d), b, edge_off, N_edge, Ns)
    grid[:, 0, :] = _edge_line(topo.edges, eid(o, b), o, edge_off, N_edge, Nt)
    grid[:, Ns, :] = _edge_line(topo.edges, eid(a, d), a, edge_off, N_edge, Nt)
    return grid


def _block_lattice_ids(members, key, H, topo, edge_off, N_edge, face_off, face_Ns, face_Nt, vol_off) -> np.ndarray:
    """(m, I+1, J+1, K+1) global node ids of the lattices of blocks ``members``."""
    I, J, K = key
    Ns3 = (I, J, K)
    m = len(members)
    L = np.full((m, I + 1, J + 1, K + 1), -1, np.int64)
    Hm = H[members]
    # edges (include corners)
    for le, (c0, c1) in enumerate(HEX_EDGES.tolist()):
        axis = le // 4
        e = topo.block_edge[members, le]
        line = _edge_line(topo.edges, e, Hm[:, c0], edge_off, N_edge, Ns3[axis])
        fixed = HEX_CORNERS[c0]
        idx = [slice(None)] * 4
        for ax in range(3):
            idx[ax + 1] = slice(None) if ax == axis else fixed[ax] * Ns3[ax]
        L[tuple(idx)] = line
    # faces
    for f in range(6):
        a, v = FACE_AXES[f]
        pa, qa = [x for x in range(3) if x != a]
        Np, Nq = Ns3[pa], Ns3[qa]
        if Np < 2 or Nq < 2:
            continue
        fid = topo.block_face[members, f]
        g = Hm[:, _face_corner_grid(f)]  # (m, 2, 2) global ids at local (pp, qq)
        canon = topo.faces[fid]  # origin, s-nbr, t-nbr, far
        origin = canon[:, 0]
        pp0 = (g[:, 1, 0] == origin) | (g[:, 1, 1] == origin)
        qq0 = (g[:, 0, 1] == origin) | (g[:, 1, 1] == origin)
        nbr_p = np.where(pp0, np.where(qq0, g[:, 0, 1], g[:, 0, 0]), np.where(qq0, g[:, 1, 1], g[:, 1, 0]))
        swap = nbr_p != canon[:, 1]  # local p axis is canonical t
        pi = np.arange(1, Np)[None, :, None]
        qi = np.arange(1, Nq)[None, None, :]
        P = np.where(pp0[:, None, None], Np - pi, pi)
        Q = np.where(qq0[:, None, None], Nq - qi, qi)
        s = np.where(swap[:, None, None], Q, P)
        t = np.where(swap[:, None, None], P, Q)
        Nt = np.where(swap, Np, Nq)
        ids = face_off[fid][:, None, None] + (s - 1) * (Nt[:, None, None] - 1) + (t - 1)
        idx = [slice(None)] * 4
        idx[a + 1] = v * Ns3[a]
        idx[pa + 1] = slice(1, Np)
        idx[qa + 1] = slice(1, Nq)
        L[tuple(idx)] = ids
    if I > 1 and J > 1 and K > 1:
        inner = vol_off[members][:, None] + np.arange((I - 1) * (J - 1) * (K - 1))[None, :]
        L[:, 1:-1, 1:-1, 1:-1] = inner.reshape(m, I - 1, J - 1, K - 1)
    return L


def _element_faces(L, elem_index, f, p, n3):
    """Node ids (tensor order, outward) and elements of the element faces on local block face f."""
    a, v = FACE_AXES[f]
    pa, qa = [x for x in range(3) if x != a]
    ni = n3
    m = len(L)
    ar = np.arange(p + 1)
    # lattice indices of element faces: along pa and qa elements, fixed a
    np_, nq_ = ni[pa], ni[qa]
    pidx = np.arange(np_)[:, None] * p + ar[None, :]  # (np, p+1)
    qidx = np.arange(nq_)[:, None] * p + ar[None, :]
    idx = [None, None, None]
    fixed = v * ni[a] * p
    # build index arrays of shape (np, nq, p+1 (q), p+1 (p)) -> tensor order with p-axis fastest
    P_ = pidx[:, None, None, :]
    Q_ = qidx[None, :, :, None]
    shape = (np_, nq_, p + 1, p + 1)
    idx[pa] = np.broadcast_to(P_, shape)
    idx[qa] = np.broadcast_to(Q_, shape)
    idx[a] = np.full(shape, fixed)
    nodes = L[:, idx[0], idx[1], idx[2]]  # (m, np, nq, p+1, p+1)
    # outward orientation: (pa, qa) ascending is outward for faces i=1, j=0, k=1 (see HEX_FACES)
    outward_as_is = f in (1, 2, 5)
    if not outward_as_is:
        nodes = nodes.swapaxes(-1, -2)
    nodes = nodes.reshape(m * np_ * nq_, (p + 1) ** 2)
    # elements owning these faces
    e_idx = [None, None, None]
    ep = np.arange(np_)[:, None]
    eq = np.arange(nq_)[None, :]
    e_idx[pa] = np.broadcast_to(ep, (np_, nq_))
    e_idx[qa] = np.broadcast_to(eq, (np_, nq_))
    e_idx[a] = np.full((np_, nq_), v * (ni[a] - 1))
    # elem_index axes are (m, ek, ej, ei)
    elems = elem_index[:, e_idx[2], e_idx[1], e_idx[0]].reshape(-1)
    return nodes, elems


def _wall_edge_normals(blocks, topo, V, wall_face) -> np.ndarray:
    """Outward unit normal per unique edge: the mean of the adjacent wall faces' normals
    (zero for edges not on the wall). Rays along it keep wall edges in their cross-section."""
    b, f = np.nonzero(blocks.face_boundary == FACE_WALL)
    fid = topo.block_face[b, f]
    c = topo.faces[fid]  # origin, s-nbr, t-nbr, far
    n = np.cross(V[c[:, 3]] - V[c[:, 0]], V[c[:, 2]] - V[c[:, 1]])
    out = V[c].mean(axis=1) - V[blocks.hexes[b]].mean(axis=1)
    n *= np.where(np.einsum("ij,ij->i", n, out) < 0, -1.0, 1.0)[:, None]
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
    acc = np.zeros((len(topo.edges), 3))
    for u, v in ((0, 1), (2, 3), (0, 2), (1, 3)):
        e = _row_lookup(topo.edges, np.sort(c[:, [u, v]], 1))
        np.add.at(acc, e, n)
    return acc / np.maximum(np.linalg.norm(acc, axis=1, keepdims=True), 1e-300)


def _wall_face_outward(blocks, topo, V) -> np.ndarray:
    """Direction ``(F, 3)`` from the owning block's centre to each wall face's centre (zero
    for other faces): which side of a wall face is out of the vessel."""
    out = np.zeros((len(topo.faces), 3))
    b, f = np.nonzero(blocks.face_boundary == FACE_WALL)
    fid = topo.block_face[b, f]
    out[fid] = V[topo.faces[fid]].mean(axis=1) - V[blocks.hexes[b]].mean(axis=1)
    return out


def _patch_normals(P: np.ndarray) -> np.ndarray:
    """Unit normals at the interior nodes of lattices (m, Ns+1, Nt+1, 3) (central differences)."""
    ds = P[:, 2:, 1:-1] - P[:, :-2, 1:-1]
    dt = P[:, 1:-1, 2:] - P[:, 1:-1, :-2]
    n = np.cross(ds, dt)
    return n / np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-300)


def ray_to_surface(points: np.ndarray, directions: np.ndarray, signed_distance, reach: np.ndarray, iterations: int = 12, return_hit: bool = False):
    """Move ``points`` along the lines ``points + t * directions`` to the zero of the signed
    distance nearest to t = 0, within ``|t| <= reach`` (secant steps inside a bracket).

    Points whose line has no zero within reach are returned unchanged (the caller's
    closest-point projection then takes over). With ``return_hit`` a second array says
    which points found the wall.
    """
    x = np.asarray(points, float)
    d = np.asarray(directions, float)
    reach = np.broadcast_to(np.asarray(reach, float), (len(x),))
    f0 = signed_distance(x)
    # a first step along +d by the signed distance: the zero is at t ~ f0 when d points outward
    probe = signed_distance(x + 0.5 * np.minimum(np.abs(f0), reach)[:, None] * d)
    outward = np.where(f0 >= 0, probe < f0, probe > f0)
    sgn = np.where(outward, 1.0, -1.0)  # direction in which t moves towards the wall
    lo = np.zeros(len(x))
    flo = f0
    hi = np.minimum(2.0 * np.abs(f0) + 1e-9, reach)
    fhi = signed_distance(x + (sgn * hi)[:, None] * d)
    # grow the bracket (bounded by reach) until the sign changes
    for _ in range(4):
        grow = (np.sign(fhi) == np.sign(flo)) & (hi < reach)
        if not grow.any():
            break
        hi = np.where(grow, np.minimum(2 * hi, reach), hi)
        fhi[grow] = signed_distance(x[grow] + (sgn[grow] * hi[grow])[:, None] * d[grow])
    ok = np.sign(fhi) != np.sign(flo)
    # secant (regula falsi, bracketed) steps on the lines still open; a line is done when
    # its bracket or its distance falls below a 1e-10 fraction of its reach
    tol = 1e-10 * np.maximum(reach, 1e-300)
    active = np.flatnonzero(ok)
    for _ in range(iterations):
        if len(active) == 0:
            break
        a_lo, a_hi, a_flo, a_fhi = lo[active], hi[active], flo[active], fhi[active]
        t = a_lo - a_flo * (a_hi - a_lo) / np.where(a_fhi != a_flo, a_fhi - a_flo, 1e-300)
        t = np.clip(t, np.minimum(a_lo, a_hi), np.maximum(a_lo, a_hi))
        mid = 0.5 * (a_lo + a_hi)
        t = np.where(np.abs(t - a_lo) < 1e-12 * np.maximum(a_hi, 1e-12), mid, t)
        ft = signed_distance(x[active] + (sgn[active] * t)[:, None] * d[active])
        same = np.sign(ft) == np.sign(a_flo)
        lo[active] = np.where(same, t, a_lo)
        flo[active] = np.where(same, ft, a_flo)
        hi[active] = np.where(~same, t, a_hi)
        fhi[active] = np.where(~same, ft, a_fhi)
        done = (np.abs(ft) <= tol[active]) | (np.abs(hi[active] - lo[active]) <= tol[active])
        active = active[~done]
    t = np.where(np.abs(flo) < np.abs(fhi), lo, hi)
    out = np.where(ok[:, None], x + (sgn * t)[:, None] * d, x)
    return (out, ok) if return_hit else out


def _project_curves(pts: np.ndarray, t: np.ndarray, project, passes: int = 2) -> np.ndarray:
    """Project polylines (m, N+1, 3) onto the wall keeping the spacing ``t`` by arc length."""
    m, n1, _ = pts.shape
    cur = pts.copy()
    inner = project(cur[:, 1:-1].reshape(-1, 3)).reshape(m, n1 - 2, 3)
    cur[:, 1:-1] = inner
    for _ in range(passes - 1):
        seg = np.linalg.norm(np.diff(cur, axis=1), axis=2)
        s = np.concatenate([np.zeros((m, 1)), np.cumsum(seg, axis=1)], axis=1)
        s /= np.maximum(s[:, -1:], 1e-300)
        # where does each target fraction t fall along the current polyline?
        res = _interp_rows(t, s, cur)
        res[:, 0], res[:, -1] = cur[:, 0], cur[:, -1]
        res[:, 1:-1] = project(res[:, 1:-1].reshape(-1, 3)).reshape(m, n1 - 2, 3)
        cur = res
    return cur


def _interp_rows(x: np.ndarray, xp: np.ndarray, fp: np.ndarray) -> np.ndarray:
    """Row-wise ``np.interp``: x (m, j), xp (m, k) ascending per row, fp (m, k) or (m, k, d)."""
    x = np.ascontiguousarray(x, float)
    xp = np.ascontiguousarray(xp, float)
    f3 = np.ascontiguousarray(fp, float)
    if f3.ndim == 2:
        f3 = f3[:, :, None]
    out = _interp_rows_kernel(x, xp, f3)
    return out[:, :, 0] if np.ndim(fp) == 2 else out


# ---------------------------------------------------------------------------
# transfinite interpolation kernels
# ---------------------------------------------------------------------------
def coons_patch(P: np.ndarray) -> np.ndarray:
    """Fill the interior of lattices (m, Ns+1, Nt+1, 3) from their boundary (Coons patch).

    Blending parameters follow the arc-length spacing of opposite edges, so graded
    edge distributions carry into the face.
    """
    P = np.array(P, float, order="C", copy=True)
    _coons_kernel(P)
    return P


def transfinite_volume(P: np.ndarray) -> np.ndarray:
    """Fill lattices (m, I+1, J+1, K+1, 3) from their six faces (transfinite interpolation).

    Blending parameters along each axis follow the mean spacing of the block's four
    parallel edges.
    """
    P = np.array(P, float, order="C", copy=True)
    _tfi_kernel(P)
    return P


# ---------------------------------------------------------------------------
# compiled kernels (parallel over lattices or lines)
# ---------------------------------------------------------------------------
@nb.njit(cache=True, error_model="numpy")
def _ratio(first, length, n):
    """Geometric ratio of one edge (see :func:`geometric_ratio`): Newton steps on the convex
    ``s(q) = 1 + q + ... + q**(n-1)`` from above the root converge monotonically; the sum
    form has no cancellation near q = 1, unlike ``(q**n - 1) / (q - 1)``."""
    target = length / max(first, 1e-300)
    if not target > n:
        return 1.0
    q = 2.0
    for _ in range(60):  # a bracket top: s(q) >= target
        s = 1.0
        for _i in range(n - 1):
            s = s * q + 1.0
        if s >= target:
            break
        q *= 2.0
    for _ in range(200):
        s, ds = 1.0, 0.0
        for _i in range(n - 1):
            ds = ds * q + s
            s = s * q + 1.0
        step = (s - target) / ds
        if not step > 1e-16 * q:
            break
        q -= step
    return q


@nb.njit(parallel=True, cache=True, error_model="numpy")
def _ratio_kernel(first, length, n):
    out = np.empty(len(first))
    for e in nb.prange(len(first)):
        out[e] = _ratio(first[e], length[e], n)
    return out


@nb.njit(cache=True, error_model="numpy", inline="always")
def _interp_line(x, xp, fp, out):
    """``out[i] = interp(x[i], xp, fp)`` for one ascending row (fp: (k, d)), the arithmetic of
    the former vectorised row-wise interpolation: interval by normalised position, clipped
    weights, flat extension outside the row."""
    k = len(xp)
    lo = xp[0]
    span = max(xp[k - 1] - lo, 1e-300)
    j = 0
    for i in range(len(x)):
        xn = min(max((x[i] - lo) / span, 0.0), 1.0)
        # last node at or before x (x is usually ascending: walk from the previous one)
        while j > 0 and (xp[j] - lo) / span > xn:
            j -= 1
        while j + 1 < k and (xp[j + 1] - lo) / span <= xn:
            j += 1
        c = min(j, k - 2)
        x0, x1 = xp[c], xp[c + 1]
        w = 0.0
        if x1 > x0:
            w = min(max((x[i] - x0) / max(x1 - x0, 1e-300), 0.0), 1.0)
        for d in range(fp.shape[1]):
            out[i, d] = fp[c, d] + w * (fp[c + 1, d] - fp[c, d])


@nb.njit(parallel=True, cache=True, error_model="numpy")
def _interp_rows_kernel(x, xp, fp):
    m = x.shape[0]
    out = np.empty((m, x.shape[1], fp.shape[2]))
    for r in nb.prange(m):
        _interp_line(x[r], xp[r], fp[r], out[r])
    return out


@nb.njit(cache=True, error_model="numpy", inline="always")
def _arc_lengths(P, out):
    """Arc length from the first node at every node of one polyline (n, 3) into out (n,)."""
    out[0] = 0.0
    for i in range(1, P.shape[0]):
        dx, dy, dz = P[i, 0] - P[i - 1, 0], P[i, 1] - P[i - 1, 1], P[i, 2] - P[i - 1, 2]
        out[i] = out[i - 1] + np.sqrt(dx * dx + dy * dy + dz * dz)


@nb.njit(cache=True, error_model="numpy", inline="always")
def _arc_params(P, out):
    """Normalised arc-length parameters of one polyline (n, 3) into out (n,)."""
    _arc_lengths(P, out)
    total = max(out[P.shape[0] - 1], 1e-300)
    for i in range(P.shape[0]):
        out[i] = out[i] / total


@nb.njit(parallel=True, cache=True, error_model="numpy")
def _coons_kernel(P):
    """Coons patch of lattices (m, Ns+1, Nt+1, 3) in place (interior only)."""
    m, ns1, nt1 = P.shape[0], P.shape[1], P.shape[2]
    Ns, Nt = ns1 - 1, nt1 - 1
    for f in nb.prange(m):
        Q = P[f]
        sb, st = np.empty(ns1), np.empty(ns1)
        vl, vr = np.empty(nt1), np.empty(nt1)
        _arc_params(Q[:, 0], sb)
        _arc_params(Q[:, Nt], st)
        _arc_params(Q[0, :], vl)
        _arc_params(Q[Ns, :], vr)
        for i in range(1, Ns):
            s_mean = 0.5 * (sb[i] + st[i])
            for j in range(1, Nt):
                t_mean = 0.5 * (vl[j] + vr[j])
                u = (1 - t_mean) * sb[i] + t_mean * st[i]
                v = (1 - s_mean) * vl[j] + s_mean * vr[j]
                for d in range(3):
                    Q[i, j, d] = (
                        (1 - v) * Q[i, 0, d] + v * Q[i, Nt, d] + (1 - u) * Q[0, j, d] + u * Q[Ns, j, d]
                        - ((1 - u) * (1 - v) * Q[0, 0, d] + u * (1 - v) * Q[Ns, 0, d] + (1 - u) * v * Q[0, Nt, d] + u * v * Q[Ns, Nt, d])
                    )


@nb.njit(cache=True, error_model="numpy", inline="always")
def _mean_edge_params(e0, e1, e2, e3, tmp, out):
    """Mean of the normalised arc-length parameters of four parallel edges."""
    _arc_params(e0, out)
    _arc_params(e1, tmp)
    for i in range(len(out)):
        out[i] = out[i] + tmp[i]
    _arc_params(e2, tmp)
    for i in range(len(out)):
        out[i] = out[i] + tmp[i]
    _arc_params(e3, tmp)
    for i in range(len(out)):
        out[i] = (out[i] + tmp[i]) / 4


@nb.njit(cache=True, error_model="numpy")
def _tfi_one(Q):
    """Transfinite interpolation of one lattice (I+1, J+1, K+1, 3) in place (interior only):
    the Boolean sum of the three directional projectors W1 (along i), W2 (adds j), W3 (adds k)."""
    I, J, K = Q.shape[0] - 1, Q.shape[1] - 1, Q.shape[2] - 1
    u, v, w = np.empty(I + 1), np.empty(J + 1), np.empty(K + 1)
    _mean_edge_params(Q[:, 0, 0], Q[:, 0, K], Q[:, J, 0], Q[:, J, K], np.empty(I + 1), u)
    _mean_edge_params(Q[0, :, 0], Q[0, :, K], Q[I, :, 0], Q[I, :, K], np.empty(J + 1), v)
    _mean_edge_params(Q[0, 0, :], Q[0, J, :], Q[I, 0, :], Q[I, J, :], np.empty(K + 1), w)
    # W2 on the faces k = 0 and k = K (needed by W3), W1 on j = 0 and j = J (needed by W2)
    W2lo = np.empty((I + 1, J + 1, 3))
    W2hi = np.empty((I + 1, J + 1, 3))
    for i in range(1, I):
        for d in range(3):
            _w2_row(Q, u, v, i, 0, d, W2lo[i, :, d])
            _w2_row(Q, u, v, i, K, d, W2hi[i, :, d])
    row = np.empty(J + 1)
    for i in range(1, I):
        for kk in range(1, K):
            for d in range(3):
                _w2_row(Q, u, v, i, kk, d, row)
                for j in range(1, J):
                    Q[i, j, kk, d] = row[j] + ((1 - w[kk]) * (Q[i, j, 0, d] - W2lo[i, j, d]) + w[kk] * (Q[i, j, K, d] - W2hi[i, j, d]))


@nb.njit(cache=True, error_model="numpy", inline="always")
def _w2_row(Q, u, v, i, kk, d, out):
    """``out[j]`` = W2 (the projectors along i and j) at lattice ``(i, j, kk)``, coordinate d,
    for the interior j."""
    I, J = Q.shape[0] - 1, Q.shape[1] - 1
    a0 = (1 - u[i]) * Q[0, 0, kk, d] + u[i] * Q[I, 0, kk, d]
    aJ = (1 - u[i]) * Q[0, J, kk, d] + u[i] * Q[I, J, kk, d]
    for j in range(1, J):
        W1 = (1 - u[i]) * Q[0, j, kk, d] + u[i] * Q[I, j, kk, d]
        out[j] = W1 + ((1 - v[j]) * (Q[i, 0, kk, d] - a0) + v[j] * (Q[i, J, kk, d] - aJ))


@nb.njit(parallel=True, cache=True, error_model="numpy")
def _tfi_kernel(P):
    """Transfinite interpolation of lattices (m, I+1, J+1, K+1, 3) in place."""
    for b in nb.prange(P.shape[0]):
        _tfi_one(P[b])


@nb.njit(parallel=True, cache=True, error_model="numpy")
def _regrade_kernel(P, lattices, inner_before, inner_after, wall_first, h1, n, ref):
    """:func:`_regrade_one` on the lattices ``P[lattices]`` (P: (m, A, k, C, 3))."""
    for q in nb.prange(len(lattices)):
        b = lattices[q]
        _regrade_one(P[b], inner_before, inner_after, wall_first[b], h1[b], n, ref)


@nb.njit(cache=True, error_model="numpy")
def _regrade_one(Q, inner_before, inner_after, wall_first, h1, n, ref):
    """Re-space the lines ``Q[a, :, c]`` (Q: (A, k, C, 3)) of one lattice whose indices a and
    c are interior: geometric element boundaries with first element ``h1`` from the wall
    end, high-order nodes at ``ref`` inside each element, placed by arc length."""
    A, k, C = Q.shape[0], Q.shape[1], Q.shape[2]
    p = len(ref)
    line = np.empty((k, 3))
    s = np.empty(k)
    t = np.empty(n + 1)
    target = np.empty(k)
    new = np.empty((k, 3))
    for a in range(A):
        if not inner_before[a]:
            continue
        for c in range(C):
            if not inner_after[c]:
                continue
            for i in range(k):  # wall end first
                src = i if wall_first else k - 1 - i
                for d in range(3):
                    line[i, d] = Q[a, src, c, d]
            _arc_lengths(line, s)
            length = s[k - 1]
            ratio = _ratio(h1, length, n)
            t[0] = 0.0
            for e in range(n):
                t[e + 1] = t[e] + ratio ** float(e)
            total = t[n]
            for e in range(n + 1):
                t[e] = t[e] / total
            for e in range(n):
                for r in range(p):
                    target[e * p + r] = (t[e] + (t[e + 1] - t[e]) * ref[r]) * length
            target[n * p] = t[n] * length
            _interp_line(target, s, line, new)
            for i in range(k):
                dst = i if wall_first else k - 1 - i
                for d in range(3):
                    Q[a, dst, c, d] = new[i, d]


@nb.njit(parallel=True, cache=True, error_model="numpy")
def _fill_blocks_kernel(X, L, layer, wall_first, h1, n3, ref, before0, after0, before1, after1, before2, after2):
    """Fill the block lattices ``L`` (m, I+1, J+1, K+1) of node ids in the node array X in place:
    gather each lattice, transfinite interpolation, re-spacing of the boundary-layer lines
    along the axes flagged in ``layer`` (m, 3), scatter of the interior nodes."""
    m, I1, J1, K1 = L.shape
    for b in nb.prange(m):
        Q = np.empty((I1, J1, K1, 3))
        for i in range(I1):
            for j in range(J1):
                for k in range(K1):
                    for d in range(3):
                        Q[i, j, k, d] = X[L[b, i, j, k], d]
        _tfi_one(Q)
        if layer[b, 0]:
            _regrade_one(Q.reshape((1, I1, J1 * K1, 3)), before0, after0, wall_first[b, 0], h1[b, 0], n3[0], ref)
        if layer[b, 1]:
            _regrade_one(Q.reshape((I1, J1, K1, 3)), before1, after1, wall_first[b, 1], h1[b, 1], n3[1], ref)
        if layer[b, 2]:
            _regrade_one(Q.reshape((I1 * J1, K1, 1, 3)), before2, after2, wall_first[b, 2], h1[b, 2], n3[2], ref)
        for i in range(1, I1 - 1):
            for j in range(1, J1 - 1):
                for k in range(1, K1 - 1):
                    for d in range(3):
                        X[L[b, i, j, k], d] = Q[i, j, k, d]


@nb.njit(parallel=True, cache=True, error_model="numpy")
def _cells_kernel(L, p, out):
    """Element node ids of block lattices L (m, I+1, J+1, K+1) into out (m nk nj ni, (p+1)^3):
    elements ordered (block, ek, ej, ei), nodes in tensor order (i fastest)."""
    m = L.shape[0]
    ni, nj, nk = (L.shape[1] - 1) // p, (L.shape[2] - 1) // p, (L.shape[3] - 1) // p
    for b in nb.prange(m):
        for ek in range(nk):
            for ej in range(nj):
                for ei in range(ni):
                    e = ((b * nk + ek) * nj + ej) * ni + ei
                    c = 0
                    for kk in range(p + 1):
                        for jj in range(p + 1):
                            for ii in range(p + 1):
                                out[e, c] = L[b, ei * p + ii, ej * p + jj, ek * p + kk]
                                c += 1
