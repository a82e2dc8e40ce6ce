"""Tracing a voxel skeleton into a graph of branches (stage 3).

26-connected voxels; clusters of junction voxels collapse into one node, chains
of degree-2 voxels become ordered branches. The chains are ordered by sparse-graph
searches, without a per-voxel Python loop.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components, dijkstra

from .branch_graph import BranchGraph


#: The 13 "forward" offsets of the 26-neighbourhood (the other 13 are their negatives).
_HALF_NEIGHBOURHOOD = np.array(
    [(a, b, c) for a in (-1, 0, 1) for b in (-1, 0, 1) for c in (-1, 0, 1) if (a, b, c) > (0, 0, 0)],
    dtype=np.int64,
)



def voxel_adjacency(ijk: np.ndarray) -> sp.csr_matrix:
    """Symmetric 26-neighbourhood adjacency of voxels ``(k, 3)`` (integer indices)."""
    ijk = np.asarray(ijk, np.int64)
    k = len(ijk)
    if k == 0:
        return sp.csr_matrix((0, 0))
    base = ijk.min(axis=0) - 1
    dims = ijk.max(axis=0) - base + 2
    key = np.ravel_multi_index((ijk - base).T, dims)
    order = np.argsort(key)
    sorted_key = key[order]
    rows, cols = [], []
    for off in _HALF_NEIGHBOURHOOD:
        nb = np.ravel_multi_index((ijk - base + off).T, dims)
        pos = np.searchsorted(sorted_key, nb)
        pos = np.minimum(pos, k - 1)
        found = sorted_key[pos] == nb
        rows.append(np.flatnonzero(found))
        cols.append(order[pos[found]])
    r, c = np.concatenate(rows), np.concatenate(cols)
    data = np.ones(2 * len(r), dtype=np.int8)
    return sp.csr_matrix((data, (np.r_[r, c], np.r_[c, r])), shape=(k, k))



@dataclass
class TracedSkeleton:
    """Voxel skeleton split into nodes and branches.

    Attributes
    ----------
    node_voxels : list of int arrays
        Voxels of each node (a junction cluster, an end voxel, or a voxel cut out
        of an isolated cycle).
    branch_ends : (b, 2) int array
        Node at the start and at the end of each branch.
    branch_voxels : list of int arrays
        Interior voxels of each branch, ordered from its start node to its end node
        (may be empty when two nodes touch).
    """

    node_voxels: list
    branch_ends: np.ndarray
    branch_voxels: list



def trace_branches(adjacency: sp.csr_matrix) -> TracedSkeleton:
    """Split a voxel skeleton graph into nodes and ordered branches.

    Voxels with other than two neighbours are node voxels; 26-connected clusters of
    junction voxels (three or more neighbours) form one node (staircase steps and
    thick crossings make such clusters). The remaining chains of two-neighbour
    voxels are the branches. An isolated cycle without any node voxel is cut at
    one voxel. Chains are ordered by a single breadth-first search from a virtual
    source linked to one end of every chain, so no per-voxel Python loop is needed.
    """
    adjacency = sp.csr_matrix(adjacency)
    k = adjacency.shape[0]
    degree = np.diff(adjacency.indptr)
    is_node = degree != 2
    # an isolated cycle has no node voxel: cut it at its first voxel
    n_comp, comp = connected_components(adjacency, directed=False)
    has_node = np.zeros(n_comp, bool)
    has_node[comp[is_node]] = True
    for c in np.flatnonzero(~has_node):
        is_node[np.flatnonzero(comp == c)[0]] = True
    # nodes: clusters of junction voxels; every other node voxel alone
    node_of = np.full(k, -1, np.int64)
    junction = is_node & (degree >= 3)
    jidx = np.flatnonzero(junction)
    n_j, jlab = connected_components(adjacency[jidx][:, jidx], directed=False)
    node_of[jidx] = jlab
    others = np.flatnonzero(is_node & ~junction)
    node_of[others] = n_j + np.arange(len(others))
    n_nodes = n_j + len(others)
    node_voxels = _group(node_of, n_nodes)

    chain = np.flatnonzero(~is_node)
    coo = sp.triu(adjacency, k=1).tocoo()
    a, b = coo.row, coo.col
    # direct node-node contacts between different nodes become empty branches
    both = is_node[a] & is_node[b] & (node_of[a] != node_of[b])
    direct = np.unique(np.sort(np.stack([node_of[a[both]], node_of[b[both]]], axis=1), axis=1), axis=0)
    ends_list = [direct.reshape(-1, 2)]
    voxels_list: list = [np.zeros(0, np.int64)] * len(ends_list[0])
    if len(chain):
        sub = adjacency[chain][:, chain]
        n_chains, chain_of = connected_components(sub, directed=False)
        chain_degree = np.diff(sub.indptr)
        # first end of every chain: its lowest-index voxel with fewer than two chain neighbours
        end_voxel = np.flatnonzero(chain_degree < 2)
        first = np.full(n_chains, -1, np.int64)
        order_end = end_voxel[np.lexsort((end_voxel, chain_of[end_voxel]))]
        starts = np.unique(chain_of[order_end], return_index=True)[1]
        first[chain_of[order_end[starts]]] = order_end[starts]
        # BFS depth from a virtual source attached to every first voxel
        m = len(chain)
        src = sp.csr_matrix((np.ones(n_chains), (np.zeros(n_chains, np.int64), first)), shape=(1, m))
        graph = sp.bmat([[sub, src.T], [src, None]], format="csr")
        depth = dijkstra(graph, directed=False, indices=m, unweighted=True)[:m]
        order = np.lexsort((depth, chain_of))
        bounds = np.searchsorted(chain_of[order], np.arange(n_chains + 1))
        # node neighbours of chain voxels (end voxels only have them)
        node_nb = adjacency[chain].tocoo()
        mask_nb = is_node[node_nb.col]
        rows, nodes_touch = node_nb.row[mask_nb], node_of[node_nb.col[mask_nb]]
        srt = np.lexsort((nodes_touch, rows))
        rows, nodes_touch = rows[srt], nodes_touch[srt]
        row_start = np.searchsorted(rows, np.arange(m + 1))
        for c in range(n_chains):
            seq = order[bounds[c] : bounds[c + 1]]
            f, l = seq[0], seq[-1]
            at_f = nodes_touch[row_start[f] : row_start[f + 1]]
            at_l = nodes_touch[row_start[l] : row_start[l + 1]]
            if f == l:
                if len(at_f) < 2:
                    continue
                u, v = at_f[0], at_f[1]
            else:
                if len(at_f) == 0 or len(at_l) == 0:
                    continue
                u, v = at_f[0], at_l[0]
            ends_list.append(np.array([[u, v]]))
            voxels_list.append(chain[seq])
    branch_ends = np.concatenate(ends_list).astype(np.int64).reshape(-1, 2)
    return TracedSkeleton(node_voxels, branch_ends, voxels_list)



def _group(labels: np.ndarray, n: int) -> list:
    """Indices of ``labels == i`` for i < n (labels < 0 ignored)."""
    idx = np.flatnonzero(labels >= 0)
    order = idx[np.argsort(labels[idx], kind="stable")]
    cuts = np.searchsorted(labels[order], np.arange(n + 1))
    return [order[cuts[i] : cuts[i + 1]] for i in range(n)]



def build_branch_graph(traced: TracedSkeleton, points: np.ndarray, radii: np.ndarray) -> BranchGraph:
    """A :class:`BranchGraph` from a traced voxel skeleton.

    ``points`` and ``radii`` are the world positions and SDF values of the voxels.
    A junction cluster is represented by its voxel of largest radius (the centre of
    the largest inscribed ball).
    """
    graph = BranchGraph()
    ids = []
    for voxels in traced.node_voxels:
        best = voxels[np.argmax(radii[voxels])]
        ids.append(graph.add_node(points[best], radii[best]))
    for (u, v), voxels in zip(traced.branch_ends, traced.branch_voxels):
        graph.add_branch(ids[u], ids[v], points[voxels], radii[voxels])
    return graph

