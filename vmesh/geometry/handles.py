"""Thin handles through the lumen: find them by the surface's genus and a short
non-separating loop, and cut them out.

A segmentation artefact can leave a thin strand of outside material crossing a vessel's
lumen (a *pillar*): the surface gets a handle (genus 1) whose short loop goes round the
strand. Section rays end on it and the skeleton skirts it (docs/junctions.md, "Hepatic's
bend is a pillar through a round trunk"). A real loop of the lumen (two vessels that join
again) is a handle too, but its short loop goes round the *lumen*; the two differ by what
lies just outside the loop: lumen all round a pillar, outside all round a vessel.

The short loop is found as in Erickson and Har-Peled (2004): the shortest non-separating
loop through a vertex ``s`` is a fundamental cycle of the shortest-path tree from ``s``; a
cycle is non-separating exactly when its Z2 homology class is not zero, which the
tree-cotree decomposition tells for every non-tree edge at once.
"""

from __future__ import annotations

import numba as nb
import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import breadth_first_order, dijkstra

from .bvh import TriangleBVH
from .sdf import ray_winding_numbers
from .topology import boundary_loops, euler_characteristic, face_normals

# Seeds of the loop search (farthest-point sampled vertices): a loop of length L is found
# from the seed nearest it as a loop of at most L + 2 * spacing, then shortened from the
# vertices of that loop (REFINE_SEEDS of them per round, until no round shortens it).
SEARCH_SEEDS = 48
REFINE_SEEDS = 24
# At most this many handles are examined (each cut lowers the genus by one); 2 * genus
# homology bits must fit an int64 word.
MAX_GENUS = 30
# Edges to the centre of an open end's virtual fan weigh this many times their length, so
# that no short loop crosses an open end.
FAN_WEIGHT = 1e6
# A loop is a pillar's when, in AROUND directions from its centre, the points PUSH_RADII
# loop radii away reach lumen (any of them: the loop may sit at a waist of the strand) in
# at least LUMEN_ALL_ROUND of the directions (a straight strand's two ways on take about
# a tenth of the sphere at 3 radii; a strand's foot on the wall, half of it).
AROUND = 64
PUSH_RADII = (1.5, 2.0, 3.0, 4.0)
LUMEN_ALL_ROUND = 0.75
# The strand is cut out as far as the outside material across it stays thinner than this
# fraction of the lumen beside it (a wall vertex's outward ray leaves the vessel or meets
# another vessel, its inward ray crosses the lumen).
THINNER_THAN_LUMEN = 0.5


def genus(faces: np.ndarray, loops: list | None = None) -> int:
    """Genus of a connected orientable triangle surface (open ends, its boundary ``loops``
    when given, counted as holes: ``2 - chi - b = 2 g``)."""
    loops = boundary_loops(faces) if loops is None else loops
    return (2 - euler_characteristic(faces) - len(loops)) // 2


def _edges(faces: np.ndarray):
    """Unique undirected edges ``(e, 2)`` and the two faces of each ``(e, 2)`` (closed
    manifold surface)."""
    he = np.sort(np.stack([faces, np.roll(faces, -1, axis=1)], axis=-1).reshape(-1, 2), axis=1)
    n = int(faces.max()) + 1
    key = he[:, 0] * n + he[:, 1]
    order = np.argsort(key, kind="stable")
    ukey, first, counts = np.unique(key[order], return_index=True, return_counts=True)
    if np.any(counts != 2):
        return None, None, None
    face_of = order // 3
    pair_faces = np.stack([face_of[first], face_of[first + 1]], axis=1)
    return np.stack([ukey // n, ukey % n], axis=1), pair_faces, (ukey, n)


@nb.njit(cache=True)
def _subtree_xor(order: np.ndarray, parent: np.ndarray, mark: np.ndarray) -> None:
    """XOR every node's ``mark`` into its parent's, leaves first (``order``: parents before
    children), so that each node ends with the XOR over its subtree."""
    for i in range(len(order) - 1, 0, -1):
        node = order[i]
        mark[parent[node]] ^= mark[node]


@nb.njit(cache=True)
def _shortest_nonseparating(pred, dist, indptr, indices, csr_edge, edge_class, edges, length):
    """The non-tree edge whose fundamental cycle in the shortest-path tree ``pred`` is
    shortest among those of non-zero homology class: ``(length, edge)``, ``(inf, -1)`` if
    none. A vertex's class is the XOR of ``edge_class`` along its tree path (set from the
    root down); an edge ``ab`` closes a cycle of class ``H[a] ^ H[b] ^ class(ab)`` (zero
    for the tree's own edges). Unreached vertices (``dist`` inf) take no part."""
    nv = len(pred)
    H = np.zeros(nv, np.int64)
    done = np.zeros(nv, np.bool_)
    stack = np.empty(nv, np.int64)
    for v in range(nv):
        if done[v] or not np.isfinite(dist[v]):
            continue
        k, x = 0, v
        while not done[x] and pred[x] >= 0:
            stack[k] = x
            k += 1
            x = pred[x]
        done[x] = True  # the root (class 0) or a vertex already set
        h = H[x]
        for i in range(k - 1, -1, -1):
            y = stack[i]
            for j in range(indptr[y], indptr[y + 1]):
                if indices[j] == pred[y]:
                    h ^= edge_class[csr_edge[j]]
                    break
            H[y] = h
            done[y] = True
    best, arg = np.inf, -1
    for e in range(len(edges)):
        a, b = edges[e, 0], edges[e, 1]
        t = dist[a] + dist[b] + length[e]
        if t < best and (H[a] ^ H[b] ^ edge_class[e]) != 0:
            best, arg = t, e
    return best, arg


class LoopSearch:
    """Shortest non-separating loops of a closed manifold triangle surface."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, heavy_from: int | None = None):
        """``heavy_from``: vertices from this index on close open ends (a fan each); loops
        keep off them (their edges weigh ``FAN_WEIGHT`` times their length)."""
        self.v, self.f = vertices, faces
        self.edges, self.edge_faces, keys = _edges(faces)
        self.edge_class = None
        if self.edges is None:  # not a closed manifold surface: no loop search
            return
        self.keys, self.n = keys
        self.heavy_from = len(vertices) if heavy_from is None else heavy_from
        self.length = np.linalg.norm(vertices[self.edges[:, 0]] - vertices[self.edges[:, 1]], axis=1)
        self.length[self.edges.max(axis=1) >= self.heavy_from] *= FAN_WEIGHT
        nv = len(vertices)
        a, b = self.edges[:, 0], self.edges[:, 1]
        ids = np.arange(1, len(self.edges) + 1)  # + 1: no stored zero
        by_id = sp.csr_matrix((np.r_[ids, ids], (np.r_[a, b], np.r_[b, a])), shape=(nv, nv))
        self.csr_edge = by_id.data.astype(np.int64) - 1  # the edge of every stored entry
        self.graph = sp.csr_matrix((self.length[self.csr_edge], by_id.indices, by_id.indptr), shape=(nv, nv))
        self.edge_class = self._homology_classes()

    def _edge_ids(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        lo, hi = np.minimum(a, b), np.maximum(a, b)
        return np.searchsorted(self.keys, lo * self.n + hi)

    def _homology_classes(self) -> np.ndarray | None:
        """Every edge's Z2 homology class as bits of an int64 (a cocycle basis: a closed
        loop's class is the XOR over its edges), from one tree-cotree decomposition; None
        on a sphere or with more than ``MAX_GENUS`` handles."""
        _, pred = breadth_first_order(self.graph, 0, directed=False, return_predecessors=True)
        pred = pred.astype(np.int64)  # any spanning tree gives the same classes of loops
        child = np.flatnonzero(pred >= 0)
        in_tree = np.zeros(len(self.edges), bool)
        in_tree[self._edge_ids(child, pred[child])] = True
        # cotree: a spanning tree of the faces over the edges the primal tree leaves
        rest = np.flatnonzero(~in_tree)
        fa, fb = self.edge_faces[rest, 0], self.edge_faces[rest, 1]
        nf = len(self.f)
        dual = sp.csr_matrix((np.ones(2 * len(rest)), (np.r_[fa, fb], np.r_[fb, fa])), shape=(nf, nf))
        order, fpred = breadth_first_order(dual, 0, directed=False, return_predecessors=True)
        kids, fpred = order[1:].astype(np.int64), fpred.astype(np.int64)
        # the edge joining each face to its parent (the first of the rest edges between them)
        pair = np.minimum(fa, fb) * nf + np.maximum(fa, fb)
        by_pair = np.argsort(pair, kind="stable")
        want = np.minimum(kids, fpred[kids]) * nf + np.maximum(kids, fpred[kids])
        cotree_edge = rest[by_pair[np.searchsorted(pair[by_pair], want)]]
        in_cotree = np.zeros(len(self.edges), bool)
        in_cotree[cotree_edge] = True
        left = np.flatnonzero(~in_tree & ~in_cotree)  # 2 * genus edges: a homology basis
        if len(left) == 0 or len(left) > 2 * MAX_GENUS:
            return None
        # each cotree edge's cycle is the sum of the basis loops whose edge leaves its subtree
        mark = np.zeros(nf, np.int64)
        bits = np.left_shift(np.int64(1), np.arange(len(left), dtype=np.int64))
        np.bitwise_xor.at(mark, self.edge_faces[left, 0], bits)
        np.bitwise_xor.at(mark, self.edge_faces[left, 1], bits)
        _subtree_xor(order.astype(np.int64), fpred, mark)
        edge_class = np.zeros(len(self.edges), np.int64)  # tree edges: 0
        edge_class[left] = bits
        edge_class[cotree_edge] = mark[kids]
        return edge_class

    def through(self, source: int, shorter_than: float = np.inf):
        """``(length, loop vertices)`` of the shortest non-separating loop through (or from)
        ``source``; ``(inf, None)`` on a sphere. Only loops shorter than ``shorter_than``
        are looked for: every vertex of such a loop lies within half of it from
        ``source``, so the shortest paths stop there (a longer loop may still be returned)."""
        if self.edge_class is None:
            return np.inf, None
        limit = 0.5 * shorter_than * (1 + 1e-9) if np.isfinite(shorter_than) else np.inf
        dist, pred = dijkstra(self.graph, indices=source, return_predecessors=True, limit=limit)
        pred = pred.astype(np.int64)
        total, edge = _shortest_nonseparating(pred, dist, self.graph.indptr, self.graph.indices, self.csr_edge, self.edge_class, self.edges, self.length)
        if edge < 0:
            return np.inf, None
        return float(total), _cycle(pred, int(self.edges[edge, 0]), int(self.edges[edge, 1]))

    def _shortest_of(self, seeds, length: float, loop):
        """The first shortest loop through ``seeds`` if shorter than ``length`` (each seed's
        search stops at half the shortest loop so far), else ``(length, loop)``."""
        for s in seeds:
            l2, loop2 = self.through(int(s), length)
            if l2 < length:
                length, loop = l2, loop2
        return length, loop

    def shortest(self, seeds: np.ndarray):
        """The shortest non-separating loop through ``seeds``, shortened from its own
        vertices; ``(length, loop)``."""
        length, loop = self._shortest_of(seeds, np.inf, None)
        tried = set(int(s) for s in seeds)
        while loop is not None:
            fresh = np.array([u for u in loop.tolist() if u not in tried])
            if not len(fresh):
                break
            pick = fresh[np.linspace(0, len(fresh) - 1, min(REFINE_SEEDS, len(fresh))).astype(int)]
            tried.update(int(s) for s in pick)
            l2, loop2 = self._shortest_of(pick, length - 1e-9, None)
            if loop2 is None:
                break
            length, loop = l2, loop2
        return length, loop


def _cycle(pred: np.ndarray, a: int, b: int) -> np.ndarray:
    """The tree paths from ``a`` and ``b`` up to their common ancestor, joined by the edge ``ab``."""

    def up(x):
        path = [x]
        while pred[path[-1]] >= 0:
            path.append(int(pred[path[-1]]))
        return path

    pa, pb = up(a), up(b)
    common = set(pa) & set(pb)
    pa = pa[: next(i for i, x in enumerate(pa) if x in common) + 1]
    pb = pb[: next(i for i, x in enumerate(pb) if x in common)]
    return np.array(pa[::-1] + pb, np.int64)


def farthest_points(points: np.ndarray, k: int) -> np.ndarray:
    """``k`` indices of ``points`` spread by farthest-point sampling (Euclidean)."""
    chosen = [0]
    gap = np.linalg.norm(points - points[0], axis=1)
    for _ in range(min(k, len(points)) - 1):
        chosen.append(int(np.argmax(gap)))
        gap = np.minimum(gap, np.linalg.norm(points - points[chosen[-1]], axis=1))
    return np.array(chosen)


def loop_frame(vertices: np.ndarray, loop: np.ndarray):
    """Centre, radius (mean distance of the loop's vertices from their centre) and axis
    (the normal of the loop's best plane) of a closed vertex loop."""
    pts = vertices[loop]
    centre = pts.mean(axis=0)
    radius = float(np.linalg.norm(pts - centre, axis=1).mean())
    axis = np.linalg.svd(pts - centre, full_matrices=False)[2][-1]
    return centre, radius, axis


def sphere_directions(n: int) -> np.ndarray:
    """``n`` unit vectors spread evenly over the sphere (Fibonacci lattice)."""
    k = np.arange(n) + 0.5
    z = 1 - 2 * k / n
    t = np.pi * (1 + 5**0.5) * k
    r = np.sqrt(1 - z * z)
    return np.stack([r * np.cos(t), r * np.sin(t), z], axis=1)


def lumen_all_round(vertices: np.ndarray, tree, loop: np.ndarray) -> tuple[bool, float]:
    """Whether ``loop`` goes round a strand of outside material with lumen all round it:
    its centre outside the surface and lumen within ``PUSH_RADII`` loop radii of the
    centre in most of ``AROUND`` directions (all but the strand's own two ways on, and
    its meeting with the wall). Also the share of directions that reach lumen."""
    centre, radius, _ = loop_frame(vertices, loop)
    ways = sphere_directions(AROUND)
    pushed = centre + radius * (ways[:, None, :] * np.asarray(PUSH_RADII)[None, :, None])
    wn = ray_winding_numbers(tree, np.vstack([centre[None], pushed.reshape(-1, 3)]))
    share = float(np.mean(np.any(wn[1:].reshape(AROUND, -1) > 0.5, axis=1)))
    return bool(wn[0] < 0.5 and share >= LUMEN_ALL_ROUND), share


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Unit area-weighted vertex normals."""
    fn = face_normals(vertices, faces, normalize=False)
    n = np.zeros_like(vertices)
    for k in range(3):
        np.add.at(n, faces[:, k], fn)
    return n / np.maximum(np.linalg.norm(n, axis=1), 1e-300)[:, None]


def _line_hits(tree, points, ways, reach: float):
    """Distances from surface points to the next crossing of the surface ahead (along
    ``ways``) and behind (``inf`` where none within ``reach``)."""
    start = 1e-6 * reach * ways
    ahead = tree.intersect_lines(points + start, ways, reach, side=np.ones(len(points)))[0]
    behind = tree.intersect_lines(points - start, -ways, reach, side=np.ones(len(points)))[0]
    return np.nan_to_num(np.abs(ahead), nan=np.inf), np.nan_to_num(np.abs(behind), nan=np.inf)


def strand_vertices(search: LoopSearch, tree, loop: np.ndarray) -> np.ndarray:
    """The vertices of the strand a handle loop goes round: grown from the loop over the
    vertices where the outside material (along the outward normal) is thinner than
    ``THINNER_THAN_LUMEN`` times the lumen (along the inward normal); the strand's foot,
    where the wall turns away from it, ends the growth."""
    v, f = search.v, search.f
    normals = vertex_normals(v, f)
    nv = search.heavy_from
    a, b = search.edges[:, 0], search.edges[:, 1]
    real = (a < nv) & (b < nv)
    nbr = sp.csr_matrix((np.ones(2 * real.sum()), (np.r_[a[real], b[real]], np.r_[b[real], a[real]])), shape=(len(v), len(v)))
    reach = float(np.linalg.norm(np.ptp(v, axis=0)))
    strand = np.zeros(len(v), bool)
    strand[loop] = True
    seen = strand.copy()
    while True:
        front = np.flatnonzero((nbr @ strand.astype(float) > 0) & ~seen)
        if not len(front):
            return np.flatnonzero(strand)
        seen[front] = True
        outside, lumen = _line_hits(tree, v[front], normals[front], reach)
        strand[front[outside < THINNER_THAN_LUMEN * lumen]] = True


def _closed(vertices: np.ndarray, faces: np.ndarray, loops: list):
    """The surface with every open end closed by a fan round a new centre vertex."""
    extra_v = [vertices[l].mean(axis=0) for l in loops]
    fans = [np.stack([l, np.full(len(l), len(vertices) + i), np.roll(l, 1)], axis=1) for i, l in enumerate(loops)]
    if not loops:
        return vertices, faces
    return np.vstack([vertices, extra_v]), np.vstack([faces, *fans])


def cut_thin_handles(vertices: np.ndarray, faces: np.ndarray):
    """Cut out the strands of outside material that cross the lumen as thin handles.

    While the surface (one connected piece, open ends allowed) has a handle, its shortest
    non-separating loop is found; if the loop goes round a strand with lumen all round it
    (:func:`lumen_all_round`), the strand's faces (:func:`strand_vertices`) are removed and
    the holes left in the wall are filled with faired patches (the cut is kept only if the
    genus drops by one and no hole stays open). The first shortest loop
    that goes round the lumen instead (a real loop of vessels) ends the search.

    Returns
    -------
    vertices, faces : the surface (unused vertices dropped)
    origin : (m,) int array, the input face of every face (-1 for the patches)
    cuts : list of ``{"loop_length", "radius", "center", "strand_vertices"}``, one per cut
    """
    from ..repair import fill_holes, remove_unreferenced_vertices
    from .topology import face_components

    v, f = np.asarray(vertices, float), np.asarray(faces, np.int64)
    origin = np.arange(len(f))
    cuts: list[dict] = []
    if not len(f) or face_components(f, len(v))[0] != 1:
        return v, f, origin, cuts
    for _ in range(MAX_GENUS):
        loops = boundary_loops(f)
        handles = genus(f, loops)
        if handles < 1:
            break
        cv, cf = _closed(v, f, loops)
        search = LoopSearch(cv, cf, heavy_from=len(v))
        if search.edges is None:  # not a manifold surface: no cut
            break
        length, loop = search.shortest(farthest_points(v, SEARCH_SEEDS))
        if loop is None or np.any(loop >= len(v)):
            break
        tree = TriangleBVH(cv, cf)
        if not lumen_all_round(cv, tree, loop)[0]:
            break
        strand = strand_vertices(search, tree, loop)
        keep = ~np.any(np.isin(f, strand), axis=1)
        pieces, label = face_components(f[keep], len(v))
        if pieces > 1:  # bits of the strand cut off from the wall go with it
            keep[np.flatnonzero(keep)[label != np.argmax(np.bincount(label))]] = False
        fk = f[keep]
        before = {frozenset(l.tolist()) for l in loops}
        holes = [l for l in boundary_loops(fk) if frozenset(l.tolist()) not in before]
        if len(holes) < 2:  # a handle cut out leaves a hole at each foot at least
            break
        nf = len(fk)
        v2, f2, _ = fill_holes(v, fk, holes)
        loops2 = boundary_loops(f2)
        if len(loops2) != len(loops) or genus(f2, loops2) != handles - 1:  # not the handle alone
            break
        centre, radius, _ = loop_frame(v, loop)
        cuts.append({"loop_length": float(length), "radius": float(radius), "center": centre.tolist(), "strand_vertices": int(len(strand))})
        origin = np.r_[origin[keep], np.full(len(f2) - nf, -1)]
        v, f = v2, f2
    if cuts:
        v, f, _ = remove_unreferenced_vertices(v, f)
    return v, f, origin, cuts


def warm_up() -> None:
    """Compile (or load) this module's kernels on a small torus, for ``vmesh compile``: the
    chain's own tube has no handle, so a first looped vessel would compile them."""
    around, tube = 12, 8
    u, w = np.meshgrid(np.linspace(0, 2 * np.pi, around, endpoint=False), np.linspace(0, 2 * np.pi, tube, endpoint=False), indexing="ij")
    vertices = np.column_stack([((3 + np.cos(w)) * np.cos(u)).ravel(), ((3 + np.cos(w)) * np.sin(u)).ravel(), np.sin(w).ravel()])
    i, j = np.meshgrid(np.arange(around), np.arange(tube), indexing="ij")
    a, b = i * tube + j, ((i + 1) % around) * tube + j
    c, d = ((i + 1) % around) * tube + (j + 1) % tube, i * tube + (j + 1) % tube
    faces = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)])
    cut_thin_handles(vertices, faces)
