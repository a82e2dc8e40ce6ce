"""Surface repair kernels: welding, dropping bad and duplicate faces, keeping the largest
piece, consistent orientation, non-manifold fins and holes in the wall.

Like :mod:`vmesh.preprocess` (which re-exports these names), every function works on
plain numpy arrays (``vertices (n, 3)``, ``faces (m, 3)``) and returns new arrays.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from .geometry import topology

# ---------------------------------------------------------------------------
# small helpers
# ---------------------------------------------------------------------------
def face_areas(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Triangle areas ``(m,)``."""
    return 0.5 * np.linalg.norm(topology.face_normals(vertices, faces, normalize=False), axis=1)


def _half_edge_pairs(faces: np.ndarray):
    """Half-edges grouped by undirected edge.

    Returns
    -------
    edge_id : (3m,) int64
        Undirected edge of half-edge ``3 f + k`` (corner ``k`` -> ``k+1`` of face ``f``).
    counts : (e,) int64
        Faces per edge.
    a, b : (3m,) int64
        Start and end vertex of each half-edge.
    """
    faces = np.asarray(faces, np.int64)
    n = int(faces.max()) + 1 if faces.size else 0
    a, b = faces.ravel(), np.roll(faces, -1, axis=1).ravel()
    _, edge_id, counts = np.unique(np.minimum(a, b) * n + np.maximum(a, b), return_inverse=True, return_counts=True)
    return edge_id.ravel(), counts, a, b


def manifold_face_pairs(faces: np.ndarray, half_edges_table=None):
    """Pairs of faces sharing a manifold edge (used by exactly two faces).

    ``half_edges_table``: :func:`_half_edge_pairs` of ``faces`` where the caller has it
    (None: computed here).

    Returns
    -------
    pairs : (k, 2) int64
        The two faces of each interior manifold edge.
    same_direction : (k,) bool
        True when both faces traverse the shared edge in the same direction
        (their orientations disagree).
    half_edges : (k, 2) int64
        The two half-edge indices (``3 f + corner``).
    """
    edge_id, counts, a, _ = _half_edge_pairs(faces) if half_edges_table is None else half_edges_table
    keep = counts[edge_id] == 2
    halves = np.flatnonzero(keep)
    halves = halves[np.argsort(edge_id[halves], kind="stable")].reshape(-1, 2)
    same = a[halves[:, 0]] == a[halves[:, 1]]
    return halves // 3, same, halves


def _packed_columns(rows: np.ndarray) -> list[np.ndarray]:
    """Integer rows ``(n, k)`` as few int64 keys that sort like the rows (consecutive columns
    packed in mixed radix while the key stays below 2^62): a lexsort over 1-2 keys instead
    of k, or one argsort."""
    lo, hi = rows.min(axis=0).astype(np.int64), rows.max(axis=0).astype(np.int64)
    span = [int(h) - int(l) + 1 for l, h in zip(lo, hi)]
    keys, key, size = [], None, 1
    for j in range(rows.shape[1]):
        col = rows[:, j].astype(np.int64) - lo[j]
        if key is not None and size * span[j] < 1 << 62:
            key, size = key * span[j] + col, size * span[j]
        else:
            if key is not None:
                keys.append(key)
            key, size = col, span[j]
    keys.append(key)
    return keys


def _row_order(rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The stable lexicographic order of rows ``(n, k)`` (as ``np.lexsort`` of the columns)
    and, along it, where a new distinct row starts."""
    if rows.dtype.kind in "iu" and rows.shape[1] > 1:
        keys = _packed_columns(rows)
        order = np.argsort(keys[0], kind="stable") if len(keys) == 1 else np.lexsort(keys[::-1])
        r = np.stack([k[order] for k in keys], axis=1)
    else:
        order = np.lexsort(rows.T[::-1])
        r = rows[order]
    new = np.ones(len(r), bool)
    new[1:] = np.any(r[1:] != r[:-1], axis=1)
    return order, new


def _row_labels(rows: np.ndarray) -> np.ndarray:
    """A label per row ``(n, k)``, equal for equal rows, numbered in the rows' lexicographic
    order (np.unique(axis=0) sorts structured rows an order of magnitude slower)."""
    if len(rows) == 0:
        return np.zeros(0, np.int64)
    order, new = _row_order(rows)
    label = np.empty(len(order), np.int64)
    label[order] = np.cumsum(new) - 1
    return label


def remove_unreferenced_vertices(vertices: np.ndarray, faces: np.ndarray):
    """Drop vertices no face uses; returns ``(vertices, faces, kept_vertex_indices)``."""
    # the used vertices in increasing order, as np.unique(faces) gives them, without its sort
    used = np.flatnonzero(np.bincount(np.asarray(faces, np.int64).ravel(), minlength=len(vertices)))
    remap = np.full(len(vertices), -1, np.int64)
    remap[used] = np.arange(len(used))
    return vertices[used], remap[faces], used


# ---------------------------------------------------------------------------
# repair
# ---------------------------------------------------------------------------
#: Dropped pieces listed one by one in a repair report (the rest are only counted).
MAX_LISTED_COMPONENTS = 20


@dataclass
class RepairReport:
    """What :func:`repair` changed (all counts)."""

    merged_vertices: int = 0
    degenerate_faces: int = 0
    duplicate_faces: int = 0
    zero_area_faces: int = 0
    nonmanifold_edges: int = 0
    #: faces dropped so that every edge has at most two faces (see :func:`nonmanifold_fins`)
    nonmanifold_faces: int = 0
    removed_components: int = 0
    removed_component_faces: int = 0
    #: pieces dropped beside the kept one that are large enough to be vessels:
    #: ``{"faces", "area", "area_fraction", "bbox_min", "bbox_max"}`` each, largest first
    dropped_components: list = field(default_factory=list)
    #: pieces dropped as debris (area below ``debris_area`` × the kept piece's)
    debris_components: int = 0
    #: holes in the wall that were filled: ``{"edges", "diameter", "center"}`` each
    filled_holes: list = field(default_factory=list)
    flipped_faces: int = 0
    oriented_outward: bool = False
    non_orientable: bool = False
    unreferenced_vertices: int = 0

    def as_dict(self) -> dict:
        d = dict(self.__dict__)
        d["dropped_components"] = [dict(c) for c in self.dropped_components]
        d["filled_holes"] = [dict(h) for h in self.filled_holes]
        return d


def component_areas(vertices: np.ndarray, faces: np.ndarray, label: np.ndarray) -> np.ndarray:
    """Surface area of each connected piece (``label`` per face)."""
    return np.bincount(label, weights=face_areas(vertices, faces), minlength=int(label.max()) + 1 if len(label) else 0)


def component_summary(vertices: np.ndarray, faces: np.ndarray, label: np.ndarray, pieces) -> list[dict]:
    """Faces, area and bounding box of the connected pieces ``pieces`` (``label`` per face)."""
    areas = component_areas(vertices, faces, label)
    n_faces = np.bincount(label, minlength=len(areas))
    out = []
    for k in pieces:
        corners = vertices[faces[label == k].ravel()]
        out.append({"faces": int(n_faces[k]), "area": float(areas[k]), "bbox_min": corners.min(axis=0).tolist(), "bbox_max": corners.max(axis=0).tolist()})
    return out


def merge_close_vertices(vertices: np.ndarray, faces: np.ndarray, tolerance: float):
    """Weld vertices closer than ``tolerance`` (0: identical coordinates only).

    Returns
    -------
    vertices, faces : arrays with every cluster of close vertices replaced by its first member
    n_merged : int
        Number of vertices removed.
    """
    n = len(vertices)
    if tolerance > 0:
        from scipy.spatial import cKDTree

        pairs = cKDTree(vertices).query_pairs(tolerance, output_type="ndarray")
        graph = sp.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
        _, label = connected_components(graph, directed=False)
    else:
        label = _row_labels(np.asarray(vertices))
    # representative: the lowest original index of each cluster
    first = np.full(label.max() + 1, n, np.int64)
    np.minimum.at(first, label, np.arange(n))
    rep = first[label]
    faces = rep[faces]
    v, f, _ = remove_unreferenced_vertices(vertices, faces)
    return v, f, n - len(v)


def orient_consistently(faces: np.ndarray, half_edges_table=None) -> tuple[np.ndarray, int, bool]:
    """Flip faces so that neighbours agree on orientation (per connected piece).

    Uses the orientation double cover: node ``(f, 0)`` is face ``f`` as given, ``(f, 1)``
    is it flipped; agreeing neighbours link equal states, disagreeing ones opposite
    states. Within each piece every face takes the state connected to the first face
    of the piece as given. A piece in which some face is linked to both its states is
    non-orientable and is left unchanged. ``half_edges_table``: :func:`_half_edge_pairs`
    of ``faces`` where the caller has it (None: computed here).

    Returns
    -------
    faces : (m, 3) array
    n_flipped : int
    orientable : bool
    """
    m = len(faces)
    pairs, same, _ = manifold_face_pairs(faces, half_edges_table)
    f, g = pairs[:, 0], pairs[:, 1]
    # agreeing neighbours (opposite half-edge directions): (f,s)-(g,s); disagreeing: (f,s)-(g,1-s)
    rows = np.concatenate([f, f + m])
    cols = np.concatenate([np.where(same, g + m, g), np.where(same, g, g + m)])
    graph = sp.coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(2 * m, 2 * m))
    _, label = connected_components(graph, directed=False)
    as_given, flipped = label[:m], label[m:]
    orientable_face = as_given != flipped
    # per piece of the (manifold-edge) face graph, the reference is its lowest face as given
    piece_graph = sp.coo_matrix((np.ones(len(f)), (f, g)), shape=(m, m))
    _, piece = connected_components(piece_graph, directed=False)
    first = np.full(piece.max() + 1, m, np.int64)
    np.minimum.at(first, piece, np.arange(m))
    ref_label = label[first[piece]]
    piece_ok = np.ones(piece.max() + 1, bool)
    np.logical_and.at(piece_ok, piece, orientable_face)
    flip = (flipped == ref_label) & piece_ok[piece]
    out = faces.copy()
    out[flip] = out[flip][:, ::-1]
    return out, int(flip.sum()), bool(piece_ok.all())


def repair(
    vertices: np.ndarray,
    faces: np.ndarray,
    merge_tolerance: float = 0.0,
    keep: str = "largest",
    orient: bool = True,
    outward: bool = True,
    face_data: dict | None = None,
    debris_area: float = 1e-3,
    fill_wall_holes: bool = True,
    hole_wall_beyond: bool = False,
):
    """Clean a triangle surface.

    Steps: weld duplicate vertices, drop faces with repeated vertices and duplicate
    faces (same three vertices in any order), drop unused vertices, keep the largest
    connected piece (by area) when ``keep="largest"``, orient faces consistently,
    and turn each piece outward (positive signed volume).

    Parameters
    ----------
    vertices : (n, 3) array
    faces : (m, 3) int array
    merge_tolerance : float
        Vertices closer than this are welded; 0 welds only identical coordinates.
    keep : {"largest", "all"}
        Which connected pieces to keep.
    orient, outward : bool
        Make orientation consistent; then flip pieces enclosing negative volume.
    face_data : dict of str -> (m, ...) arrays, optional
        Per-face arrays, filtered along with the faces.
    debris_area : float
        Dropped pieces smaller than this fraction of the kept piece's area are counted as
        debris (``report.debris_components``); larger ones are listed with their size and
        bounding box (``report.dropped_components``).
    fill_wall_holes : bool
        Drop the extra faces of non-manifold edges (:func:`nonmanifold_fins`), then close
        the boundary loops that are holes in the wall rather than open ends (see
        :func:`wall_hole_loops`) with a faired patch (``report.filled_holes``); needs
        ``orient``. Filled faces get 0 in every face array.
    hole_wall_beyond : bool
        A hole must also have the wall going on past it (``wall_beyond`` of
        :func:`wall_hole_loops`).

    Returns
    -------
    vertices, faces, face_data, report : the cleaned surface and a :class:`RepairReport`
    """
    report = RepairReport()
    v = np.asarray(vertices, np.float64)
    f = np.asarray(faces, np.int64)
    data = {k: np.asarray(a) for k, a in (face_data or {}).items() if len(a) == len(f)}
    v, f, report.merged_vertices = merge_close_vertices(v, f, merge_tolerance)
    f, data = _drop_repeated_faces(f, data, report)
    if len(f) == 0:
        return v[:0], f, data, report
    if fill_wall_holes:  # the holes the dropped fins leave are filled below
        fins = nonmanifold_fins(v, f)
        report.nonmanifold_faces = len(fins)
        if len(fins):
            f, data = _keep_faces(f, data, ~np.isin(np.arange(len(f)), fins))
    if keep == "largest":
        f, data = _keep_largest_piece(v, f, data, debris_area, report)
    elif keep != "all":
        raise ValueError(f"keep must be 'largest' or 'all', got {keep!r}")
    n_before = len(v)
    v, f, _ = remove_unreferenced_vertices(v, f)
    report.unreferenced_vertices = n_before - len(v)
    diag = float(np.linalg.norm(np.ptp(v, axis=0))) if len(v) else 0.0
    report.zero_area_faces = int(np.sum(face_areas(v, f) <= 1e-14 * diag**2))
    # one undirected edge table for the count and the orientation (the edges' sort was
    # done once for each of them)
    table = _half_edge_pairs(f)
    report.nonmanifold_edges = int(np.count_nonzero(table[1] > 2))
    if orient:
        f, report.flipped_faces, orientable = orient_consistently(f, table)
        report.non_orientable = not orientable
    if fill_wall_holes and orient and not report.non_orientable:
        holes = wall_hole_loops(v, f, wall_beyond=hole_wall_beyond)
        if holes:
            n_faces = len(f)
            v, f, report.filled_holes = fill_holes(v, f, holes)
            data = {k: np.concatenate([a, np.zeros((len(f) - n_faces, *a.shape[1:]), a.dtype)]) for k, a in data.items()}
    if outward:
        _orient_outward(v, f, report)
    return v, f, data, report


def _keep_faces(f: np.ndarray, data: dict, mask: np.ndarray):
    """The faces ``mask`` selects, with their per-face arrays."""
    return f[mask], {k: a[mask] for k, a in data.items()}


def _drop_repeated_faces(f: np.ndarray, data: dict, report: RepairReport):
    """Drop faces with a repeated vertex and all but the first face of each vertex triple."""
    degenerate = (f[:, 0] == f[:, 1]) | (f[:, 1] == f[:, 2]) | (f[:, 2] == f[:, 0])
    report.degenerate_faces = int(degenerate.sum())
    f, data = _keep_faces(f, data, ~degenerate)
    label = _row_labels(np.sort(f, axis=1))
    unique = np.zeros(len(f), bool)
    unique[np.unique(label, return_index=True)[1]] = True  # the first face of each vertex triple
    report.duplicate_faces = int((~unique).sum())
    return _keep_faces(f, data, unique)


def _keep_largest_piece(v: np.ndarray, f: np.ndarray, data: dict, debris_area: float, report: RepairReport):
    """Keep the connected piece of largest area; report the others (debris counted, the
    larger ones listed with their size and bounding box)."""
    count, label = topology.face_components(f, len(v))
    if count <= 1:
        return f, data
    areas = component_areas(v, f, label)
    largest = int(np.argmax(areas))
    report.removed_components = count - 1
    report.removed_component_faces = int(np.sum(label != largest))
    fraction = areas / areas[largest] if areas[largest] > 0 else np.zeros(count)
    others = np.argsort(-areas, kind="stable")
    others = others[others != largest]
    debris = fraction[others] < debris_area
    report.debris_components = int(debris.sum())
    listed = others[~debris][:MAX_LISTED_COMPONENTS]
    report.dropped_components = [
        {**piece, "area_fraction": float(fraction[k])} for k, piece in zip(listed, component_summary(v, f, label, listed))
    ]
    return _keep_faces(f, data, label == largest)


def _orient_outward(v: np.ndarray, f: np.ndarray, report: RepairReport) -> None:
    """Flip (in place) every piece that encloses a negative volume."""
    count, label = topology.face_components(f, len(v))
    for piece in range(count):
        sel = label == piece
        if topology.signed_volume(v, f[sel]) < 0:
            f[sel] = f[sel][:, ::-1]
            report.flipped_faces += int(sel.sum())
    report.oriented_outward = True


def nonmanifold_fins(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Faces to drop so that no edge has more than two faces.

    At an edge with three or more faces the wall continues through the pair that runs
    on most smoothly: one face using the edge in each direction (as consistently oriented
    neighbours do; any two when no such pair exists), with the most nearly equal normals.
    The other faces are fins or overlaps of a bad segmentation export; the holes they
    leave are holes in the wall (see :func:`wall_hole_loops`). Edges are handled one at a
    time with the faces already dropped left out, until none has more than two faces.
    """
    he = topology.directed_edges(faces)
    _, inv, counts = np.unique(topology.pair_keys(np.sort(he, axis=1))[0], return_inverse=True, return_counts=True)
    inv = inv.ravel()
    crowded = np.flatnonzero(counts[inv] > 2)  # half-edges of non-manifold edges
    if len(crowded) == 0:
        return np.zeros(0, np.int64)
    normals = topology.face_normals(vertices, faces)
    order = crowded[np.argsort(inv[crowded], kind="stable")]
    edge_ids, starts = np.unique(inv[order], return_index=True)
    dropped: set[int] = set()
    for group in np.split(order, starts[1:]):
        face_ids = group // 3
        alive = np.array([int(g) not in dropped for g in face_ids])
        face_ids, forward = face_ids[alive], (he[group, 0] < he[group, 1])[alive]
        if len(face_ids) <= 2:
            continue
        smooth = normals[face_ids] @ normals[face_ids].T
        opposite = forward[:, None] != forward[None, :]
        score = np.where(opposite, smooth, smooth - 4.0)  # a consistently oriented pair first
        np.fill_diagonal(score, -np.inf)
        i, j = np.unravel_index(int(np.argmax(score)), score.shape)
        dropped.update(int(g) for k, g in enumerate(face_ids) if k not in (i, j))
    return np.array(sorted(dropped), np.int64)


#: A boundary loop is a hole in the wall when the faces touching it, and the surface
#: within ``HOLE_REACH`` loop radii of its centre, lie nearly in the loop's plane: their
#: mean |cos| between normal and loop normal (area-weighted in the ball) exceeds
#: ``HOLE_ALIGNMENT`` and ``HOLE_AREA_ALIGNMENT``. Around an open end the wall runs along
#: the vessel, across the loop plane: for a tube cut at any angle the ring mean is at most
#: 2/pi = 0.64, and an end whose last row of faces was left in the cap plane (a flange)
#: still has its wall inside the ball (0.4 or less on real ends). Around a hole spanning
#: ±45° of a tube's circumference the two are 0.75 and 0.7, growing towards 1 for smaller
#: holes.
HOLE_ALIGNMENT = 0.7
HOLE_AREA_ALIGNMENT = 0.5
HOLE_REACH = 1.5
#: a boundary loop of at most this many edges is a hole (a few missing triangles), never a vessel's open end
HOLE_MAX_EDGES = 5
#: A hole also has the wall going on past it: beyond ``HOLE_BEYOND`` loop radii of its
#: centre, within one loop radius of its plane and facing along its axis, on two opposite
#: sides (of ``HOLE_SECTORS`` sectors round the axis, an opposite pair each at least
#: ``HOLE_SECTOR_COVER`` covered). Past a vessel's open end the wall has turned back along
#: the vessel: an end whose rim smoothing bevelled into a flange (a short stub's, a small
#: vessel's; rims 0.4-0.9 of the radius) passes the two tests above but has no wall past the
#: flange, or on one side only (its parent's wall beside a slanting stub). On the generated
#: corpus: holes 0.81-1.12 covered, open ends 0. The ring is in loop radii, not the vessel's:
#: on a tube of radius R the wall round the circumference leaves the slab |h| <= r before
#: 2r for a hole wider than about R/2 (and the ring wraps round the tube), so such a hole is
#: judged by the wall along the tube alone, which a bend or a junction within 3 hole radii
#: can break. Opt-in (``wall_beyond``): with it two runs that passed with such an end filled
#: fail elsewhere (docs/junctions.md).
HOLE_BEYOND = 2.0
HOLE_SECTORS = 8
HOLE_SECTOR_COVER = 0.5


def _plane_around(tree, areas, normals, centre, rim, axis) -> bool:
    """Whether the faces within :data:`HOLE_REACH` rim radii of a loop's centre lie mostly
    in the loop's plane (their area-weighted normals along ``axis``). Asked only of loops
    whose own ring of faces passed the cheaper alignment test: the k-d tree query costs."""
    ball = np.asarray(tree.query_ball_point(centre, HOLE_REACH * np.linalg.norm(rim - centre, axis=1).mean()), np.int64)
    return bool(len(ball)) and np.sum(areas[ball] * np.abs(normals[ball] @ axis)) > HOLE_AREA_ALIGNMENT * np.sum(areas[ball])


def _wall_beyond(tree, areas, normals, centre, rim, axis) -> bool:
    """Whether the wall goes on past a loop on two opposite sides (see :data:`HOLE_BEYOND`):
    a hole in a wall, not a vessel's open end with a flange round its rim."""
    r = float(np.linalg.norm(rim - centre, axis=1).mean())
    ball = np.asarray(tree.query_ball_point(centre, (HOLE_BEYOND + 1.0) * r), np.int64)
    if not len(ball):
        return False
    d = tree.data[ball] - centre
    h = d @ axis
    lateral = d - h[:, None] * axis
    e1 = np.cross(axis, [1.0, 0.0, 0.0] if abs(axis[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    sector = np.floor((np.arctan2(lateral @ np.cross(axis, e1), lateral @ e1) + np.pi) * HOLE_SECTORS / (2 * np.pi)).astype(np.int64) % HOLE_SECTORS
    wall = (np.linalg.norm(lateral, axis=1) >= HOLE_BEYOND * r) & (np.abs(h) <= r) & (np.abs(normals[ball] @ axis) > HOLE_ALIGNMENT)
    cover = np.bincount(sector[wall], weights=areas[ball][wall], minlength=HOLE_SECTORS)
    cover = cover / (((HOLE_BEYOND + 1.0) ** 2 - HOLE_BEYOND**2) * np.pi * r * r / HOLE_SECTORS)
    half = HOLE_SECTORS // 2
    return bool(np.any(np.minimum(cover[:half], cover[half:]) >= HOLE_SECTOR_COVER))


def wall_hole_loops(vertices: np.ndarray, faces: np.ndarray, wall_beyond: bool = False) -> list[np.ndarray]:
    """The boundary loops of a consistently oriented surface that are holes in its wall
    (the surface around them lies nearly in the loop's plane, with ``wall_beyond`` also
    going on past it on two opposite sides (:func:`_wall_beyond`), or the loop has at most
    ``HOLE_MAX_EDGES`` edges: a missing triangle beside an open end's rim lies in the end's
    plane, across the wall), not open ends of a vessel. Of a loop through a vertex twice
    (a rim pinched there) only the 3-edge parts are holes: a triangle missing beside the
    rim, touching it at one vertex; larger parts may be lobes of the open end.

    Parameters
    ----------
    vertices : (n, 3) float array
    faces : (m, 3) int array
        Consistently oriented triangles.
    wall_beyond : bool, default False
        Also require the wall to go on past the loop on two opposite sides
        (:data:`HOLE_BEYOND`), so that an open end whose rim was bevelled into a flange
        (a short stub's) is not taken for a hole. Its ring is measured in loop radii: see
        :data:`HOLE_BEYOND` for holes nearly as wide as their vessel.

    Returns
    -------
    list of int arrays
        The vertex loops (as :func:`topology.boundary_loops` gives them, or their 3-edge
        parts) that are holes.
    """
    loops = topology.boundary_loops(faces)
    if not loops:
        return []
    from scipy.spatial import cKDTree

    normals = topology.face_normals(vertices, faces)
    areas = face_areas(vertices, faces)
    centres = vertices[faces].mean(axis=1)
    tree = cKDTree(centres)
    face_of_vertex = sp.coo_matrix(
        (np.ones(faces.size), (faces.ravel(), np.repeat(np.arange(len(faces)), 3))), shape=(len(vertices), len(faces))
    ).tocsr()
    holes = []
    for loop in loops:
        rim = vertices[loop]
        centre = rim.mean(axis=0)
        area_vector = 0.5 * np.cross(rim - centre, np.roll(rim, -1, axis=0) - centre).sum(axis=0)
        norm = np.linalg.norm(area_vector)
        if norm == 0 or len(loop) < 3:
            continue
        if len(loop) <= HOLE_MAX_EDGES:
            holes.append(loop)
            continue
        axis = area_vector / norm
        ring = np.unique(face_of_vertex[loop].indices)
        if (np.mean(np.abs(normals[ring] @ axis)) > HOLE_ALIGNMENT and _plane_around(tree, areas, normals, centre, rim, axis)
                and (not wall_beyond or _wall_beyond(tree, areas, normals, centre, rim, axis))):
            holes.append(loop)
        else:  # an open end; where its rim is pinched at a vertex, a triangle missing there is a hole
            holes.extend(c for c in topology.split_pinched_loop(loop) if len(c) == 3 < len(loop))
    return holes


def fill_holes(vertices: np.ndarray, faces: np.ndarray, loops) -> tuple[np.ndarray, np.ndarray, list[dict]]:
    """Close ``loops`` with ring patches (as caps), then fair the new vertices so that each
    patch continues the wall around it (least squared umbrella Laplacian, the original
    vertices fixed). Returns the surface and ``{"edges", "diameter", "center"}`` per hole."""
    from .preprocess import cap_loop, uniform_laplacian

    v_parts, f_parts, n = [vertices], [faces], len(vertices)
    filled = []
    for loop in loops:
        pts, tris = cap_loop(vertices, loop)
        f_parts.append(np.where(tris >= len(vertices), tris - len(vertices) + n, tris))
        v_parts.append(pts)
        n += len(pts)
        rim = vertices[loop]
        filled.append({"edges": int(len(loop)), "diameter": float(2 * np.linalg.norm(rim - rim.mean(axis=0), axis=1).mean()), "center": rim.mean(axis=0).tolist()})
    v, f = np.vstack(v_parts), np.vstack(f_parts)
    free = np.arange(len(vertices), len(v))
    fixed = np.arange(len(vertices))
    lap = uniform_laplacian(len(v), f)
    energy = (lap.T @ lap).tocsr()
    rhs = -(energy[free][:, fixed] @ v[fixed])
    from scipy.sparse.linalg import spsolve

    solved = spsolve(energy[free][:, free].tocsc(), rhs)
    if np.all(np.isfinite(solved)):
        v = v.copy()
        v[free] = np.asarray(solved).reshape(-1, 3)
    return v, f, filled
