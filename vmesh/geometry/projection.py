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

    entries = _entries(surface)
    if "tree" not in entries:
        entries["tree"] = TriangleBVH(surface.vertices, surface.faces)
    return entries["tree"]


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


def wall_projector(surface, caps=None) -> SurfaceProjector:
    """A projector onto ``surface`` without the triangles of ``caps`` (flat open ends).

    One projector per surface object and set of cap triangles, shared by every caller
    (the whole surface's projector shares its tree with :func:`surface_tree` and with the
    surface's :class:`~vmesh.geometry.sdf.SignedDistance`)."""
    keep = wall_faces(surface, caps)
    key = ("wall", None if keep is None else keep.tobytes())
    entries = _entries(surface)
    projector = entries.get(key)
    if projector is None:
        if keep is None:
            projector = SurfaceProjector(surface.vertices, surface.faces, tree=surface_tree(surface))
        else:
            projector = SurfaceProjector(surface.vertices, surface.faces[keep])
        entries[key] = projector
    return projector
