"""Closest-point projection onto a triangle surface (parallel BVH, :mod:`vmesh.geometry.bvh`)."""

from __future__ import annotations

import numpy as np


class SurfaceProjector:
    """Closest points on a (possibly open) triangle surface.

    Used to put mesh nodes on the vessel wall; the wall excludes flat caps so that
    points near an open end are not pulled onto the cap plane.
    """

    def __init__(self, vertices: np.ndarray, faces: np.ndarray):
        from .bvh import TriangleBVH

        self.vertices = np.ascontiguousarray(vertices, dtype=np.float64)
        self.faces = np.ascontiguousarray(faces, dtype=np.int64)
        self._tree = TriangleBVH(self.vertices, self.faces)

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Closest surface points ``(n, 3)``, unsigned distances ``(n,)`` and face indices ``(n,)``."""
        p = np.ascontiguousarray(np.asarray(points, np.float64).reshape(-1, 3))
        if len(p) == 0:
            return p.copy(), np.zeros(0), np.zeros(0, np.int64)
        sq, face, closest, _ = self._tree.closest(p)
        return closest, np.sqrt(sq), face

    def __call__(self, points):
        return self.project(points)[0]


def wall_projector(surface, caps=None) -> SurfaceProjector:
    """A projector onto ``surface`` without the triangles of ``caps`` (flat open ends)."""
    faces = surface.faces
    if caps:
        drop = np.concatenate([np.asarray(c.faces, np.int64) for c in caps]) if caps else np.zeros(0, np.int64)
        if len(drop):
            keep = np.ones(len(faces), bool)
            keep[drop[(drop >= 0) & (drop < len(faces))]] = False
            if keep.any():
                faces = faces[keep]
    return SurfaceProjector(surface.vertices, faces)
