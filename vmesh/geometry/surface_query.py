"""The surface-query interface of the signed distances (the ``sdf`` layer of a run).

:class:`~vmesh.geometry.sdf.SignedDistance`, :class:`~vmesh.geometry.sdf.TwoStepSignedDistance`
and :class:`~vmesh.geometry.octree_sdf.OctreeSignedDistance` implement it; the filters use
these members directly.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np


class SurfaceQuery(Protocol):
    """What the filters ask of a signed distance (the ``sdf`` layer): the interface that
    :class:`SignedDistance`, :class:`TwoStepSignedDistance` and
    :class:`~vmesh.geometry.octree_sdf.OctreeSignedDistance` implement.

    ``fine`` is the query of the finest surface the object holds without a coarse search
    in front (the fine :class:`SignedDistance` of a two-step distance; the object itself
    otherwise); ``coarse`` is the one searched first (the object itself when there is no
    such step). Distances are positive inside the vessel.
    """

    name: str
    vertices: np.ndarray
    faces: np.ndarray
    bounds: tuple
    diagonal: float
    sign_method: str

    @property
    def n_faces(self) -> int: ...

    @property
    def fine(self) -> "SurfaceQuery": ...

    @property
    def coarse(self) -> "SurfaceQuery": ...

    def project(self, points) -> tuple[np.ndarray, np.ndarray, np.ndarray]: ...

    def distance(self, points) -> np.ndarray: ...

    def closest_points(self, points) -> np.ndarray: ...

    def gradient(self, points) -> np.ndarray: ...

    def intersect_lines(self, points, directions, reach, side=None) -> tuple[np.ndarray, np.ndarray]: ...

    def winding_number(self, points) -> np.ndarray: ...

    def ray_winding_number(self, points) -> np.ndarray: ...
