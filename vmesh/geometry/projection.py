"""Closest-point projection onto a triangle surface (parallel BVH, :mod:`vmesh.geometry.bvh`).

The trees are cached per surface layer: a chain's filters (``build_sdf``,
``build_block_structure``, ``mesh_transfinite``, ``compute_quality``, ``check_coverage``)
share one tree of the fine surface and one of its wall (the surface without its flat caps)
instead of building their own. A cache entry lives as long as the
:class:`~vmesh.surface.SurfaceMesh` object it was made from: a filter that changes the
surface puts a new object into the context, and the next query builds a new tree. Layers
are never changed in place (the chain's contract), which is what makes this safe.
"""

from __future__ import annotations

import weakref

import numpy as np

#: id(surface) -> {key: TriangleBVH or SurfaceProjector}; entries leave with their surface
_CACHE: dict[int, dict] = {}


class SurfaceProjector:
    """Closest points on a (possibly open) triangle surface.

    Used to put mesh nodes on the vessel wall; the wall excludes flat caps so that
    points near an open end are not pulled onto the cap plane.

    Parameters
    ----------
    vertices, faces : arrays of the surface
    tree : TriangleBVH, optional
        A tree already built over exactly these triangles (shared, not rebuilt).
    """

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, tree=None):
        from .bvh import TriangleBVH

        self.vertices = np.ascontiguousarray(vertices, dtype=np.float64)
        self.faces = np.ascontiguousarray(faces, dtype=np.int64)
        self._tree = TriangleBVH(self.vertices, self.faces) if tree is None else tree

    @property
    def tree(self):
        """The :class:`~vmesh.geometry.bvh.TriangleBVH` answering the queries."""
        return self._tree

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Closest surface points ``(n, 3)``, unsigned distances ``(n,)`` and face indices ``(n,)``."""
        p = np.ascontiguousarray(np.asarray(points, np.float64).reshape(-1, 3))
        if len(p) == 0:
            return p.copy(), np.zeros(0), np.zeros(0, np.int64)
        sq, face, closest, _ = self._tree.closest(p)
        return closest, np.sqrt(sq), face

    def __call__(self, points):
        return self.project(points)[0]


#: A point stays on a cap (rather than going to the wall) when the closest point of the
#: closed surface is on that cap and the wall is farther than this x the cap's keep radius
#: (the cap's radius, or the radius of a thinner vessel in contact at its end: see
#: :func:`wall_projector`) ...
CAP_KEEP_RADIUS = 0.25
#: ... and this many times farther than the cap (docs/optimiser.md, h18/cap)
CAP_KEEP_RATIO = 4.0
#: Face index a projection answers for a point on a contact cut
#: (:mod:`vmesh.geometry.contact_cut`) ...
ON_CUT = -1
#: ... and for a point kept on a cap (:class:`CapKeepingProjector`): no wall face either
ON_CAP = -2


class CapKeepingProjector:
    """A wall projector (caps left out) that keeps a point on one of its caps where the
    closed surface's closest point is on that cap and the wall lies far beyond it.

    Used for the caps of open ends that another vessel touches (a contact cut at the end
    node). The wall projector leaves caps out so that an open end's own rim nodes go to
    the wall, not to the cap's plane: those lie within a chord's sagitta of the wall. A
    point far from the wall but on such a cap is the other vessel's, whose lumen the cap
    closes (the builder's section rays, cast in the closed surface, stop on the cap
    there). Sending it to the nearest wall would take it across that vessel's lumen or
    onto the contact cut; it stays on the cap, where the rays put it.

    Parameters
    ----------
    wall : SurfaceProjector
        The projector onto the surface without its caps.
    closed : TriangleBVH
        The tree of the whole (closed) surface.
    cap_of_face : (m,) int array
        The index into ``cap_radius`` of each closed-surface face's cap, -1 for the wall.
    cap_radius : (k,) array
        The radius each cap's rule is judged against (:func:`keep_radii`).
    """

    def __init__(self, wall: SurfaceProjector, closed, cap_of_face: np.ndarray, cap_radius: np.ndarray):
        self.wall = wall
        self.closed = closed
        self.cap_of_face = np.asarray(cap_of_face, np.int64)
        self.cap_radius = np.asarray(cap_radius, float)
        self.least_far = CAP_KEEP_RADIUS * float(self.cap_radius.min())

    @property
    def tree(self):
        """The wall's :class:`~vmesh.geometry.bvh.TriangleBVH` (caps left out)."""
        return self.wall.tree

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """As :meth:`SurfaceProjector.project`; a point kept on a cap gets face index :data:`ON_CAP`."""
        closest, d, face = self.wall.project(points)
        far = np.flatnonzero(d > self.least_far)  # only these can be kept: one closed query for them
        if not len(far):
            return closest, d, face
        p = np.ascontiguousarray(np.asarray(points, np.float64).reshape(-1, 3)[far])
        sq, f_closed, on_closed, _ = self.closed.closest(p)
        cap = self.cap_of_face[f_closed]
        d_cap = np.sqrt(sq)
        radius = self.cap_radius[np.maximum(cap, 0)]
        keep = (cap >= 0) & (d[far] > CAP_KEEP_RADIUS * radius) & (d[far] > CAP_KEEP_RATIO * d_cap)
        if not keep.any():
            return closest, d, face
        i = far[keep]
        closest, d, face = closest.copy(), d.copy(), face.copy()
        closest[i], d[i], face[i] = on_closed[keep], d_cap[keep], ON_CAP
        return closest, d, face

    def __call__(self, points):
        return self.project(points)[0]


def _entries(surface) -> dict:
    """The cache of ``surface`` (created, with its clean-up, on first use)."""
    key = id(surface)
    entries = _CACHE.get(key)
    if entries is None:
        entries = _CACHE[key] = {}
        weakref.finalize(surface, _CACHE.pop, key, None)
    return entries


def cached_trees(surface) -> dict:
    """The trees and projectors built so far over ``surface`` (for
    :class:`vmesh.cache.DiskPrefixCache`, which keeps them with the surface)."""
    return dict(_CACHE.get(id(surface), {}))


def adopt_trees(surface, trees: dict) -> None:
    """Cache ``trees`` (from :func:`cached_trees` of an equal surface) for ``surface``."""
    _entries(surface).update(trees)


def surface_tree(surface):
    """The :class:`~vmesh.geometry.bvh.TriangleBVH` of all of ``surface``'s triangles, built
    once per surface object (cached; see the module docstring)."""
    from .bvh import TriangleBVH

    return cached_for_surface(surface, "tree", lambda: TriangleBVH(surface.vertices, surface.faces))


def cached_for_surface(surface, key, build):
    """``build()``, computed once per surface object and ``key`` and cached with its trees
    (kept with them in the prefix disk cache, :func:`cached_trees`)."""
    entries = _entries(surface)
    if key not in entries:
        entries[key] = build()
    return entries[key]


def surface_distance(surface, sign: str = "auto"):
    """The :class:`~vmesh.geometry.sdf.SignedDistance` of ``surface``
    (``SignedDistance.from_surface``), built once per surface object and sign: the fine
    surface's, which ``build_sdf`` refines on, is built while pymeshlab decimates
    (``decimate_surface``, :mod:`vmesh.preload`)."""
    from .sdf import SignedDistance

    return cached_for_surface(surface, ("signed distance", sign), lambda: SignedDistance.from_surface(surface, sign=sign))


def wall_faces(surface, caps=None) -> np.ndarray | None:
    """Indices of ``surface``'s faces without the triangles of ``caps``; ``None`` when
    that is every face (no caps, or nothing but caps)."""
    drop = np.concatenate([np.asarray(c.faces, np.int64) for c in caps]) if caps else np.zeros(0, np.int64)
    n = len(surface.faces)
    drop = drop[(drop >= 0) & (drop < n)]
    if len(drop) == 0:
        return None
    keep = np.ones(n, bool)
    keep[drop] = False
    return np.flatnonzero(keep) if keep.any() and not keep.all() else None


def wall_projector(surface, caps=None, kept=()) -> SurfaceProjector | CapKeepingProjector:
    """A projector onto ``surface`` without the triangles of ``caps`` (flat open ends);
    with ``kept`` (cap ids: open ends another vessel touches) points far from the wall
    whose closest point is on one of those caps stay there (:class:`CapKeepingProjector`).

    ``kept`` may map each cap id to the radius of the thinnest vessel in contact at that
    end (``blocks.info["touched_caps"]``): "far from the wall" is then judged against the
    lesser of that radius and the cap's (:func:`keep_radii`). A cap that cuts through a
    passing vessel much thinner than itself has all of that vessel's lumen within a
    quarter of the cap's radius of the wall, so by the cap's radius alone none of its cap
    points would stay on the cap where the section rays put them (s0 g0015 extracted).

    One projector per surface object, set of cap triangles and kept caps, shared by every
    caller (the whole surface's projector shares its tree with :func:`surface_tree` and
    with the surface's :class:`~vmesh.geometry.sdf.SignedDistance`)."""
    keep = wall_faces(surface, caps)
    radii = keep_radii(caps, kept) if keep is not None else {}
    key = ("wall", None if keep is None else keep.tobytes(), *sorted(radii.items()))
    entries = _entries(surface)
    projector = entries.get(key)
    if projector is None:
        if keep is None:
            projector = SurfaceProjector(surface.vertices, surface.faces, tree=surface_tree(surface))
        elif radii:  # the plain wall projector (cached, its tree shared), wrapped
            projector = _cap_keeping(surface, [c for c in caps if int(c.id) in radii], wall_projector(surface, caps), radii)
        else:
            projector = SurfaceProjector(surface.vertices, surface.faces[keep])
        entries[key] = projector
    return projector


def caps_on(surface, fine, caps) -> list | None:
    """``caps`` (triangles of the ``fine`` surface) as triangles of ``surface``, another
    triangulation of it (the coarse surface of ``decimate_surface``): a triangle of
    ``surface`` belongs to the cap that holds the fine triangle closest to its centroid.
    None without caps; ``caps`` themselves when ``surface`` is ``fine``."""
    import dataclasses

    if not caps or surface is fine:
        return caps or None
    n = len(fine.faces)
    cap_of_face = np.full(n, -1, np.int64)
    for k, cap in enumerate(caps):
        f = np.asarray(cap.faces, np.int64)
        cap_of_face[f[(f >= 0) & (f < n)]] = k
    centroid = np.asarray(surface.vertices, np.float64)[np.asarray(surface.faces, np.int64)].mean(axis=1)
    on = cap_of_face[surface_tree(fine).closest(centroid)[1]]
    return [dataclasses.replace(cap, faces=np.flatnonzero(on == k)) for k, cap in enumerate(caps)]


def keep_radii(caps, kept) -> dict:
    """The radius each kept cap's keep rule is judged against, by cap id: the cap's own
    radius, or the lesser radius ``kept`` maps it to (the thinnest vessel in contact at its
    end); a plain sequence of ids keeps the caps' own radii. Ids of no cap in ``caps`` are
    left out."""
    own = {int(c.id): float(c.radius) for c in caps or []}
    lumen = kept if isinstance(kept, dict) else dict.fromkeys(kept or (), np.inf)
    return {int(k): min(own[int(k)], float(r)) for k, r in lumen.items() if int(k) in own}


def _cap_keeping(surface, caps, wall: SurfaceProjector, radii: dict) -> SurfaceProjector | CapKeepingProjector:
    """``wall`` keeping the triangles of ``caps`` where :class:`CapKeepingProjector` keeps
    them, each judged against its radius in ``radii`` (by cap id; ``wall`` itself when
    those caps have no triangles)."""
    n = len(surface.faces)
    cap_of_face = np.full(n, -1, np.int64)
    radius = []
    for cap in caps:
        f = np.asarray(cap.faces, np.int64)
        f = f[(f >= 0) & (f < n)]
        if len(f):
            cap_of_face[f] = len(radius)
            radius.append(radii[int(cap.id)])
    return CapKeepingProjector(wall, surface_tree(surface), cap_of_face, np.asarray(radius)) if radius else wall
