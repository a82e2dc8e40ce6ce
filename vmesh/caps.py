"""Open ends of a vessel (inlets and outlets) as flat caps."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class Cap:
    """A flat cap closing one open end of the vessel.

    Attributes
    ----------
    id : int
        1-based boundary id (0 is the wall), used for named boundary faces.
    name : str
        ``"inlet"`` or ``"outlet_<k>"``.
    center : (3,) float64
        Centroid of the rim.
    normal : (3,) float64
        Unit normal pointing out of the vessel.
    radius : float
        Mean distance from the rim to the centre.
    rim : (k, 3) float64
        The boundary loop, in order.
    faces : (m,) int64
        Indices of the cap's triangles in the capped surface.
    needs_end : bool
        A flat region of a closed surface whose wall behind is no tube of its size
        (:func:`~vmesh.preprocess.flat_caps_needing_an_end`): a part of an end face where a
        skeleton end reaches it, else a facet of the wall (a voxel staircase's terrace),
        which the skeleton stages turn back into wall.
    """

    id: int
    name: str
    center: np.ndarray
    normal: np.ndarray
    radius: float
    rim: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    faces: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    needs_end: bool = False

    def as_dict(self) -> dict:
        return {
            "id": self.id,
            "name": self.name,
            "center": np.asarray(self.center).tolist(),
            "normal": np.asarray(self.normal).tolist(),
            "radius": float(self.radius),
            "rim_points": int(len(self.rim)),
            "faces": int(len(self.faces)),
            **({"needs_end": True} if self.needs_end else {}),
        }
