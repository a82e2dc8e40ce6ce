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
    """

    id: int
    name: str
    center: np.ndarray
    normal: np.ndarray
    radius: float
    rim: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    faces: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))

    def as_dict(self) -> dict:
        return {
            "id": self.id,
            "name": self.name,
            "center": np.asarray(self.center).tolist(),
            "normal": np.asarray(self.normal).tolist(),
            "radius": float(self.radius),
            "rim_points": int(len(self.rim)),
            "faces": int(len(self.faces)),
        }
