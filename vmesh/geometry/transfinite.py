"""Transfinite meshing of a block structure into one conforming hexahedral mesh.

Every block is filled with a structured lattice of nodes:

1. **Edges.** Block edges are grouped into classes that must carry the same number of
   elements (the four parallel edges of every block, transitively); each class gets
   the largest count its members ask for. Nodes are distributed along each edge
   (uniform, or geometric towards the wall in the boundary layer), mesh order ``p``
   adds Gauss-Lobatto or equispaced nodes inside each element, and edges on the wall
   are projected onto the surface and re-spaced by arc length.
2. **Faces.** Coons patches from the four edges of each block face; faces on the wall
   are projected again.
3. **Blocks.** Transfinite interpolation from the six faces fills each block.

Nodes on shared corners, edges and faces are numbered once through the block
topology (a canonical orientation per edge and face), so the mesh is conforming by
construction, not by merging nearby points. All work is vectorised over groups of
edges, faces and blocks of the same size.
"""

from __future__ import annotations

from dataclasses import dataclass

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
        (``None``: uniform spacing).
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
    """Ratio q with ``first * (q**n - 1) / (q - 1) = length`` for arrays of edges (bisection).

    Returns 1 where uniform spacing already gives elements thinner than ``first``.
    """
    first = np.asarray(first, float)
    length = np.asarray(length, float)
    target = length / np.maximum(first, 1e-300)
    lo = np.ones_like(target)
    hi = np.full_like(target, 2.0)
    # grow the bracket where needed
    for _ in range(60):
        s = (hi**n - 1) / (hi - 1)
        grow = s < target
        if not grow.any():
            break
        hi = np.where(grow, hi * 2, hi)
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        s = np.where(np.abs(mid - 1) < 1e-12, n, (mid**n - 1) / np.maximum(mid - 1, 1e-300))
        too_big = s > target
        hi = np.where(too_big, mid, hi)
        lo = np.where(too_big, lo, mid)
    q = 0.5 * (lo + hi)
    return np.where(target <= n, 1.0, q)


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
    edges, inv = np.unique(key, axis=0, return_inverse=True)
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
    fkeys, first, finv = np.unique(fkey, axis=0, return_index=True, return_inverse=True)
    block_face = finv.reshape(nb, 6)
    g4 = corner_ids.reshape(-1, 4)[first]  # a representative corner grid per unique face
    faces = canonical_faces(g4)
    fb = np.full(len(fkeys), FACE_INTERIOR, np.int64)
    bf = blocks.face_boundary.reshape(-1)
    on_boundary = bf != FACE_INTERIOR
    fb[finv.ravel()[on_boundary]] = bf[on_boundary]
    return Topology(edges, block_edge, edge_class, faces, block_face, fb)


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
    nb = len(H)
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
                q = geometric_ratio(ref.first_layer * edge_radius[sel][graded], length[graded], int(n))
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
        P = coons_patch(X[grid])  # boundary known; interior filled
        if ref.first_layer:
            for axis, (c0, c1) in ((1, (0, 1)), (2, (0, 2))):
                e = _row_lookup(topo.edges, np.sort(fc[sel][:, [c0, c1]], 1))
                layer = edge_kind[e] == AXIS_LAYER
                if layer.any():
                    wall_first = blocks.vertex_on_surface[fc[sel][layer, c0]]
                    h1 = ref.first_layer * edge_radius[e[layer]]
                    P[layer] = regrade_lines(P[layer], axis, wall_first, h1, int(n_edge[e[layer][0]]), p, ref.nodes)
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
            P = transfinite_volume(X[L])
            if ref.first_layer:
                kinds = blocks.axis_kind[members]
                for axis in range(3):
                    layer = kinds[:, axis] == AXIS_LAYER
                    if layer.any():
                        c1 = [1, 3, 4][axis]  # corner next to corner 0 along this axis
                        wall_first = blocks.vertex_on_surface[H[members[layer], 0]] & ~blocks.vertex_on_surface[H[members[layer], c1]]
                        h1 = ref.first_layer * blocks.block_radius[members[layer]]
                        P[layer] = regrade_lines(P[layer], axis + 1, wall_first, h1, key[axis] // p, p, ref.nodes)
            X[L[:, 1:-1, 1:-1, 1:-1].reshape(-1)] = P[:, 1:-1, 1:-1, 1:-1].reshape(-1, 3)
        lattices[key] = (members, L)
    if np.isnan(X).any():
        raise RuntimeError("transfinite meshing left nodes unset (inconsistent block topology)")

    # --- elements and boundary faces ------------------------------------------
    tick(0.85, "connectivity")
    cells, cell_block, bfaces, bids, bcells = [], [], [], [], []
    n_cells = 0
    for key, (members, L) in lattices.items():
        ni, nj, nk = (k // p for k in key)
        # element (ei, ej, ek) spans lattice [ei p : ei p + p + 1] etc.
        ar = np.arange(p + 1)
        ii = (np.arange(ni)[:, None] * p + ar[None, :])  # (ni, p+1)
        jj = (np.arange(nj)[:, None] * p + ar[None, :])
        kk = (np.arange(nk)[:, None] * p + ar[None, :])
        # tensor order with i fastest: index = i + (p+1) (j + (p+1) k)
        E6 = L[:, ii[None, None, :, None, None, :], jj[None, :, None, None, :, None], kk[:, None, None, :, None, None]]
        # E6 axes: (m, ek, ej, ei, kk, jj, ii)
        c = E6.reshape(len(members), nk * nj * ni, (p + 1) ** 3)
        elem_index = n_cells + np.arange(len(members) * nk * nj * ni).reshape(len(members), nk, nj, ni)
        cells.append(c.reshape(-1, (p + 1) ** 3))
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
        cells=np.concatenate(cells),
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
    if n < 2:
        return P
    Q = np.moveaxis(P, axis, -2)  # (m, ..., N+1, 3)
    shape = Q.shape
    m, k = shape[0], shape[-2]
    lines = Q.reshape(m, -1, k, 3)
    flip = ~np.asarray(wall_first, bool)
    lines = np.where(flip[:, None, None, None], lines[:, :, ::-1], lines)  # wall end first
    seg = np.linalg.norm(np.diff(lines, axis=2), axis=3)
    s = np.concatenate([np.zeros(seg.shape[:2] + (1,)), np.cumsum(seg, axis=2)], axis=2)
    length = s[..., -1]
    ratio = geometric_ratio(np.repeat(h1[:, None], lines.shape[1], 1).ravel(), length.ravel(), n)
    target = with_order(element_boundaries(n, ratio), p, kind).reshape(s.shape) * length[..., None]
    flat = lines.reshape(-1, k, 3)
    new = _interp_rows(target.reshape(-1, k), s.reshape(-1, k), flat)
    new = new.reshape(lines.shape)
    new = np.where(flip[:, None, None, None], new[:, :, ::-1], new)
    out = np.moveaxis(new.reshape(shape), -2, axis)
    res = P.copy()
    inner = tuple([slice(None)] + [slice(None) if d == axis else slice(1, -1) for d in range(1, P.ndim - 1)])
    res[inner] = out[inner]
    return res


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
    m, k = xp.shape
    lo = xp[:, :1]
    span = np.maximum(xp[:, -1:] - lo, 1e-300)
    # one sorted array for all rows: row r occupies [3 r, 3 r + 1]
    offset = 3.0 * np.arange(m)[:, None]
    flat_xp = ((xp - lo) / span + offset).ravel()
    flat_x = (np.clip((x - lo) / span, 0.0, 1.0) + offset).ravel()
    idx = np.searchsorted(flat_xp, flat_x, side="right") - 1
    row_start = (np.arange(m) * k)[:, None]
    idx = np.clip(idx.reshape(x.shape) - row_start, 0, k - 2)
    x0 = np.take_along_axis(xp, idx, 1)
    x1 = np.take_along_axis(xp, idx + 1, 1)
    w = np.clip(np.where(x1 > x0, (x - x0) / np.maximum(x1 - x0, 1e-300), 0.0), 0.0, 1.0)
    if fp.ndim == 3:
        idx, w = idx[..., None], w[..., None]
    f0 = np.take_along_axis(fp, idx, 1)
    f1 = np.take_along_axis(fp, idx + 1, 1)
    return f0 + w * (f1 - f0)


# ---------------------------------------------------------------------------
# transfinite interpolation kernels
# ---------------------------------------------------------------------------
def _edge_params(curve: np.ndarray) -> np.ndarray:
    """Normalised arc-length parameters along curves (..., n, 3) -> (..., n)."""
    seg = np.linalg.norm(np.diff(curve, axis=-2), axis=-1)
    s = np.concatenate([np.zeros(seg.shape[:-1] + (1,)), np.cumsum(seg, axis=-1)], axis=-1)
    return s / np.maximum(s[..., -1:], 1e-300)


def coons_patch(P: np.ndarray) -> np.ndarray:
    """Fill the interior of lattices (m, Ns+1, Nt+1, 3) from their boundary (Coons patch).

    Blending parameters follow the arc-length spacing of opposite edges, so graded
    edge distributions carry into the face.
    """
    P = P.copy()
    B, T = P[:, :, 0], P[:, :, -1]  # along s at t = 0, 1
    Lf, R = P[:, 0, :], P[:, -1, :]  # along t at s = 0, 1
    sb, st = _edge_params(B), _edge_params(T)  # (m, Ns+1)
    vl, vr = _edge_params(Lf), _edge_params(R)  # (m, Nt+1)
    # blending parameters: linear mix of the opposite edges' spacings
    t_mean = 0.5 * (vl + vr)[:, None, :]
    s_mean = 0.5 * (sb + st)[:, :, None]
    u = ((1 - t_mean) * sb[:, :, None] + t_mean * st[:, :, None])[..., None]
    v = ((1 - s_mean) * vl[:, None, :] + s_mean * vr[:, None, :])[..., None]
    c00, c10, c01, c11 = P[:, :1, :1], P[:, -1:, :1], P[:, :1, -1:], P[:, -1:, -1:]
    inner = (
        (1 - v) * B[:, :, None] + v * T[:, :, None] + (1 - u) * Lf[:, None, :] + u * R[:, None, :]
        - ((1 - u) * (1 - v) * c00 + u * (1 - v) * c10 + (1 - u) * v * c01 + u * v * c11)
    )
    P[:, 1:-1, 1:-1] = inner[:, 1:-1, 1:-1]
    return P


def transfinite_volume(P: np.ndarray) -> np.ndarray:
    """Fill lattices (m, I+1, J+1, K+1, 3) from their six faces (transfinite interpolation).

    Blending parameters along each axis follow the mean spacing of the block's four
    parallel edges.
    """
    P = P.copy()
    # blending parameters from the spacing of the four parallel edges along each axis
    ui = _edge_params(P[:, :, [0, 0, -1, -1], [0, -1, 0, -1]].transpose(0, 2, 1, 3)).mean(axis=1)  # (m, I+1)
    vj = _edge_params(P[:, [0, 0, -1, -1], :, [0, -1, 0, -1]].transpose(1, 0, 2, 3)).mean(axis=1)
    wk = _edge_params(P[:, [0, 0, -1, -1], [0, -1, 0, -1], :]).mean(axis=1)
    u = ui[:, :, None, None, None]
    v = vj[:, None, :, None, None]
    w = wk[:, None, None, :, None]
    # Boolean sum of the three directional projectors (equal to the full TFI formula for
    # separable blending functions, with a third of the array operations)
    W = (1 - u) * P[:, :1] + u * P[:, -1:]
    W += (1 - v) * (P[:, :, :1] - W[:, :, :1]) + v * (P[:, :, -1:] - W[:, :, -1:])
    W += (1 - w) * (P[:, :, :, :1] - W[:, :, :, :1]) + w * (P[:, :, :, -1:] - W[:, :, :, -1:])
    inner = W
    P[:, 1:-1, 1:-1, 1:-1] = inner[:, 1:-1, 1:-1, 1:-1]
    return P
