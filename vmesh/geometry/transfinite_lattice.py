"""Block topology and node numbering of the transfinite mesher.

Unique edges and faces of a block structure with canonical orientations, the global
numbering of the lattice nodes (block corners, then edge, face and block interiors), the
lattice node ids of faces and blocks, and the elements and boundary faces that the block
lattices make. See :mod:`vmesh.geometry.transfinite`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from ..blocks import FACE_INTERIOR, HEX_CORNERS, HEX_EDGES, BlockStructure
from .transfinite_kernels import _cells_kernel

# local faces in HEX_FACES order: (fixed axis, fixed value); free axes are the other two, ascending
FACE_AXES = [(0, 0), (0, 1), (1, 0), (1, 1), (2, 0), (2, 1)]
_CORNER_INDEX = {tuple(c): n for n, c in enumerate(HEX_CORNERS.tolist())}


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
# numbering
# ---------------------------------------------------------------------------
@dataclass
class Numbering:
    """Lattice sizes and global node-id offsets (block corners first, then the interiors of
    the unique edges, faces and blocks)."""

    n_edge: np.ndarray  # (E,) elements per unique edge
    N_edge: np.ndarray  # (E,) lattice intervals per unique edge (n_edge * p)
    block_n: np.ndarray  # (nb, 3) elements per block along i, j, k
    block_N: np.ndarray  # (nb, 3) lattice intervals per block
    edge_off: np.ndarray  # (E,) id of each edge's first interior node
    face_Ns: np.ndarray  # (F,) lattice intervals along each face's s axis
    face_Nt: np.ndarray  # (F,) ... and t axis
    face_off: np.ndarray  # (F,) id of each face's first interior node
    vol_off: np.ndarray  # (nb,) id of each block's first interior node
    n_nodes: int


def number_nodes(topo: Topology, counts: np.ndarray, p: int, nv: int) -> Numbering:
    """Global numbering of the lattice nodes from the element count of every edge class
    (``counts``), order ``p`` and ``nv`` block corners."""
    n_edge = counts[topo.edge_class]
    N_edge = n_edge * p
    # block lattice sizes along i, j, k (edges 0, 4, 8 run along i, j, k)
    block_n = n_edge[topo.block_edge[:, [0, 4, 8]]]
    block_N = block_n * p
    fc = topo.faces
    edge_off = nv + np.concatenate([[0], np.cumsum(N_edge - 1)])[:-1]
    n_after_edges = nv + int((N_edge - 1).sum())
    face_Ns = N_edge[_row_lookup(topo.edges, np.sort(fc[:, [0, 1]], 1))]
    face_Nt = N_edge[_row_lookup(topo.edges, np.sort(fc[:, [0, 2]], 1))]
    face_off = n_after_edges + np.concatenate([[0], np.cumsum((face_Ns - 1) * (face_Nt - 1))])[:-1]
    n_after_faces = n_after_edges + int(((face_Ns - 1) * (face_Nt - 1)).sum())
    vol_sizes = np.prod(block_N - 1, axis=1)
    vol_off = n_after_faces + np.concatenate([[0], np.cumsum(vol_sizes)])[:-1]
    n_nodes = n_after_faces + int(vol_sizes.sum())
    return Numbering(n_edge, N_edge, block_n, block_N, edge_off, face_Ns, face_Nt, face_off, vol_off, n_nodes)


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



# ---------------------------------------------------------------------------
# elements and boundary faces
# ---------------------------------------------------------------------------
def connectivity(blocks: BlockStructure, lattices: dict, p: int):
    """Elements (tensor order) and boundary faces (outward) of the block lattices.

    ``lattices`` maps a lattice size (I, J, K) to ``(members, L)``: the blocks of that size
    and their node ids. Returns ``cells, cell_block, boundary_faces, boundary_ids,
    boundary_cells, boundary_local_face`` (the last: the face of its block, 0-5 in
    ``HEX_FACES`` order, that each boundary face lies on).
    """
    cell_block, bfaces, bids, bcells, blocal = [], [], [], [], []
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
            blocal.append(np.full(face_nodes.shape[0], f, np.int8))
        n_cells += n_here
    empty = np.zeros((0, (p + 1) ** 2), np.int64)
    return (
        all_cells,
        np.concatenate(cell_block),
        np.concatenate(bfaces) if bfaces else empty,
        np.concatenate(bids) if bids else np.zeros(0, np.int64),
        np.concatenate(bcells) if bcells else np.zeros(0, np.int64),
        np.concatenate(blocal) if blocal else np.zeros(0, np.int8),
    )
