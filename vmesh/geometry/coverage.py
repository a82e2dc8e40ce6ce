"""How much of the input vessel a hexahedral mesh covers.

A mesh can be valid element by element and still leave out part of the vessel: a
skeleton that never entered a short, wide branch gives a mesh that stops at the branch's
mouth, with the flat face where it stops labelled wall. :func:`measure_coverage`
measures, with pure array work and BVH queries,

- the share of the input wall (caps left out: the mesh ends there) farther than
  ``distance`` local radii from the mesh boundary;
- the enclosed volume ratio (mesh volume / surface volume);
- the distance of every mesh wall node to the input wall, relative to the local radius
  (nodes the mesher left off the wall over an opening, ``on_wall`` false, apart);

and clusters the uncovered wall into connected patches. A patch larger than a local
cross-section (``patch_area`` × π r²) that reaches deeper than ``depth`` local radii
is a *missing part*: facet sag (the bilinear wall faces cut chords of the curved wall,
about 0.08 r with 8 faces around at refinement 1) stays far below that depth.

The local radius is taken from the skeleton: the radius at the closest point of its
edges (sampled at a quarter of the smaller end radius), which the skeleton's own radius
estimate (inscribed spheres of the signed distance) provides. A patch is judged by the
smaller of that radius and its own (:func:`_own_radius`): a side vessel the skeleton never
entered has no skeleton radius of its own, and the parent's would hide it.

A voxel (staircase) input surface is itself only known to half its voxel step: the
step is measured from the surface (:func:`voxel_step`) and half of it added to the
distance a wall point may lie from the mesh (``tolerance``).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import numpy as np

#: Patches reported in full (the largest first); the rest are only counted.
MAX_PATCHES = 10
#: check_coverage's defaults (its filter's registration), with which the extraction's spur
#: rule judges (skeleton.spur_wall; not the chain's check_coverage settings)
DISTANCE, PATCH_AREA, DEPTH, END_DEPTH = 0.1, 1.0, 0.3, 1.5
#: Edges exactly along each grid axis a voxel surface must have to count as one.
VOXEL_EDGES = 8


@dataclass
class MissingPart:
    """One connected patch of the input wall that the mesh does not reach."""

    area: float
    cross_sections: float
    share: float
    depth: float
    position: np.ndarray
    caps: list = field(default_factory=list)
    #: skeleton node nearest to where the part leaves the meshed vessel (its shallowest face)
    skeleton_node: int = -1
    branch: int = -1
    #: farthest mesh wall node off the input wall near the patch (x local radius): the mesh
    #: reaches the place, but its wall was moved off the surface there (folded blocks)
    wall_off: float = 0.0
    #: mesh wall nodes near the patch that the mesher left on their face's patch, off the
    #: wall, because no wall lay along the face's normal: the face spans the mouth of the part
    over_opening: int = 0
    #: the farthest of those off the input wall (x local radius)
    over_opening_max: float = 0.0
    #: the whole patch's uncovered area (``area`` is the part that makes it missing: its side
    #: wall or its end wall, whose ``cross_sections`` are judged)
    patch_area: float = 0.0

    def describe(self) -> str:
        """Where the patch is: the caps it reaches, the nearest skeleton node and branch, a position."""
        where = []
        if self.caps:
            where.append("cap" + ("s " if len(self.caps) > 1 else " ") + ", ".join(f"'{c}'" for c in self.caps))
        if self.skeleton_node >= 0:
            where.append(f"leaving the meshed vessel near skeleton node {self.skeleton_node} (branch {self.branch})")
        x, y, z = self.position
        where.append(f"around ({x:.4g}, {y:.4g}, {z:.4g})")
        return ", ".join(where)

    def as_dict(self) -> dict:
        return {
            "area": float(self.area),
            "patch_area": float(self.patch_area),
            "cross_sections": float(self.cross_sections),
            "share": float(self.share),
            "depth_rel": float(self.depth),
            "position": [float(v) for v in self.position],
            "caps": list(self.caps),
            "skeleton_node": int(self.skeleton_node),
            "branch": int(self.branch),
            "wall_off_rel": float(self.wall_off),
            "nodes_over_opening": int(self.over_opening),
            "over_opening_max_rel": float(self.over_opening_max),
        }

    def cause(self, depth: float = 0.3) -> str:
        """Why the mesh misses the part, and a remedy: its wall nodes moved off the wall
        (``wall_off`` beyond ``depth``), or a vessel the skeleton never entered (the mesh's
        wall faces may span its mouth: ``over_opening``)."""
        if self.wall_off > depth:
            return (
                f"the mesh's wall nodes there lie up to {self.wall_off:.2g} radii off the input wall: its blocks "
                "reach the place, but their boundary layer folded and was moved off the wall (see compute_quality's "
                "minimum and the build_block_structure warnings on folding blocks)"
            )
        # nodes left that far off may also sit on a folded face whose ray missed the wall
        far = f", the farthest {self.over_opening_max:.2g} radii from the input wall" if self.over_opening_max > depth else ""
        mouth = (
            f"the mesh's wall spans its mouth ({self.over_opening} wall node(s) there found no wall along their "
            f"face's normal and stayed off it{far}); " if self.over_opening else ""
        )
        return mouth + "the skeleton does not reach into it (give a centerline that does, or keep clean_skeleton.graft_to_caps on)"

    def message(self, depth: float = 0.3) -> str:
        """The line a failed check prints: size, place and :meth:`cause`."""
        where = self.describe()
        return (
            f"{100 * self.share:.1f} % of the wall ({self.cross_sections:.1f} cross-sections, up to {self.depth:.2g} "
            f"radii from the mesh) {'at ' if self.caps else ''}{where}; {self.cause(depth)}"
        )


def boundary_triangles(boundary_faces: np.ndarray, order: int) -> np.ndarray:
    """Split (p+1)²-node boundary faces (tensor order) into two triangles per sub-quad."""
    p = int(order)
    i, j = np.meshgrid(np.arange(p), np.arange(p), indexing="ij")
    a = (i + (p + 1) * j).ravel()
    quads = np.stack([a, a + 1, a + p + 2, a + p + 1], axis=1)  # (p², 4) local node numbers, same turning as the face
    q = np.asarray(boundary_faces, np.int64)[:, quads].reshape(-1, 4)
    return np.concatenate([q[:, [0, 1, 2]], q[:, [0, 2, 3]]])


def enclosed_volume(vertices: np.ndarray, triangles: np.ndarray) -> float:
    """Volume enclosed by a closed triangulation (divergence theorem), any orientation."""
    v = np.asarray(vertices, np.float64)[np.asarray(triangles, np.int64)]
    return abs(float(np.einsum("ij,ij->i", v[:, 0], np.cross(v[:, 1], v[:, 2])).sum()) / 6.0)


def skeleton_radius(points, skeleton_points, skeleton_edges, skeleton_radii):
    """Radius of the skeleton at its closest point to each point, and that point's node.

    Returns
    -------
    radius : (n,) float64
    node : (n,) int64
        The skeleton node nearest to the closest sample.
    gap : (n,) float64
        Distance from each point to the skeleton sample.
    """
    from scipy.spatial import cKDTree

    sp = np.asarray(skeleton_points, np.float64).reshape(-1, 3)
    sr = np.asarray(skeleton_radii, np.float64).reshape(-1)
    e = np.asarray(skeleton_edges, np.int64).reshape(-1, 2)
    good = np.isfinite(sr) & (sr > 0)
    sr = np.where(good, sr, np.median(sr[good]) if good.any() else 1.0)
    samples, radii, nodes = [sp], [sr], [np.arange(len(sp))]
    if len(e):
        a, b = e[:, 0], e[:, 1]
        length = np.linalg.norm(sp[b] - sp[a], axis=1)
        k = np.clip(np.ceil(length / (0.25 * np.minimum(sr[a], sr[b]))), 1, 64).astype(np.int64)
        edge = np.repeat(np.arange(len(e)), k - 1)
        t = (np.arange(len(edge)) - np.repeat(np.cumsum(k - 1) - (k - 1), k - 1) + 1) / np.repeat(k, k - 1)
        samples.append(sp[a[edge]] + t[:, None] * (sp[b[edge]] - sp[a[edge]]))
        radii.append((1 - t) * sr[a[edge]] + t * sr[b[edge]])
        nodes.append(np.where(t < 0.5, a[edge], b[edge]))
    samples, radii, nodes = np.concatenate(samples), np.concatenate(radii), np.concatenate(nodes)
    gap, near = cKDTree(samples).query(np.asarray(points, np.float64).reshape(-1, 3), workers=-1)
    return radii[near], nodes[near], gap


def _wall_to_mesh(V, WF, mesh_tree, tri, boundary_ids, skeleton, distance, tolerance=0.0):
    """Distances from four area-weighted samples per wall triangle (the centroid and the
    centres of the three corner sub-triangles) to the mesh boundary, × local radius, and
    the distance beyond which each sample is uncovered: ``distance`` plus the absolute
    ``tolerance``, × the same radius.

    The corner samples are queried only where they can be farther than ``distance``: a
    distance moves no more than the point does, so a triangle whose centroid is closer
    than ``distance`` minus its corners' offset keeps the centroid's value for them.

    Returns rel (m, 4), limit (m, 4), beyond (m, 4: the closest mesh face is an end face),
    the local radius and the nearest skeleton node of each triangle's centroid."""
    t = V[WF]
    c = t.mean(axis=1)
    corner = (2.0 / 3.0) * t + (1.0 / 3.0) * c[:, None, :]
    face_r, face_node, _ = skeleton_radius(c, *skeleton)
    sq, tri_c = mesh_tree.closest(c)[:2]
    half = len(tri) // 2
    per_face = max(half // max(len(boundary_ids), 1), 1)
    end_face = np.asarray(boundary_ids)[(np.arange(len(tri)) % max(half, 1)) // per_face] > 0
    rel_c = np.sqrt(sq) / face_r
    reach = np.linalg.norm(corner - c[:, None, :], axis=2).max(axis=1) / face_r
    rel = np.repeat(rel_c[:, None], 4, axis=1)
    limit = np.repeat((distance + tolerance / face_r)[:, None], 4, axis=1)
    beyond = np.repeat(end_face[tri_c][:, None], 4, axis=1)
    check = np.flatnonzero(rel_c + reach > distance)  # the limit is never below distance
    if len(check):
        p = corner[check].reshape(-1, 3)
        r_k = skeleton_radius(p, *skeleton)[0]
        sq_k, tri_k = mesh_tree.closest(p)[:2]
        rel[check, 1:] = (np.sqrt(sq_k) / r_k).reshape(-1, 3)
        limit[check, 1:] = (distance + tolerance / r_k).reshape(-1, 3)
        beyond[check, 1:] = end_face[tri_k].reshape(-1, 3)
    return rel, limit, beyond, face_r, face_node


def _patches(faces, n_vertices, uncovered):
    """Connected components (through shared vertices) of the uncovered faces; -1 elsewhere."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    idx = np.flatnonzero(uncovered)
    label = np.full(len(faces), -1, np.int64)
    if len(idx) == 0:
        return label, 0
    f = faces[idx]
    # faces x vertices incidence; two uncovered faces sharing a vertex are one patch
    inc = coo_matrix((np.ones(f.size), (np.repeat(np.arange(len(idx)), 3), f.ravel())), shape=(len(idx), n_vertices)).tocsr()
    n, lab = connected_components(inc @ inc.T, directed=False)
    label[idx] = lab
    return label, n


class SurfaceFacts:
    """What :func:`measure_coverage` asks of the input surface alone, each computed once on
    first use: its :func:`voxel_step` and enclosed volume (~0.06 s CPU on the ICA's 150,000
    triangles), and for :func:`_own_radius` its orientation and Taubin-smoothed copy (~0.1 s).
    :func:`surface_facts` keeps one per surface object, so ``decimate_surface`` computes the
    first two while pymeshlab decimates (:mod:`vmesh.preload`), from the arrays the measure
    uses."""

    def __init__(self, vertices, faces):
        self.vertices = np.ascontiguousarray(vertices, np.float64)
        self.faces = np.ascontiguousarray(faces, np.int64)

    def matches(self, vertices, faces) -> bool:
        """Whether these facts are of exactly ``vertices`` and ``faces``."""
        return (self.vertices is vertices or np.array_equal(self.vertices, vertices)) and (self.faces is faces or np.array_equal(self.faces, faces))

    def compute(self) -> "SurfaceFacts":
        """Compute now what every measure uses: the voxel step and the volume. The smoothed
        copy stays lazy: only a measure with uncovered patches asks for it (the ICA has none),
        and computing it ahead would cost 0.1 s CPU for nothing on a busy machine."""
        for name in ("voxel_step", "volume"):
            getattr(self, name)
        return self

    @functools.cached_property
    def voxel_step(self) -> float:
        return voxel_step(self.vertices, self.faces)

    @functools.cached_property
    def volume(self) -> float:
        return enclosed_volume(self.vertices, self.faces)

    @functools.cached_property
    def inward(self) -> bool:
        """The faces point inward (negative signed volume)."""
        from .topology import signed_volume

        return bool(signed_volume(self.vertices, self.faces) < 0)

    @functools.cached_property
    def smoothed(self) -> np.ndarray:
        """The vertices after 10 Taubin steps (:func:`_own_radius`'s normals)."""
        from ..preprocess import taubin_smooth

        return taubin_smooth(self.vertices, self.faces, 10)


def surface_facts(surface) -> SurfaceFacts:
    """The :class:`SurfaceFacts` of a :class:`~vmesh.surface.SurfaceMesh`, one per surface
    object (cached with its trees, :func:`vmesh.geometry.projection.cached_for_surface`)."""
    from .projection import cached_for_surface

    return cached_for_surface(surface, "coverage facts", lambda: SurfaceFacts(surface.vertices, surface.faces))


def measure_coverage(
    surface_vertices,
    surface_faces,
    cap_faces,
    cap_names,
    mesh_points,
    boundary_faces,
    boundary_ids,
    order,
    skeleton_points,
    skeleton_edges,
    skeleton_radii,
    distance: float = DISTANCE,
    patch_area: float = PATCH_AREA,
    depth: float = DEPTH,
    end_depth: float = END_DEPTH,
    branches=None,
    wall_tree=None,
    on_wall=None,
    tolerance: float | None = None,
    wall_projector=None,
    own_radius: bool = True,
    surface_tree=None, facts=None,  # TriangleBVH, SurfaceFacts
) -> tuple[dict, list]:
    """Measure how much of the input wall the mesh boundary misses.

    Parameters
    ----------
    surface_vertices, surface_faces : arrays
        The closed input surface the chain meshed (repaired and capped).
    cap_faces : list of (m_i,) int arrays
        Triangles of each cap in ``surface_faces`` (left out of the wall).
    cap_names : list of str
    mesh_points, boundary_faces, boundary_ids, order
        The mesh's nodes, its boundary faces ((p+1)² nodes in tensor order), their ids
        (0 on the wall) and the order p.
    skeleton_points, skeleton_edges, skeleton_radii : arrays
        The skeleton the mesh was built on (local radius, names of missing parts).
    distance : float
        Wall farther than this many local radii from the mesh boundary is uncovered.
    patch_area : float
        A connected uncovered patch larger than this many local cross-sections
        (π r², r at its deepest point) ...
    depth : float
        ... and reaching farther than this many local radii from the mesh is a missing part.
    end_depth : float
        Depth allowed to a patch beyond one of the mesh's end faces (a rounded closed
        end past the last section, where no flat cap was found: a hemisphere is 1 r deep).
    branches : list of node arrays, optional
        Skeleton branches (node paths), to name the branch of a missing part.
    wall_tree, surface_tree, facts : TriangleBVH, TriangleBVH, SurfaceFacts, optional
        Trees of the wall triangles (no caps) and of all triangles (for :func:`_own_radius`), and
        the surface's :func:`surface_facts` (used when of these arrays), shared with the chain (None: built here).
    on_wall : (n,) bool, optional
        Nodes the mesher put on the wall (``HexMesh.on_wall``; None: all), see :func:`_wall_node_stats`.
    tolerance : float, optional
        Absolute distance added to ``distance`` before wall counts as uncovered (None: half
        the surface's :func:`voxel_step`, 0 on a surface that is no staircase).
    wall_projector : SurfaceProjector or CapKeepingProjector, optional
        The mesher's projector, which measures the wall nodes (default ``wall_tree``).
    own_radius : bool
        Judge a patch by the smaller of the skeleton's radius and its own (:func:`_own_radius`).

    Returns
    -------
    summary : dict
        The report's ``coverage`` section: shares, areas, volumes, relative distances,
        patch counts and the missing parts as dicts.
    missing : list of MissingPart
        Largest first.
    """
    from .bvh import TriangleBVH

    V, F = np.ascontiguousarray(surface_vertices, np.float64), np.ascontiguousarray(surface_faces, np.int64)
    facts = facts if facts is not None and facts.matches(V, F) else SurfaceFacts(V, F)
    X = np.ascontiguousarray(mesh_points, np.float64)
    wall, cap_of_vertex = _wall_and_caps(F, len(V), cap_faces)
    WF = F[wall]
    tri = boundary_triangles(boundary_faces, order)
    mesh_tree = TriangleBVH(X, tri)
    # input wall -> mesh boundary, at four area-weighted samples per triangle
    area = 0.5 * np.linalg.norm(np.cross(V[WF[:, 1]] - V[WF[:, 0]], V[WF[:, 2]] - V[WF[:, 0]]), axis=1)
    skeleton = (skeleton_points, skeleton_edges, skeleton_radii)
    tolerance = 0.5 * facts.voxel_step if tolerance is None else float(tolerance)
    rel, limit, beyond, face_r, face_node = _wall_to_mesh(V, WF, mesh_tree, tri, boundary_ids, skeleton, distance, tolerance)
    far = rel > limit
    # the end wall (closest to an end face, or past its plane near its axis) to the verdict's
    # end_depth: the end cap of a surface without flat caps, left out as flat caps are
    at_end_face = beyond | _past_end_faces(X, boundary_faces, boundary_ids, V[WF].mean(axis=1))[:, None]
    end_cap = far & at_end_face & (rel <= end_depth)
    wall_tree = TriangleBVH(V, WF) if wall_tree is None else wall_tree
    off = _wall_node_distances(X, boundary_faces, boundary_ids, wall_tree if wall_projector is None else wall_projector, *skeleton, on_wall)
    node_of_branch = _branch_of_node(branches, len(np.asarray(skeleton_points).reshape(-1, 3)))
    missing, n_patches, n_missing = _missing_parts(  # end wall: closest to an end face, or past one near its axis
        V, WF, area, rel, far, at_end_face, face_r, face_node, cap_of_vertex, cap_names,
        patch_area, depth, end_depth, node_of_branch, off, F if own_radius else None, surface_tree, facts,
    )
    summary = _coverage_summary(distance, area, rel, far & ~end_cap, end_cap, (facts.volume, enclosed_volume(X, tri)), off, n_patches, missing, n_missing)
    return {**summary, "voxel_step": float(facts.voxel_step), "tolerance": float(tolerance)}, missing


def _coverage_summary(distance, area, rel, uncovered, end_cap, volumes, off, n_patches, missing, n_missing) -> dict:
    """:func:`measure_coverage`'s summary: the shares of the wall (triangle ``area``, four
    samples each) ``uncovered`` and past the end faces (``end_cap``), the samples'
    distances ``rel``, the ``volumes`` (surface, mesh), the wall-node statistics of ``off``
    and the patches and missing parts."""
    total = float(area.sum())
    uncovered_area = float((area[:, None] * uncovered).sum() / 4.0)
    beyond_area = float((area[:, None] * end_cap).sum() / 4.0)
    surface_volume, mesh_volume = volumes
    return {
        "distance_rel": float(distance),
        "uncovered_share": uncovered_area / total if total > 0 else 0.0,
        "uncovered_area": uncovered_area,
        "surface_area": total,
        "beyond_ends_share": beyond_area / total if total > 0 else 0.0,
        "surface_max_rel": float(rel.max()) if rel.size else 0.0,
        "surface_mean_rel": float((rel.mean(axis=1) * area).sum() / total) if total > 0 else 0.0,
        "volume_ratio": mesh_volume / surface_volume if surface_volume > 0 else float("nan"),
        "mesh_volume": mesh_volume,
        "surface_volume": surface_volume,
        **_wall_node_stats(off),
        "patches": int(n_patches),
        "missing_parts": int(n_missing),
        "missing": [m.as_dict() for m in missing],
    }


def _past_end_faces(X, boundary_faces, boundary_ids, points) -> np.ndarray:
    """Whether each point lies past one of the mesh's open end faces: beyond the face's
    plane (outward: away from the mesh next to it) and within 1.5 x its radius of its
    axis."""
    faces, ids = np.asarray(boundary_faces), np.asarray(boundary_ids)
    out = np.zeros(len(points), bool)
    for k in np.unique(ids[ids > 0]).tolist():
        P = X[np.unique(faces[ids == k])]
        c = P.mean(axis=0)
        n = np.linalg.svd(P - c, full_matrices=False)[2][-1]  # the full U is (k, k)
        R = float(np.linalg.norm(P - c, axis=1).max())
        # the mesh lies on the inner side; the box test only spares the norms far away
        box = np.flatnonzero((np.abs(X - c) < 1.5 * R).all(axis=1))
        near = box[np.linalg.norm(X[box] - c, axis=1) < 1.5 * R]
        if (X[near].mean(axis=0) - c) @ n > 0:
            n = -n
        rel = points - c
        along = rel @ n
        ahead = np.flatnonzero(along > 0)
        lateral = np.linalg.norm(rel[ahead] - along[ahead, None] * n, axis=1)
        out[ahead[lateral < 1.5 * R]] = True
    return out


def _wall_node_distances(X, boundary_faces, boundary_ids, wall, skeleton_points, skeleton_edges, skeleton_radii, on_wall=None):
    """The mesh wall nodes' positions, their distances to the input wall (``wall``: a
    TriangleBVH, or a projector, whose kept caps count as wall), relative to the local
    radius, and which of them the mesher put on the wall."""
    wall_nodes = np.unique(np.asarray(boundary_faces)[np.asarray(boundary_ids) == 0])
    if len(wall_nodes) == 0:
        return np.zeros((1, 3)), np.zeros(1), np.ones(1, bool)
    r_n = skeleton_radius(X[wall_nodes], skeleton_points, skeleton_edges, skeleton_radii)[0]
    placed = np.ones(len(wall_nodes), bool) if on_wall is None else np.asarray(on_wall, bool)[wall_nodes]
    p = X[wall_nodes]
    d = wall.project(p)[1] if hasattr(wall, "project") else np.sqrt(wall.closest(p)[0])
    return p, d / r_n, placed


def _wall_node_stats(off) -> dict:
    """Distances of the wall nodes off the input wall (``off`` of :func:`_wall_node_distances`).

    ``wall_node_max_rel`` / ``wall_node_mean_rel`` are over every mesh wall node. A
    wall-face node the mesher did not put on the wall stayed on its face's patch: no wall lay
    along the face's normal (the face spans the mouth of a vessel part without skeleton, or
    the face is folded and its ray missed the wall); ``..._placed`` leave those out, and
    they are counted apart."""
    dist, placed = off[1], off[2]
    on, left = dist[placed], dist[~placed]
    return {
        "wall_node_max_rel": float(dist.max()) if dist.size else 0.0,
        "wall_node_mean_rel": float(dist.mean()) if dist.size else 0.0,
        "wall_node_max_rel_placed": float(on.max()) if on.size else 0.0,
        "wall_node_mean_rel_placed": float(on.mean()) if on.size else 0.0,
        "wall_nodes_over_openings": int(left.size),
        "over_openings_max_rel": float(left.max()) if left.size else 0.0,
    }


def _wall_and_caps(F, n_vertices, cap_faces):
    """Wall mask of the faces (caps left out; all faces when everything is cap) and the
    cap index of each vertex on a cap (-1 elsewhere)."""
    wall = np.ones(len(F), bool)
    cap_of_vertex = np.full(n_vertices, -1, np.int64)
    for k, cf in enumerate(cap_faces):
        cf = np.asarray(cf, np.int64)
        cf = cf[(cf >= 0) & (cf < len(F))]
        wall[cf] = False
        cap_of_vertex[F[cf].ravel()] = k
    if not wall.any():
        wall[:] = True
    return wall, cap_of_vertex


def _missing_parts(V, WF, area, rel, far, at_end_face, face_r, face_node, cap_of_vertex, cap_names, patch_area, depth, end_depth, node_of_branch, off, F, tree=None, facts=None):
    """Connected uncovered patches of the wall (a face is uncovered when at least two of its
    four samples are) and the missing parts among them, largest first; ``off``: the mesh
    wall nodes, their distances off the wall (x local radius) and whether the mesher put them
    on the wall, for a part's ``wall_off``: the farthest node put on the wall within the
    part's depth (plus half a radius) of its faces, where the mesh wall that misses it lies
    (and ``over_opening``: the nodes there the mesher left off the wall).

    Each patch is split by ``at_end_face`` (per sample: wall an end face of the mesh
    explains, :func:`measure_coverage`) into its **end wall** and its **side wall**, and
    each is judged on its own by :func:`judge_end_and_side` (the rule the extraction's spur
    pruning shares): the side wall as a part beside the meshed vessel (by the smaller of the
    skeleton's radius at its deepest face and the side wall's own, :func:`_own_radius` over
    the faces with two or more side samples, across the closed surface ``F``, ``tree`` its
    BVH where built; None: the skeleton's alone; ``depth``), the end wall as the vessel
    running on past an end face (by the skeleton's radius; ``end_depth``). A patch is
    missing when either is; a part's ``area``, ``share`` and ``cross_sections`` are of the
    wall that makes it missing, ``patch_area`` the whole patch's. A branch the skeleton never entered is side wall, several of its own
    cross-sections and deeper than its radius; the wall between an end face and the cap
    or rounded end beyond it is end wall, whatever mesh face lies closest to it. (Up to
    session 22 a patch was *at an end* when more than half of its far area had an end face
    as its closest mesh face: a vote that any smoothing of the end face's rim could flip,
    e.g. an end patch at 0.511 on a real graft, docs/coverage.md.)

    Returns the parts (at most :data:`MAX_PATCHES`), the patch count and the count of
    missing parts."""
    total = float(area.sum())
    label, n_patches = _patches(WF, len(V), far.sum(axis=1) >= 2)
    missing = []
    if not n_patches:
        return missing, 0, 0
    sel = label >= 0
    lab = label[sel]
    face_area = area * far.mean(axis=1)
    patch_area_sum = np.bincount(lab, weights=face_area[sel], minlength=n_patches)
    # the side wall and the end wall of each patch, measured apart
    measured = {}
    for kind, part in (("side", far & ~at_end_face), ("end", far & at_end_face)):
        part_rel = np.where(part, rel, 0.0).max(axis=1)
        part_area = np.bincount(lab, weights=(area * part.mean(axis=1))[sel], minlength=n_patches)
        deep_face = np.flatnonzero(sel)[_deepest(part_rel[sel], lab, n_patches)]
        measured[kind] = (part_area, part_rel[deep_face] * face_r[deep_face], face_r[deep_face])
    # the side wall's own radius, over its faces (two of four samples, as a patch's faces)
    side_label = np.where((far & ~at_end_face).sum(axis=1) >= 2, label, -1)
    own = _own_radius(V, F, WF, side_label, n_patches, tree, facts) if F is not None else np.full(n_patches, np.inf)
    is_missing, _, judged_area, sections, patch_depth, patch_r = judge_end_and_side(measured["side"], measured["end"], own, patch_area, depth, end_depth)
    face_rel = rel.max(axis=1)
    big = np.flatnonzero(is_missing)
    big = big[np.argsort(-judged_area[big])]
    for k in big[:MAX_PATCHES]:
        faces_k = np.flatnonzero(label == k)
        verts = np.unique(WF[faces_k])
        caps = sorted({cap_names[c] for c in cap_of_vertex[verts] if c >= 0})
        node = int(face_node[faces_k[np.argmin(face_rel[faces_k])]])  # where the part leaves the meshed vessel
        w = face_area[faces_k]
        centre = (V[WF[faces_k]].mean(axis=1) * w[:, None]).sum(axis=0) / max(w.sum(), 1e-300)
        missing.append(
            MissingPart(
                area=float(judged_area[k]),
                cross_sections=float(sections[k]),
                share=float(judged_area[k] / total) if total > 0 else 0.0,
                patch_area=float(patch_area_sum[k]),
                depth=float(patch_depth[k]),
                position=centre,
                caps=caps,
                skeleton_node=node,
                branch=int(node_of_branch[node]) if node_of_branch is not None else -1,
                **_wall_off(V[WF[faces_k]].mean(axis=1), (patch_depth[k] + 0.5) * patch_r[k], off),
            )
        )
    return missing, n_patches, len(big)


def _deepest(values, lab, n_patches):
    """Index (into ``values``) of the largest value of each label ``0 .. n_patches - 1``."""
    order_ = np.lexsort((-values, lab))
    return order_[np.searchsorted(lab[order_], np.arange(n_patches))]


def judge_end_and_side(side, end, own_r, patch_area=PATCH_AREA, depth=DEPTH, end_depth=END_DEPTH):
    """Judge each patch's **side wall** and **end wall** apart (:func:`judge_patches`): the one
    rule of the verdict (:func:`_missing_parts`) and of the extraction's spur pruning
    (:func:`~vmesh.geometry.skeleton.spur_wall.spurs_explaining_wall`).

    Parameters
    ----------
    side, end : tuple of (n,) arrays
        Per patch, of its side wall (beside the meshed vessel) and of its end wall (past an
        end face): the area, the deepest point's distance and the skeleton's radius there.
    own_r : (n,) array
        The side wall's own radius (``inf`` where unknown); the end wall is judged by the
        skeleton's (it continues the vessel the skeleton ends in).

    Returns
    -------
    missing, side_missing, area, sections, depth_rel, radius : numpy.ndarray
        Per patch: missing (either wall is), its side wall missing, and the area,
        cross-sections, depth in radii and radius of the wall that makes it missing (its side
        wall where both do, or where neither does).
    """
    n = len(np.asarray(own_r))
    s = judge_patches(*side, own_r, np.zeros(n, bool), patch_area, depth, end_depth)
    e = judge_patches(*end, own_r, np.ones(n, bool), patch_area, depth, end_depth)
    use_end = e[0] & ~s[0]
    pick = lambda a, b: np.where(use_end, b, a)  # noqa: E731
    return (s[0] | e[0], s[0], pick(np.asarray(side[0], float), np.asarray(end[0], float))) + tuple(pick(a, b) for a, b in zip(s[1:], e[1:]))


def judge_patches(area, real_depth, skeleton_r, own_r, at_end, patch_area=PATCH_AREA, depth=DEPTH, end_depth=END_DEPTH):
    """Which uncovered patches are missing parts of the vessel: the one rule of the verdict
    (:func:`measure_coverage`) and of the extraction's spur pruning
    (:func:`~vmesh.geometry.skeleton.spur_wall.spurs_explaining_wall`).

    A patch is judged by the skeleton's radius at its deepest point, or by its own radius
    (``own_r``, ``inf`` where unknown) where that is smaller and the patch stands out by at
    least that much (``real_depth >= own_r``: a side vessel left out; a shallow patch across
    a narrow neck keeps the skeleton's), except past an end face (``at_end``: it continues
    the vessel the skeleton ends in). It is missing when it spans more than ``patch_area``
    cross-sections (pi r**2) and reaches deeper than ``depth`` radii (``end_depth`` at an end).

    Returns
    -------
    missing, sections, depth_rel, radius : numpy.ndarray
        Per patch: the verdict, its area in cross-sections, its depth in radii and the
        radius it is judged by.
    """
    real_depth = np.asarray(real_depth, float)
    own_r = np.asarray(own_r, float)
    patch_r = np.asarray(skeleton_r, float)
    patch_r = np.where(~np.asarray(at_end, bool) & (real_depth >= own_r), np.minimum(patch_r, own_r), patch_r)
    depth_rel = real_depth / patch_r
    sections = np.asarray(area, float) / (np.pi * patch_r**2)
    missing = (sections > patch_area) & (depth_rel > np.where(at_end, end_depth, depth))
    return missing, sections, depth_rel, patch_r


def _own_radius(V, F, WF, label, n_patches, tree=None, facts=None) -> np.ndarray:
    """Each uncovered patch's own radius: the median over its faces of half the chord
    across the closed surface (``V``, ``F``) along the face's inward normal.

    On a vessel's wall that chord is its diameter; the skeleton's radius is that of the
    vessel the skeleton holds, and a side vessel it never entered would be judged by its
    parent's. Normals of a Taubin-smoothed copy: a staircase's terrace normals point
    along the grid axes, not across the vessel. A chord shorter than its face's longest
    edge gives no radius (the surface does not resolve a lumen that narrow). ``tree``: the
    BVH of ``(V, F)`` where the chain built one (None: built here); ``facts``: the
    :class:`SurfaceFacts` of ``(V, F)`` (None: computed here). Faces labelled -1 are left
    out; a patch without faces keeps ``inf``."""
    from .bvh import TriangleBVH

    sel = np.flatnonzero(label >= 0)
    own = np.full(n_patches, np.inf)
    if not len(sel):
        return own
    facts = SurfaceFacts(V, F) if facts is None else facts
    T = facts.smoothed[WF[sel]]
    n = np.cross(T[:, 1] - T[:, 0], T[:, 2] - T[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1), 1e-300)[:, None]
    if facts.inward:
        n = -n  # inward faces
    c = V[WF[sel]].mean(axis=1)
    reach = 2.0 * float(np.ptp(V, axis=0).max())
    tree = TriangleBVH(V, F) if tree is None else tree
    t = tree.intersect_lines(c - 1e-9 * reach * n, -n, reach, side=1)[0]
    # a chord shorter than the face it starts from crosses a sliver (a ragged end's flap),
    # not a lumen the surface resolves: no radius from it
    tv = V[WF[sel]]
    edge = np.linalg.norm(tv - np.roll(tv, 1, axis=1), axis=2).max(axis=1)
    half = np.where(np.isfinite(t) & (t >= edge), 0.5 * t, np.inf)
    lab = label[sel]
    order_ = np.lexsort((half, lab))
    start = np.searchsorted(lab[order_], np.arange(n_patches))
    count = np.bincount(lab, minlength=n_patches)
    some = count > 0  # a patch without faces here (no side wall) keeps inf
    own[some] = half[order_[(start + count // 2)[some]]]  # the median (upper) face
    return own


def voxel_step(vertices, faces) -> float:
    """The grid step of a voxel (staircase) surface, 0 for any other surface.

    Marching cubes of a binary image puts every vertex at the middle of a grid edge, so an
    edge of the surface that runs along a grid axis is exactly one step long. The surface
    is a staircase when edges run exactly along each of the three axes and most of those
    along each axis have one length (a smooth tube meshed in rings along an axis has such
    edges along one axis only). Scans often have anisotropic voxels (a thicker slice): the
    largest of the three steps is returned."""
    V, F = np.asarray(vertices, np.float64), np.asarray(faces, np.int64)
    if len(F) == 0:
        return 0.0
    e = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    d = np.abs(V[e[:, 1]] - V[e[:, 0]])  # either direction: the same |difference|
    length = np.linalg.norm(d, axis=1)
    flat = d <= 1e-6 * np.maximum(length, 1e-300)[:, None]  # components zero (to float32 rounding)
    # each edge once, counted among the axis-aligned ones only (a smooth surface has few):
    # the same edges, in the same order, as the unique rows of all edges; only those
    # few edges' ends are put in order (sorting all 3m rows was most of the cost)
    aligned = np.flatnonzero(flat.sum(axis=1) == 2)
    ends = np.sort(e[aligned], axis=1)
    aligned = aligned[np.unique(ends[:, 0] * len(V) + ends[:, 1], return_index=True)[1]]
    length, flat = length[aligned], flat[aligned]
    steps = []
    for a in range(3):
        along = length[~flat[:, a]]
        if len(along) < VOXEL_EDGES:
            return 0.0
        h = float(np.median(along))
        if np.mean(np.abs(along - h) <= 0.01 * h) < 0.5:
            return 0.0
        steps.append(h)
    return float(max(steps))


def _wall_off(centres, reach, off) -> dict:
    """Of the mesh wall nodes ``off = (positions, distances, placed)`` within ``reach`` of
    any of ``centres``: the farthest distance of those the mesher put on the wall
    (``wall_off``, 0 when none is), the count of those it left off (``over_opening``) and
    their farthest distance (``over_opening_max``)."""
    from scipy.spatial import cKDTree

    near = cKDTree(centres).query(off[0], distance_upper_bound=reach)[0] <= reach
    moved, left = near & off[2], near & ~off[2]
    return {"wall_off": float(off[1][moved].max()) if moved.any() else 0.0, "over_opening": int(left.sum()),
            "over_opening_max": float(off[1][left].max()) if left.any() else 0.0}


def _branch_of_node(branches, n_nodes):
    """Branch index of every skeleton node (a junction node keeps the first branch through it)."""
    if branches is None:
        return None
    out = np.full(n_nodes, -1, np.int64)
    for k in range(len(branches) - 1, -1, -1):
        out[np.asarray(branches[k], np.int64)] = k
    return out
