"""Triangle surfaces: a plain data class of numpy arrays and its diagnostics."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .geometry import topology


@dataclass
class SurfaceInfo:
    """Diagnostics of a triangle surface (what ``vmesh info`` prints)."""

    n_vertices: int
    n_triangles: int
    n_boundary_loops: int
    n_nonmanifold_edges: int
    n_components: int
    consistently_oriented: bool
    orientation: str
    volume: float
    bbox_min: list
    bbox_max: list
    diagonal: float
    euler_characteristic: int

    @property
    def closed(self) -> bool:
        return self.n_boundary_loops == 0

    @property
    def manifold(self) -> bool:
        return self.n_nonmanifold_edges == 0

    def as_dict(self) -> dict:
        d = dict(self.__dict__)
        d["closed"] = self.closed
        d["manifold"] = self.manifold
        return d

    def __str__(self) -> str:
        lo = ", ".join(f"{x:.4g}" for x in self.bbox_min)
        hi = ", ".join(f"{x:.4g}" for x in self.bbox_max)
        return "\n".join(
            [
                f"vertices            {self.n_vertices}",
                f"triangles           {self.n_triangles}",
                f"open boundary loops {self.n_boundary_loops}",
                f"non-manifold edges  {self.n_nonmanifold_edges}",
                f"components          {self.n_components}",
                f"orientation         {self.orientation}"
                + ("" if self.consistently_oriented else " (inconsistent)"),
                f"volume              {self.volume:.6g}",
                f"bounding box        ({lo}) - ({hi}), diagonal {self.diagonal:.4g}",
                f"Euler characteristic {self.euler_characteristic}",
            ]
        )


@dataclass
class SurfaceMesh:
    """A triangle surface.

    Attributes
    ----------
    vertices : (n, 3) float64 array
    faces : (m, 3) int64 array of vertex indices
    name : str
        Where it came from (file name), for messages.
    face_data : dict of str -> (m, ...) arrays
        Per-face arrays kept from the input file (e.g. ``ModelFaceID``).
    """

    vertices: np.ndarray
    faces: np.ndarray
    name: str = ""
    face_data: dict = field(default_factory=dict)

    def __post_init__(self):
        self.vertices = np.ascontiguousarray(self.vertices, dtype=np.float64).reshape(-1, 3)
        self.faces = np.ascontiguousarray(self.faces, dtype=np.int64).reshape(-1, 3)

    def __repr__(self) -> str:  # counts, not the arrays
        return f"SurfaceMesh({self.name!r}: {self.n_vertices} vertices, {self.n_faces} triangles)"

    @property
    def n_vertices(self) -> int:
        return len(self.vertices)

    @property
    def n_faces(self) -> int:
        return len(self.faces)

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        return self.vertices.min(axis=0), self.vertices.max(axis=0)

    @property
    def diagonal(self) -> float:
        lo, hi = self.bounds
        return float(np.linalg.norm(hi - lo))

    def copy(self, **changes) -> "SurfaceMesh":
        kw = dict(
            vertices=self.vertices.copy(),
            faces=self.faces.copy(),
            name=self.name,
            face_data={k: v.copy() for k, v in self.face_data.items()},
        )
        kw.update(changes)
        return SurfaceMesh(**kw)

    def info(self) -> SurfaceInfo:
        f = self.faces
        loops = topology.boundary_loops(f) if len(f) else []
        oriented = topology.is_consistently_oriented(f)
        vol = topology.signed_volume(self.vertices, f) if len(f) else 0.0
        if not oriented:
            orientation = "inconsistent"
        else:
            orientation = "outward" if vol > 0 else "inward"
            if loops:
                orientation += " (estimated: surface is open)"
        lo, hi = self.bounds if self.n_vertices else (np.zeros(3), np.zeros(3))
        return SurfaceInfo(
            n_vertices=self.n_vertices,
            n_triangles=self.n_faces,
            n_boundary_loops=len(loops),
            n_nonmanifold_edges=len(topology.non_manifold_edges(f)) if len(f) else 0,
            n_components=topology.face_components(f, self.n_vertices)[0],
            consistently_oriented=oriented,
            orientation=orientation,
            volume=abs(vol),
            bbox_min=lo.tolist(),
            bbox_max=hi.tolist(),
            diagonal=float(np.linalg.norm(hi - lo)),
            euler_characteristic=topology.euler_characteristic(f) if len(f) else 0,
        )

    def to_pyvista(self):
        import pyvista as pv

        cells = np.hstack([np.full((self.n_faces, 1), 3), self.faces]).ravel()
        mesh = pv.PolyData(self.vertices, cells)
        for k, v in self.face_data.items():
            mesh.cell_data[k] = v
        return mesh
