"""Surface preprocessing kernels: capping, flat-cap detection, smoothing, decimation (and
the repair kernels of :mod:`vmesh.repair`, re-exported).

Every function here works on plain numpy arrays (``vertices (n, 3)``, ``faces (m, 3)``)
and returns new arrays; the filters in :mod:`vmesh.filters.preprocess_filters` wrap
them. Caps are tracked through every step by a per-face integer label
(``0`` = wall, ``k`` = cap ``k``), stored on surfaces as ``face_data["cap_id"]``.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from .caps import Cap
from .geometry import topology
from .repair import (  # the repair kernels, re-exported under their old names
    face_areas,
    manifold_face_pairs,
    remove_unreferenced_vertices,
    MAX_LISTED_COMPONENTS,
    RepairReport,
    component_areas,
    component_summary,
    merge_close_vertices,
    orient_consistently,
    repair,
    nonmanifold_fins,
    HOLE_ALIGNMENT,
    HOLE_AREA_ALIGNMENT,
    HOLE_REACH,
    wall_hole_loops,
    fill_holes,
)

#: Name of the per-face cap label array on capped surfaces (0 = wall, k = cap id k).
CAP_LABEL = "cap_id"


# ---------------------------------------------------------------------------
# capping
# ---------------------------------------------------------------------------
def _zip_rings(outer: np.ndarray, t_outer: np.ndarray, inner: np.ndarray, t_inner: np.ndarray) -> np.ndarray:
    """Triangulate the band between two closed rings of vertex ids, matched by parameter.

    ``outer`` follows the boundary direction; triangles are oriented like the fan
    ``(outer[j+1], outer[j], inner)``, i.e. consistently with the wall the rim bounds.
    """
    no, ni = len(outer), len(inner)
    nxt = np.concatenate([np.append(t_outer[1:], 1.0), np.append(t_inner[1:], 1.0)])
    is_outer = np.concatenate([np.ones(no, bool), np.zeros(ni, bool)])
    order = np.argsort(nxt, kind="stable")
    is_outer = is_outer[order]
    j = np.cumsum(is_outer) - is_outer  # outer steps taken before each event
    i = np.cumsum(~is_outer) - ~is_outer
    o0, o1 = outer[j % no], outer[(j + 1) % no]
    i0, i1 = inner[i % ni], inner[(i + 1) % ni]
    return np.where(is_outer[:, None], np.stack([o1, o0, i0], 1), np.stack([i0, i1, o0], 1))


def cap_loop(vertices: np.ndarray, loop: np.ndarray, rings: int | None = None):
    """Flat-ish cap of one boundary loop: concentric rings zipped together, then a fan.

    Parameters
    ----------
    vertices : (n, 3) array
    loop : (k,) int array
        Boundary vertex ids in boundary half-edge order.
    rings : int, optional
        Number of inner rings; ``None`` picks about one ring per rim edge length of
        radius, ``0`` gives a plain centre fan.

    Returns
    -------
    new_vertices : (p, 3) array
        Vertices to append (ring points and the centre, last).
    triangles : (q, 3) int array
        Cap triangles; ids ``>= len(vertices)`` refer to ``new_vertices``.
    """
    rim = vertices[loop]
    seg = np.linalg.norm(np.roll(rim, -1, axis=0) - rim, axis=1)
    perimeter = seg.sum()
    center = (0.5 * (rim + np.roll(rim, -1, axis=0)) * seg[:, None]).sum(axis=0) / max(perimeter, 1e-300)
    radius = np.linalg.norm(rim - center, axis=1).mean()
    h = perimeter / len(loop)
    if rings is None:
        rings = max(0, int(round(radius / max(h, 1e-300))) - 1)
    t_rim = np.concatenate([[0.0], np.cumsum(seg)[:-1]]) / max(perimeter, 1e-300)
    closed_t = np.append(t_rim, 1.0)
    closed_rim = np.vstack([rim, rim[:1]])
    base = len(vertices)
    new_pts, tris = [], []
    outer, t_outer = np.asarray(loop), t_rim
    for k in range(1, rings + 1):
        scale = 1.0 - k / (rings + 1)
        count = int(round(len(loop) * scale))
        if count < 6:
            break
        t = np.arange(count) / count
        pts = np.stack([np.interp(t, closed_t, closed_rim[:, a]) for a in range(3)], axis=1)
        ids = base + sum(len(p) for p in new_pts) + np.arange(count)
        new_pts.append(center + scale * (pts - center))
        tris.append(_zip_rings(outer, t_outer, ids, t))
        outer, t_outer = ids, t
    c_id = base + sum(len(p) for p in new_pts)
    new_pts.append(center[None, :])
    tris.append(np.stack([np.roll(outer, -1), outer, np.full(len(outer), c_id)], axis=1))
    return np.vstack(new_pts), np.vstack(tris).astype(np.int64)


def cap_boundary_loops(vertices: np.ndarray, faces: np.ndarray, rings: int | None = None, method: str = "rings"):
    """Close every open end of a surface with a flat cap.

    Parameters
    ----------
    vertices : (n, 3) array
    faces : (m, 3) int array
        A consistently oriented surface.
    rings : int, optional
        Inner rings per cap for ``method="rings"`` (``None``: automatic; 0: centre fan).
    method : {"rings", "meshlab"}
        ``"rings"``: concentric rings plus a centre fan, sized like the rim edges;
        ``"meshlab"``: pymeshlab's hole filling (``meshing_close_holes``) with refinement.

    Returns
    -------
    vertices, faces : the closed surface (original faces first, in order)
    labels : (m',) int64
        0 for the original faces, ``k`` (1-based, in loop order) for cap ``k``'s faces.
    """
    loops = topology.join_touching(topology.boundary_loops(faces))  # a pinched rim is one open end
    labels = np.zeros(len(faces), np.int64)
    if not loops:
        return vertices, faces, labels
    if method == "meshlab":
        return _cap_meshlab(vertices, faces, loops)
    if method != "rings":
        raise ValueError(f"unknown capping method {method!r}")
    v_parts, f_parts, l_parts = [vertices], [faces], [labels]
    n = len(vertices)
    for k, loop in enumerate(loops, start=1):
        pts, tris = cap_loop(vertices, loop, rings)
        tris = np.where(tris >= len(vertices), tris - len(vertices) + n, tris)
        v_parts.append(pts)
        f_parts.append(tris)
        l_parts.append(np.full(len(tris), k, np.int64))
        n += len(pts)
    return np.vstack(v_parts), np.vstack(f_parts), np.concatenate(l_parts)


def _cap_meshlab(vertices, faces, loops):
    import pymeshlab

    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertices, faces))
    longest = max(len(loop) for loop in loops)
    ms.meshing_close_holes(maxholesize=longest + 1, newfaceselected=True, selfintersection=False, refinehole=True)
    m = ms.current_mesh()
    v, f = m.vertex_matrix().astype(np.float64), m.face_matrix().astype(np.int64)
    new = np.asarray(m.face_selection_array(), bool)
    # pymeshlab keeps the original faces in order; label new faces by the loop they close
    labels = np.zeros(len(f), np.int64)
    if new.any():
        sub = np.flatnonzero(new)
        count, comp = topology.face_components(f[sub], len(v))
        loop_of_vertex = np.zeros(len(v), np.int64)
        for k, loop in enumerate(loops, start=1):
            loop_of_vertex[loop] = k
        for c in range(count):
            ids = sub[comp == c]
            touched = loop_of_vertex[f[ids].ravel()]
            labels[ids] = np.bincount(touched[touched > 0]).argmax() if np.any(touched > 0) else 0
    return v, f, labels


def caps_from_labels(vertices: np.ndarray, faces: np.ndarray, labels: np.ndarray) -> list[Cap]:
    """Cap geometry (centre, outward normal, radius, rim, faces) of each labelled face group.

    Parameters
    ----------
    vertices, faces : an outward-oriented surface
    labels : (m,) int array
        0 for wall faces, ``k > 0`` for cap ``k``.

    Returns
    -------
    list of :class:`~vmesh.caps.Cap` in label order, ids equal to the labels and
    provisional names ``"cap_<k>"`` (see :func:`name_caps`).
    """
    caps = []
    raw = topology.face_normals(vertices, faces, normalize=False)
    for k in np.unique(labels[labels > 0]):
        ids = np.flatnonzero(labels == k)
        area2 = np.linalg.norm(raw[ids], axis=1)
        centroid = vertices[faces[ids]].mean(axis=1)
        center = (centroid * area2[:, None]).sum(0) / max(area2.sum(), 1e-300)
        normal = raw[ids].sum(axis=0)
        normal /= max(np.linalg.norm(normal), 1e-300)
        loops = topology.boundary_loops(faces[ids])
        rim_ids = max(loops, key=len) if loops else np.unique(faces[ids])
        rim = vertices[rim_ids]
        radius = float(np.linalg.norm(rim - center, axis=1).mean())
        caps.append(Cap(id=int(k), name=f"cap_{k}", center=center, normal=normal, radius=radius, rim=rim, faces=ids))
    return caps


def name_caps(caps: list[Cap], inlet: int | None = None, inlet_point=None) -> tuple[list[Cap], dict]:
    """Order caps by decreasing radius, name them, and renumber their ids 1..n.

    The inlet is the largest cap known to be an end (not ``needs_end``; the largest of
    all where every cap needs one) unless ``inlet`` (1-based position in the order of
    decreasing radius) or ``inlet_point`` (the cap whose centre is nearest) names
    another. It gets id 1 and name ``"inlet"``; the others ``"outlet_1"``,
    ``"outlet_2"``, ... in order of decreasing radius, the caps that need an end after
    the others (they may turn out to be facets of the wall and be dropped; the sure caps'
    names then stay).

    Returns
    -------
    caps : list of Cap, inlet first
    relabel : dict old id -> new id
    """
    if not caps:
        return [], {}
    by_radius = sorted(caps, key=lambda c: -c.radius)
    if inlet_point is not None:
        pt = np.asarray(inlet_point, float).reshape(3)
        chosen = min(range(len(by_radius)), key=lambda i: np.linalg.norm(by_radius[i].center - pt))
    elif inlet is not None:
        if not 1 <= inlet <= len(by_radius):
            raise ValueError(f"inlet = {inlet} but there are {len(by_radius)} caps (1 = largest)")
        chosen = inlet - 1
    else:
        chosen = next((i for i, c in enumerate(by_radius) if not c.needs_end), 0)
    rest = [c for i, c in enumerate(by_radius) if i != chosen]
    ordered = [by_radius[chosen]] + [c for c in rest if not c.needs_end] + [c for c in rest if c.needs_end]
    out, relabel = [], {}
    for new_id, c in enumerate(ordered, start=1):
        relabel[c.id] = new_id
        name = "inlet" if new_id == 1 else f"outlet_{new_id - 1}"
        out.append(Cap(id=new_id, name=name, center=c.center, normal=c.normal, radius=c.radius, rim=c.rim, faces=c.faces, needs_end=c.needs_end))
    return out, relabel


def relabel(labels: np.ndarray, mapping: dict) -> np.ndarray:
    """Apply ``{old id: new id}`` to a label array (0 stays 0)."""
    lut = np.zeros(max([0, *mapping, int(labels.max(initial=0))]) + 1, np.int64)
    for old, new in mapping.items():
        lut[old] = new
    return lut[labels]


# ---------------------------------------------------------------------------
# flat-cap detection on closed surfaces
# ---------------------------------------------------------------------------
def detect_flat_caps(
    vertices: np.ndarray,
    faces: np.ndarray,
    angle_tolerance: float = 2.0,
    min_crease_angle: float = 30.0,
    min_roundness: float = 0.5,
    min_faces: int = 6,
    planarity: float = 0.02,
) -> np.ndarray:
    """Find flat end caps of a closed surface: planar, disc-like regions bounded by a crease.

    A face region is grown across edges whose two faces deviate by less than
    ``angle_tolerance`` degrees. A region is a cap when it has at least ``min_faces``
    faces, all its vertices lie within ``planarity`` × its equivalent radius of its
    plane, it is round (``4 π area / perimeter² >= min_roundness``; strips along a
    tube are not), its boundary is a single loop, and the wall meets it at a crease of
    at least ``min_crease_angle`` degrees on average.

    Returns
    -------
    labels : (m,) int64
        0 for wall faces, ``k = 1..n`` for the faces of the ``k``-th cap found.
    """
    v = np.asarray(vertices, np.float64)
    f = np.asarray(faces, np.int64)
    m = len(f)
    raw = topology.face_normals(v, f, normalize=False)
    area2 = np.linalg.norm(raw, axis=1)
    unit = raw / np.maximum(area2, 1e-300)[:, None]
    pairs, _, halves = manifold_face_pairs(f)
    cos = np.einsum("ij,ij->i", unit[pairs[:, 0]], unit[pairs[:, 1]])
    flat = cos > np.cos(np.radians(angle_tolerance))
    graph = sp.coo_matrix((np.ones(flat.sum()), (pairs[flat, 0], pairs[flat, 1])), shape=(m, m))
    _, region = connected_components(graph, directed=False)
    n_reg = region.max() + 1
    size = np.bincount(region, minlength=n_reg)
    area = 0.5 * np.bincount(region, weights=area2, minlength=n_reg)
    normal = np.stack([np.bincount(region, weights=raw[:, a], minlength=n_reg) for a in range(3)], 1)
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-300)
    centroid_f = v[f].mean(axis=1)
    centre = np.stack([np.bincount(region, weights=centroid_f[:, a] * area2, minlength=n_reg) for a in range(3)], 1)
    centre /= np.maximum(2 * area, 1e-300)[:, None]
    # planarity: largest vertex distance from the region plane
    corner_region = np.repeat(region, 3)
    off = np.abs(np.einsum("ij,ij->i", v[f.ravel()] - centre[corner_region], normal[corner_region]))
    deviation = np.zeros(n_reg)
    np.maximum.at(deviation, corner_region, off)
    # boundary between regions: perimeter and crease angle (length weighted)
    cross = region[pairs[:, 0]] != region[pairs[:, 1]]
    a_v = f.ravel()[halves[cross, 0]]
    b_v = np.roll(f, -1, axis=1).ravel()[halves[cross, 0]]
    length = np.linalg.norm(v[a_v] - v[b_v], axis=1)
    crease = np.degrees(np.arccos(np.clip(cos[cross], -1, 1)))
    r0, r1 = region[pairs[cross, 0]], region[pairs[cross, 1]]
    perimeter = np.bincount(r0, weights=length, minlength=n_reg) + np.bincount(r1, weights=length, minlength=n_reg)
    crease_sum = np.bincount(r0, weights=length * crease, minlength=n_reg) + np.bincount(r1, weights=length * crease, minlength=n_reg)
    mean_crease = crease_sum / np.maximum(perimeter, 1e-300)
    roundness = 4 * np.pi * area / np.maximum(perimeter, 1e-300) ** 2
    eq_radius = np.sqrt(area / np.pi)
    candidate = (
        (size >= min_faces)
        & (deviation <= planarity * eq_radius)
        & (roundness >= min_roundness)
        & (mean_crease >= min_crease_angle)
    )
    labels = np.zeros(m, np.int64)
    k = 0
    for r in np.flatnonzero(candidate):
        ids = np.flatnonzero(region == r)
        if len(topology.boundary_loops(f[ids])) != 1:
            continue
        k += 1
        labels[ids] = k
    return labels


#: The wall behind a flat end cap is the vessel's: within ``CAP_TUBE_DEPTH`` cap radii
#: (and three rim edges) behind its plane, nine tenths of the surface reached from the
#: cap's rim lie within ``CAP_TUBE_SPREAD`` cap radii of the cap's axis. A tube cut square
#: keeps about 1, cut at 60 degrees 2 along its long axis; a flat region smaller than the
#: lumen (a bevelled, decimated rim) 1.5-2. A flat facet of the wall (a voxel staircase's
#: terrace) is met by the wall spreading along the vessel and around it (4.2 or more on
#: the generated staircase vessels), but so is a flat part of an end face beside a parent
#: vessel (4.6): such a region is an end only where the skeleton reaches it. The value
#: lies between a wall that leaves the cap's rim backwards, as a tube's does however it is
#: cut (at most 2), and a wall that carries on past the region sideways, as around a
#: facet (the vessel's whole girth and length within the slab: 4.2 and more).
CAP_TUBE_DEPTH = 0.5
CAP_TUBE_SPREAD = 3.0


def flat_caps_needing_an_end(vertices: np.ndarray, faces: np.ndarray, labels: np.ndarray) -> list[int]:
    """The flat caps whose wall behind is no tube of their size.

    Parameters
    ----------
    vertices : (n, 3) float array
    faces : (m, 3) int array
        An outward-oriented closed surface.
    labels : (m,) int array
        Cap labels per face (:func:`detect_flat_caps`; 0 = wall).

    Returns
    -------
    list of int
        The labels of the caps whose wall behind spreads beyond a tube of their size
        (``CAP_TUBE_DEPTH``, ``CAP_TUBE_SPREAD``): ends only where a skeleton end reaches
        them (``Cap.needs_end``), else facets of the wall.
    """
    from scipy.spatial import cKDTree

    v = np.asarray(vertices, np.float64)
    f = np.asarray(faces, np.int64)
    raw = topology.face_normals(v, f, normalize=False)
    adjacency = tree = None
    out = []
    for k in np.unique(labels[labels > 0]):
        ids = np.flatnonzero(labels == k)
        loops = topology.boundary_loops(f[ids])
        if len(loops) != 1:
            continue
        area2 = np.linalg.norm(raw[ids], axis=1)
        centre = (v[f[ids]].mean(axis=1) * area2[:, None]).sum(0) / max(area2.sum(), 1e-300)
        normal = raw[ids].sum(0)
        normal /= max(np.linalg.norm(normal), 1e-300)
        if adjacency is None:
            adjacency, tree = _vertex_adjacency(len(v), f), cKDTree(v)
        if not _tube_behind(v, adjacency, loops[0], centre, normal, np.sqrt(0.5 * area2.sum() / np.pi), tree):
            out.append(int(k))
    return out


def _vertex_adjacency(n_vertices: int, faces: np.ndarray) -> sp.csr_matrix:
    """Symmetric vertex adjacency of a triangle mesh (entries 1)."""
    a, b = faces.ravel(), np.roll(faces, -1, axis=1).ravel()
    adj = sp.coo_matrix((np.ones(2 * len(a)), (np.concatenate([a, b]), np.concatenate([b, a]))), shape=(n_vertices, n_vertices)).tocsr()
    adj.data[:] = 1.0  # duplicate entries from two faces per edge
    return adj


def _tube_behind(v, adjacency, rim, centre, normal, radius, tree=None) -> bool:
    """Whether the surface reached from ``rim`` within ``CAP_TUBE_DEPTH`` radii behind the
    plane (``normal`` points out) stays, but for a tenth, within ``CAP_TUBE_SPREAD`` radii
    of the axis. ``tree``: a KD-tree of ``v`` (only the ball around the cap is looked at)."""
    # at least a few rim edges deep: a staircase's riser (one voxel) must not cut the slab off
    reach = max(CAP_TUBE_DEPTH * radius, 3.0 * float(np.linalg.norm(v[rim] - v[np.roll(rim, -1)], axis=1).mean()))
    # the slab is cut at twice the spread tested: wide enough that the tenth beyond the
    # spread is still counted, bounded so that it does not run along the whole vessel
    wide = 2.0 * CAP_TUBE_SPREAD * radius
    # a tenth of a radius in front of the plane: the rim of a voxelised or decimated cap
    # stands that much proud of the fitted plane; the wall of a tube never comes forward
    front = 0.1 * radius
    near = np.arange(len(v)) if tree is None else np.union1d(tree.query_ball_point(centre, float(np.hypot(max(reach, front), wide))), rim).astype(np.int64)
    rel = v[near] - centre
    depth = -(rel @ normal)
    radial_near = np.linalg.norm(rel + depth[:, None] * normal, axis=1)
    keep = (depth >= -front) & (depth <= reach) & (radial_near <= wide)
    keep[np.isin(near, rim)] = True
    ids = near[keep]
    radial = radial_near[keep]
    _, piece = connected_components(adjacency[ids][:, ids], directed=False)
    # ids is sorted and holds the rim: its pieces by search, no per-cap array over all vertices
    reached = np.isin(piece, np.unique(piece[np.searchsorted(ids, rim)]))
    # nine tenths: one spike of wall (a neighbouring vessel's edge touching the slab) does not decide
    return bool(np.percentile(radial[reached], 90) <= CAP_TUBE_SPREAD * radius)


# ---------------------------------------------------------------------------
# smoothing
# ---------------------------------------------------------------------------
def uniform_laplacian(n_vertices: int, faces: np.ndarray) -> sp.csr_matrix:
    """Row-normalised umbrella operator ``L = A D^-1 - I`` as a sparse matrix."""
    adj = _vertex_adjacency(n_vertices, faces)
    deg = np.asarray(adj.sum(axis=1)).ravel()
    inv = sp.diags(1.0 / np.maximum(deg, 1))
    return (inv @ adj - sp.identity(n_vertices, format="csr")).tocsr()


def taubin_smooth(
    vertices: np.ndarray,
    faces: np.ndarray,
    iterations: int = 10,
    lambda_: float = 0.5,
    mu: float = -0.53,
    fixed: np.ndarray | None = None,
) -> np.ndarray:
    """Taubin λ|μ smoothing (low-pass, no shrinkage) with optional fixed vertices.

    Parameters
    ----------
    vertices : (n, 3) array
    faces : (m, 3) int array
    iterations : int
        Number of λ/μ step pairs.
    lambda_, mu : float
        Positive and negative step factors (``mu < -lambda_``).
    fixed : (n,) bool array, optional
        Vertices that must not move (e.g. those of flat caps).

    Returns
    -------
    (n, 3) array of smoothed vertex positions.
    """
    x = np.array(vertices, np.float64)
    lap = uniform_laplacian(len(x), faces)
    free = np.ones(len(x)) if fixed is None else (~np.asarray(fixed, bool)).astype(float)
    for _ in range(iterations):
        for factor in (lambda_, mu):
            x += factor * free[:, None] * (lap @ x)
    return x


def loop_subdivide(
    vertices: np.ndarray,
    faces: np.ndarray,
    iterations: int = 1,
    edge_threshold: float = 0.0,
    weights: str = "Loop",
    face_mask: np.ndarray | None = None,
    labels: np.ndarray | None = None,
):
    """Loop subdivision through pymeshlab (``meshing_surface_subdivision_loop``).

    Parameters
    ----------
    vertices, faces : the surface
    iterations : int
    edge_threshold : float
        Only edges longer than this are split (absolute length; 0 splits all).
    weights : {"Loop", "Enhance regularity", "Enhance continuity"}
        pymeshlab's weighting scheme.
    face_mask : (m,) bool array, optional
        Subdivide only these faces (their neighbours are split just enough to stay conforming).
    labels : (m,) int array, optional
        Per-face labels carried to the child faces (e.g. cap ids).

    Returns
    -------
    vertices, faces, labels (``None`` when none were given)
    """
    import pymeshlab

    scheme = {"Loop": 0, "Enhance regularity": 1, "Enhance continuity": 2}[weights]
    # the labels ride along as face quality, which the subdivision copies to every child face
    # (a custom attribute reaches only one child of each split face); the face colour's red
    # channel carries the selection
    carry = np.zeros(len(faces)) if labels is None else np.asarray(labels, float)
    select = np.ones(len(faces)) if face_mask is None else np.asarray(face_mask, float)
    colour = np.zeros((len(faces), 4))
    colour[:, 0], colour[:, 3] = select, 1.0
    mesh = pymeshlab.Mesh(np.asarray(vertices, np.float64), np.asarray(faces, np.int64), f_scalar_array=carry, f_color_matrix=colour)
    ms = pymeshlab.MeshSet()
    ms.add_mesh(mesh)
    if face_mask is not None:
        ms.compute_selection_by_condition_per_face(condselect="fr > 127")
    ms.meshing_surface_subdivision_loop(
        loopweight=scheme,
        iterations=iterations,
        threshold=pymeshlab.PureValue(edge_threshold),
        selected=face_mask is not None,
    )
    out = ms.current_mesh()
    v, f = out.vertex_matrix().astype(np.float64), out.face_matrix().astype(np.int64)
    new_labels = None if labels is None else np.rint(out.face_scalar_array()).astype(np.int64)
    return v, f, new_labels


def flatten_caps(vertices: np.ndarray, faces: np.ndarray, labels: np.ndarray, caps: list[Cap]) -> np.ndarray:
    """Project the vertices of each cap's faces back onto that cap's plane."""
    v = np.array(vertices, np.float64)
    for cap in caps:
        ids = np.unique(faces[labels == cap.id])
        n = np.asarray(cap.normal, float)
        v[ids] -= np.outer((v[ids] - cap.center) @ n, n)
    return v


def faces_near_points(vertices: np.ndarray, faces: np.ndarray, centers: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """Boolean ``(m,)``: faces with a vertex within ``radii[i]`` of some ``centers[i]``."""
    from scipy.spatial import cKDTree

    near = np.zeros(len(vertices), bool)
    if len(centers):
        hits = cKDTree(vertices).query_ball_point(np.asarray(centers, float), np.asarray(radii, float))
        idx = np.concatenate([np.asarray(h, np.int64) for h in hits]) if len(hits) else np.zeros(0, np.int64)
        near[idx] = True
    return near[faces].any(axis=1)


# ---------------------------------------------------------------------------
# decimation
# ---------------------------------------------------------------------------
def decimate(
    vertices: np.ndarray,
    faces: np.ndarray,
    target_faces: int,
    backend: str = "pymeshlab",
    preserve_boundary: bool = True,
    preserve_topology: bool = True,
    preserve_normal: bool = True,
    quality_threshold: float = 0.3,
    aggressiveness: float = 7.0,
):
    """Quadric edge-collapse decimation to ``target_faces`` triangles.

    Parameters
    ----------
    vertices, faces : the surface
    target_faces : int
    backend : {"pymeshlab", "fast_simplification"}
        pymeshlab's ``meshing_decimation_quadric_edge_collapse`` (topology, boundary
        and normals preserved, optimal vertex placement) or fast-simplification
        (Garland–Heckbert in C++, several times faster).
    preserve_boundary, preserve_topology, preserve_normal : bool
        pymeshlab options (``preserve_boundary`` also for fast-simplification).
    quality_threshold : float
        pymeshlab: penalise collapses producing triangles of quality below this (0..1).
    aggressiveness : float
        fast-simplification's ``agg`` (higher is faster, coarser quality).

    Returns
    -------
    vertices, faces : the decimated surface
    """
    f = np.asarray(faces, np.int64)
    target = int(min(max(target_faces, 4), len(f)))
    if target >= len(f):
        return np.array(vertices, np.float64), f.copy()
    if backend == "pymeshlab":
        import pymeshlab

        ms = pymeshlab.MeshSet()
        ms.add_mesh(pymeshlab.Mesh(np.asarray(vertices, np.float64), f))
        ms.meshing_decimation_quadric_edge_collapse(
            targetfacenum=target,
            qualitythr=quality_threshold,
            preserveboundary=preserve_boundary,
            preservenormal=preserve_normal,
            preservetopology=preserve_topology,
            optimalplacement=True,
            planarquadric=True,
            autoclean=True,
        )
        m = ms.current_mesh()
        return m.vertex_matrix().astype(np.float64), m.face_matrix().astype(np.int64)
    if backend == "fast_simplification":
        import fast_simplification

        # fast-simplification does not preserve topology: now and then a collapse leaves a
        # non-manifold edge, which costs the signed distance its exact pseudonormal sign.
        # A slightly different target collapses other edges; pymeshlab is the last resort.
        keep_manifold = _is_manifold(f)
        for attempt in range(4):
            count = min(len(f), int(round(target * (1.0 + 0.003 * attempt))))  # stays within 1 %
            v, f2 = fast_simplification.simplify(
                np.asarray(vertices, np.float64), f.astype(np.int32), target_count=count, agg=aggressiveness, preserve_border=preserve_boundary
            )
            v, f2, _ = remove_unreferenced_vertices(np.asarray(v, np.float64), np.asarray(f2, np.int64))
            if not keep_manifold or _is_manifold(f2):
                return v, f2
        import warnings

        warnings.warn(f"fast-simplification leaves non-manifold edges at {target} faces: decimated with pymeshlab instead", RuntimeWarning, stacklevel=2)
        return decimate(vertices, f, target, "pymeshlab", preserve_boundary, preserve_topology, preserve_normal, quality_threshold, aggressiveness)
    raise ValueError(f"unknown decimation backend {backend!r}")


def _is_manifold(faces: np.ndarray) -> bool:
    """True when no edge has more than two faces and the faces are consistently oriented."""
    from .geometry.sdf import edge_table

    _, faces_per_edge, oriented = edge_table(np.asarray(faces, np.int64))
    return bool(oriented) and not bool(np.any(faces_per_edge > 2))


def vertex_radii(vertices: np.ndarray, faces: np.ndarray, wall_faces: np.ndarray | None = None) -> np.ndarray:
    """Local vessel radius ``(n,)`` at every vertex of a closed surface: half the chord
    along the inward normal (:func:`vmesh.geometry.sdf.local_radius`; caps, ``wall_faces``
    False, are left out of the chords)."""
    from .geometry.sdf import SignedDistance, local_radius

    fine = SignedDistance(vertices, faces)
    return local_radius(fine, fine.vertices, fine.vertex_normals, wall_faces=wall_faces)


def wall_radius_deviation(fine_vertices: np.ndarray, fine_faces: np.ndarray, coarse_vertices: np.ndarray, coarse_faces: np.ndarray, wall_faces: np.ndarray | None = None, radii: np.ndarray | None = None) -> np.ndarray:
    """Distance of every fine vertex from the coarse surface over the local vessel radius ``(n,)``.

    ``radii`` are the fine vertices' radii (:func:`vertex_radii`, computed when not given).
    A cheap, faithful proxy of the coarse signed distance's projection error relative to
    the radius (``benchmarks/sdf_coarse_vs_fine.py`` measures both).
    """
    from .geometry.bvh import TriangleBVH

    if radii is None:
        radii = vertex_radii(fine_vertices, fine_faces, wall_faces)
    sq = TriangleBVH(coarse_vertices, coarse_faces).closest(fine_vertices)[0]
    return np.sqrt(sq) / np.maximum(radii, 1e-300)


def decimate_to_tolerance(vertices, faces, target_faces: int, max_error: float, wall_faces=None, max_tries: int = 5, **options):
    """Decimate to ``target_faces``, then to more faces until every fine vertex lies within
    ``max_error`` local radii of the result.

    The chordal error of a decimation falls about like 1/faces, so each retry scales the
    face count by the measured error over the tolerance (times 1.15, at least 1.25×).

    Returns
    -------
    vertices, faces : the decimated surface
    tries : list of ``(faces, max relative error)`` per attempt
    """
    f = np.asarray(faces, np.int64)
    target = int(target_faces)
    tries = []
    radii = None  # the fine surface's radii, the same for every try
    while True:
        v2, f2 = decimate(vertices, f, target, **options)
        if len(f2) >= len(f):
            tries.append((len(f2), 0.0))
            return v2, f2, tries
        if radii is None:
            radii = vertex_radii(vertices, f, wall_faces)
        err = float(wall_radius_deviation(vertices, f, v2, f2, radii=radii).max())
        tries.append((len(f2), err))
        if err <= max_error or len(tries) >= max_tries:
            return v2, f2, tries
        target = int(min(len(f), max(1.25, 1.15 * err / max_error) * len(f2)))


#: The kernels of this module and the repair kernels it re-exports.
__all__ = [
    "Cap",
    "cap_boundary_loops",
    "CAP_LABEL",
    "cap_loop",
    "caps_from_labels",
    "component_areas",
    "component_summary",
    "decimate",
    "decimate_to_tolerance",
    "detect_flat_caps",
    "flat_caps_needing_an_end",
    "face_areas",
    "faces_near_points",
    "fill_holes",
    "flatten_caps",
    "HOLE_ALIGNMENT",
    "HOLE_AREA_ALIGNMENT",
    "HOLE_REACH",
    "loop_subdivide",
    "manifold_face_pairs",
    "MAX_LISTED_COMPONENTS",
    "merge_close_vertices",
    "name_caps",
    "nonmanifold_fins",
    "orient_consistently",
    "relabel",
    "remove_unreferenced_vertices",
    "repair",
    "RepairReport",
    "taubin_smooth",
    "uniform_laplacian",
    "vertex_radii",
    "wall_hole_loops",
    "wall_radius_deviation",
]
