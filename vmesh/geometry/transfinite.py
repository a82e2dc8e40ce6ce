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

import numpy as np

from ..blocks import (
    AXIS_ALONG,
    AXIS_AROUND,
    AXIS_CORE,
    AXIS_LAYER,
    AXIS_RING,
    FACE_WALL,
    BlockStructure,
)
from .transfinite_curves import along_tangents, curved_edges, edge_turns, hermite_edges
from .transfinite_kernels import (  # noqa: F401  (coons_patch, transfinite_volume, _interp_rows: public here)
    _coons_kernel,
    _fill_blocks_kernel,
    _interp_rows,
    _ratio_kernel,
    _regrade_kernel,
    coons_patch,
    transfinite_volume,
)
from .transfinite_lattice import (  # noqa: F401  (Topology, block_topology, canonical_faces: public here)
    Numbering,
    Topology,
    _block_lattice_ids,
    _face_lattice_ids,
    _row_lookup,
    block_topology,
    canonical_faces,
    connectivity,
    number_nodes,
)

#: wall edge nodes follow their ray to the wall only when it is at most this many times
#: longer than their distance to the wall (otherwise the closest point is used)
RAY_TRUST = 1.5
#: rays search the wall up to this many times the node's distance to it (and a radius at most):
#: a wall much farther along the normal than the closest wall point lies beyond a concavity
RAY_SEARCH = 32.0
#: wall-face nodes whose ray finds no wall within a radius are projected only when they are
#: closer to the wall than this fraction of the radius (otherwise they span an opening)
OPENING_DEPTH = 0.25


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
    curved_sections : bool
        Curve the core/ring and ring/boundary-layer interfaces of the cross-sections so
        that the angles at their corners balance (:mod:`~vmesh.geometry.transfinite_curves`).
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
    curved_sections: bool = False

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
    boundary_local_face: np.ndarray  # (k,) face of its block (HEX_FACES order) each boundary face lies on


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


@dataclass
class _Fill:
    """What the stages of :func:`mesh_blocks` share: the inputs, the block topology and
    numbering, per-edge kinds and radii, and the node positions being filled."""

    blocks: BlockStructure
    ref: Refinement
    project: object
    signed_distance: object
    intersect_lines: object
    V: np.ndarray  # (nv, 3) block corners (wall corners on this wall)
    topo: Topology
    num: Numbering
    edge_kind: np.ndarray  # (E,) axis kind of each unique edge
    edge_radius: np.ndarray  # (E,) local radius of each unique edge
    X: np.ndarray  # (n, 3) node positions (NaN until set)
    on_wall: np.ndarray  # (n,) bool


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
    topo = block_topology(blocks)
    num = number_nodes(topo, requested_counts(blocks, topo, ref), p, len(V))
    E = len(topo.edges)
    edge_kind = np.full(E, -1)
    edge_radius = np.zeros(E)
    axis_of_edge = np.repeat(np.arange(3), 4)
    edge_kind[topo.block_edge.ravel()] = blocks.axis_kind[:, axis_of_edge].ravel()
    edge_radius[topo.block_edge.ravel()] = np.repeat(blocks.block_radius, 12)
    X = np.full((num.n_nodes, 3), np.nan)
    on_wall = np.zeros(num.n_nodes, bool)
    X[: len(V)] = V
    on_wall[: len(V)] = blocks.vertex_on_surface
    fill = _Fill(blocks, ref, project, signed_distance, intersect_lines, V, topo, num, edge_kind, edge_radius, X, on_wall)
    tick(0.05, "edges")
    _fill_edges(fill)
    tick(0.3, "faces")
    _fill_faces(fill)
    tick(0.6, "blocks")
    lattices = _fill_volumes(fill)
    if np.isnan(X).any():
        raise RuntimeError("transfinite meshing left nodes unset (inconsistent block topology)")
    tick(0.85, "connectivity")
    cells, cell_block, bfaces, bids, bcells, blocal = connectivity(blocks, lattices, p)
    tick(1.0, "done")
    return StructuredMesh(
        points=X,
        cells=cells,
        order=p,
        cell_block=cell_block,
        boundary_faces=bfaces,
        boundary_ids=bids,
        boundary_cells=bcells,
        on_wall=on_wall,
        block_counts=num.block_n,
        boundary_local_face=blocal,
    )


def _edge_on_wall(topo: Topology) -> np.ndarray:
    """(E,) bool: the unique edges of wall faces."""
    fc = topo.faces[topo.face_boundary == FACE_WALL]
    pairs = np.concatenate([np.sort(fc[:, [0, 1]], 1), np.sort(fc[:, [2, 3]], 1), np.sort(fc[:, [0, 2]], 1), np.sort(fc[:, [1, 3]], 1)])
    out = np.zeros(len(topo.edges), bool)
    if len(pairs):
        idx = _row_lookup(topo.edges, pairs)
        out[idx[idx >= 0]] = True
    return out


def _fill_edges(fill: _Fill) -> None:
    """Nodes along every unique edge: uniform or graded towards the wall, order-p nodes
    inside elements, wall edges moved onto the wall along their normal and re-spaced."""
    blocks, ref, topo, num, V = fill.blocks, fill.ref, fill.topo, fill.num, fill.V
    p = int(ref.order)
    signed_distance = fill.signed_distance
    wall_end_first = blocks.vertex_on_surface[topo.edges[:, 0]]
    wall_end_last = blocks.vertex_on_surface[topo.edges[:, 1]]
    edge_on_wall = _edge_on_wall(topo)
    wall_face = topo.face_boundary == FACE_WALL
    edge_normal = _wall_edge_normals(blocks, topo, V, wall_face) if signed_distance is not None else None
    turn, bulge = edge_turns(blocks, topo, V) if ref.curved_sections else (np.zeros((len(topo.edges), 2)), None)
    tangent, along = along_tangents(blocks, topo, V, fill.project) if ref.curved_sections else (None, np.zeros(len(topo.edges), bool))
    for n in np.unique(num.n_edge):
        sel = np.flatnonzero(num.n_edge == n)
        a, b = V[topo.edges[sel, 0]], V[topo.edges[sel, 1]]
        length = np.linalg.norm(b - a, axis=1)
        ratio = np.ones(len(sel))
        graded = (fill.edge_kind[sel] == AXIS_LAYER) & (wall_end_first[sel] ^ wall_end_last[sel])
        if graded.any() and n > 1 and (ref.first_layer or ref.growth):
            if ref.first_layer:
                q = geometric_ratio(ref.first_height(fill.edge_radius[sel][graded]), length[graded], int(n))
            else:
                q = np.full(graded.sum(), float(ref.growth))
            # sizes grow away from the wall: from t = 0 when the wall is at the first vertex
            ratio[graded] = np.where(wall_end_first[sel][graded], q, 1.0 / q)
        t = with_order(element_boundaries(int(n), ratio), p, ref.nodes)  # (m, N+1)
        pts = a[:, None, :] + t[:, :, None] * (b - a)[:, None, :]
        wall = edge_on_wall[sel]
        curved = np.any(turn[sel] != 0, axis=1) & ~wall
        if curved.any():
            pts[curved] = curved_edges(a[curved], b[curved], t[curved], turn[sel[curved]], bulge[sel[curved]])
        bend = along[sel]
        if bend.any():
            pts[bend] = hermite_edges(a[bend], b[bend], t[bend], tangent[sel[bend], 0], tangent[sel[bend], 1])
        if wall.any():
            if edge_normal is not None and pts.shape[1] > 2:  # edges of one linear element have no inner nodes
                inner_pts = pts[wall, 1:-1]
                k = inner_pts.shape[1]
                flat = inner_pts.reshape(-1, 3)
                f0 = signed_distance(flat)
                # the edge normal points out of the vessel: inside nodes move outward, outside ones inward
                reach = np.minimum(np.repeat(fill.edge_radius[sel[wall]], k), RAY_SEARCH * np.abs(f0))
                moved, _ = fill.intersect_lines(flat, np.repeat(edge_normal[sel[wall]], k, axis=0), reach, np.where(f0 >= 0, 1, -1))
                pts[wall, 1:-1] = _trust_rays(moved, flat, f0).reshape(-1, k, 3)
            pts[wall] = _project_curves(pts[wall], t[wall], fill.project)
        ids = (num.edge_off[sel][:, None] + np.arange(int(n) * p - 1)[None, :]).ravel()
        fill.X[ids] = pts[:, 1:-1].reshape(-1, 3)
        fill.on_wall[ids] = np.repeat(wall, int(n) * p - 1)


def _fill_faces(fill: _Fill) -> None:
    """Coons patches on every unique face (boundary-layer lines re-spaced to the first-layer
    height); wall faces moved onto the wall along their normals and projected."""
    blocks, ref, topo, num = fill.blocks, fill.ref, fill.topo, fill.num
    p = int(ref.order)
    fc = topo.faces
    wall_face = topo.face_boundary == FACE_WALL
    face_radius = np.zeros(len(fc))
    face_radius[topo.block_face.ravel()] = np.repeat(blocks.block_radius, 6)
    face_out = _wall_face_outward(blocks, topo, fill.V)
    for Ns, Nt in sorted(set(zip(num.face_Ns.tolist(), num.face_Nt.tolist()))):
        sel = np.flatnonzero((num.face_Ns == Ns) & (num.face_Nt == Nt))
        if Ns < 2 or Nt < 2:
            continue
        grid = _face_lattice_ids(fc[sel], Ns, Nt, topo, num.edge_off, num.N_edge)  # (m, Ns+1, Nt+1), interior -1
        m = len(sel)
        inner_ids = num.face_off[sel][:, None] + np.arange((Ns - 1) * (Nt - 1))[None, :]
        grid[:, 1:-1, 1:-1] = inner_ids.reshape(m, Ns - 1, Nt - 1)
        P = fill.X[grid]  # boundary known; interior filled in place (a fresh array)
        _coons_kernel(P)
        if ref.first_layer:
            for axis, (c0, c1) in ((1, (0, 1)), (2, (0, 2))):
                e = _row_lookup(topo.edges, np.sort(fc[sel][:, [c0, c1]], 1))
                layer = fill.edge_kind[e] == AXIS_LAYER
                if layer.any():
                    wall_first = blocks.vertex_on_surface[fc[sel][layer, c0]]
                    h1 = ref.first_height(fill.edge_radius[e[layer]])
                    _regrade_inplace(P, axis, layer, wall_first, h1, int(num.n_edge[e[layer][0]]), p, ref.nodes)
        wall = wall_face[sel]
        hit = None
        if wall.any():
            hit = _face_to_wall(fill, P, wall, face_out[sel[wall]], face_radius[sel][wall])
        fill.X[inner_ids.ravel()] = P[:, 1:-1, 1:-1].reshape(-1, 3)
        wall_nodes = np.repeat(wall, (Ns - 1) * (Nt - 1))
        if hit is not None:
            wall_nodes[wall_nodes] = hit
        fill.on_wall[inner_ids.ravel()] = wall_nodes


def _trust_rays(moved: np.ndarray, start: np.ndarray, f0: np.ndarray) -> np.ndarray:
    """Ray hits ``moved`` from ``start`` (signed distances ``f0``), with the start kept where
    the ray ran much farther than the distance to the wall: it passed a concave place (the
    saddle beside a junction, a vessel mouth) and landed far from where the edge or face
    runs; the closest point (the projection that follows) is nearer and keeps the node on
    its side of the fold."""
    far = np.linalg.norm(moved - start, axis=1) > RAY_TRUST * np.abs(f0) + 1e-9
    return np.where(far[:, None], start, moved)


def _face_to_wall(fill: _Fill, P: np.ndarray, wall: np.ndarray, out: np.ndarray, radius: np.ndarray) -> np.ndarray:
    """Move the interior nodes of the wall faces ``P[wall]`` onto the wall in place; returns
    which of them found it (the others span an opening and stay on their patch)."""
    Ns, Nt = P.shape[1] - 1, P.shape[2] - 1
    Pw = P[wall]
    interior = Pw[:, 1:-1, 1:-1].reshape(-1, 3)
    hit = np.ones(len(interior), bool)
    if fill.signed_distance is not None:
        normal = _patch_normals(Pw)  # (k, Ns-1, Nt-1, 3)
        # oriented out of the vessel: inside nodes move outward, outside ones inward
        flip = np.einsum("ijkl,il->ijk", normal, out) < 0
        normal = np.where(flip[..., None], -normal, normal).reshape(-1, 3)
        reach = np.repeat(radius, (Ns - 1) * (Nt - 1))
        f0 = fill.signed_distance(interior)
        moved, hit = fill.intersect_lines(interior, normal, np.minimum(reach, RAY_SEARCH * np.abs(f0)), np.where(f0 >= 0, 1, -1))
        interior = _trust_rays(moved, interior, f0)
        # no wall along the normal within a radius: the face spans an opening (the mouth
        # of a vessel without skeleton). The closest wall point is then on the opening's
        # rim, far to the side, and would fold the layer: keep the patch point instead.
        # Points already close to the wall are projected as before.
        hit |= np.abs(f0) < OPENING_DEPTH * reach
    projected = fill.project(interior)
    P[wall, 1:-1, 1:-1] = np.where(hit[:, None], projected, interior).reshape(-1, Ns - 1, Nt - 1, 3)
    return hit


def _fill_volumes(fill: _Fill) -> dict:
    """Transfinite interpolation inside every block (boundary-layer lines re-spaced);
    returns ``{lattice size: (blocks, node ids)}``."""
    blocks, ref, topo, num = fill.blocks, fill.ref, fill.topo, fill.num
    p = int(ref.order)
    H = blocks.hexes
    lattices = {}
    groups = {}
    for b, key in enumerate(map(tuple, num.block_N.tolist())):
        groups.setdefault(key, []).append(b)
    for key, members in groups.items():
        members = np.asarray(members)
        L = _block_lattice_ids(members, key, H, topo, num.edge_off, num.N_edge, num.face_off, num.face_Ns, num.face_Nt, num.vol_off)
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
            _fill_blocks_kernel(fill.X, L, layer, wall_first, h1, n3, reference_points(p, ref.nodes)[:-1].copy(), *masks)
        lattices[key] = (members, L)
    return lattices


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

