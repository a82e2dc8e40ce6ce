"""The hexahedral mesh: nodes, (high-order) hexahedra, labels and named boundaries."""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np

# VTK cell types
VTK_HEXAHEDRON = 12
VTK_QUAD = 9
VTK_LAGRANGE_HEXAHEDRON = 72
VTK_LAGRANGE_QUADRILATERAL = 70


@lru_cache(maxsize=None)
def tensor_to_vtk(order: int) -> np.ndarray:
    """Permutation ``perm`` with ``vtk_cell = tensor_cell[perm]`` for hexahedra of order p.

    p = 1 is VTK's linear hexahedron; p > 1 VTK's Lagrange hexahedron, whose node
    order is taken from VTK itself (``vtkLagrangeHexahedron.PointIndexFromIJK``).
    """
    p = order
    if p == 1:
        return np.array([0, 1, 3, 2, 4, 5, 7, 6])
    import vtk

    n = (p + 1) ** 3
    perm = np.empty(n, np.int64)
    for k in range(p + 1):
        for j in range(p + 1):
            for i in range(p + 1):
                perm[vtk.vtkLagrangeHexahedron.PointIndexFromIJK(i, j, k, [p, p, p])] = i + (p + 1) * (j + (p + 1) * k)
    return perm


@lru_cache(maxsize=None)
def tensor_to_hex27() -> np.ndarray:
    """Permutation of a p = 2 tensor-order cell to VTK's tri-quadratic hexahedron
    (meshio's ``hexahedron27``, which meshio maps to Gmsh's hex27 order when writing .msh)."""
    import vtk

    cell = vtk.vtkTriQuadraticHexahedron()
    pc = np.array([cell.GetParametricCoords()[i] for i in range(81)]).reshape(27, 3)
    ijk = np.rint(pc * 2).astype(int)
    return ijk[:, 0] + 3 * (ijk[:, 1] + 3 * ijk[:, 2])


@dataclass
class HexMesh:
    """A conforming hexahedral mesh of order p.

    Attributes
    ----------
    points : (n, 3) float64
    cells : (m, (p+1)^3) int64
        Node ids in tensor order (i fastest, then j, then k).
    order : int
    cell_data : dict of str -> (m,) arrays
        ``block_id``, ``segment_id``, ``layer``, ``label``, ``scaled_jacobian``...
    boundary_faces : (k, (p+1)^2) int64
        Outward boundary faces in tensor order.
    boundary_ids : (k,) int64
        0 for the wall, j >= 1 for open end j.
    boundary_cells : (k,) int64
        Element owning each boundary face.
    boundary_names : dict int -> str
        ``{0: "wall", 1: "inlet", 2: "outlet_1", ...}``.
    label_names : dict int -> str
        Names of the integer ``label`` cell values (skeleton tags).
    on_wall : (n,) bool
        Nodes placed on the vessel wall.
    units : str or None
        Length unit of ``points`` (``"mm"``, ``"cm"``, ``"m"``); ``None`` when unknown.
    """

    points: np.ndarray
    cells: np.ndarray
    order: int = 1
    cell_data: dict = field(default_factory=dict)
    boundary_faces: np.ndarray = field(default_factory=lambda: np.zeros((0, 4), np.int64))
    boundary_ids: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    boundary_cells: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    boundary_names: dict = field(default_factory=lambda: {0: "wall"})
    label_names: dict = field(default_factory=dict)
    on_wall: np.ndarray | None = None
    node_distribution: str = "gauss_lobatto"
    units: str | None = None

    # duplicates: count properties like Skeleton's and SurfaceMesh's: each class counts its own arrays
    @property
    def n_points(self) -> int:
        return len(self.points)

    @property
    def n_cells(self) -> int:
        return len(self.cells)

    def __repr__(self) -> str:  # counts, not the arrays: a mesh printed at the prompt stays one line
        return (
            f"HexMesh({self.n_cells} hexahedra of order {self.order}, {self.n_points} nodes, units {self.units}, "
            f"labels {list(self.label_names.values())}, boundaries {list(self.boundary_names.values())})"
        )

    def corner_cells(self) -> np.ndarray:
        """(m, 8) corner node ids in VTK linear-hexahedron order."""
        p = self.order
        idx = [i + (p + 1) * (j + (p + 1) * k) for k in (0, p) for j in (0, p) for i in (0, p)]
        return self.cells[:, idx][:, [0, 1, 3, 2, 4, 5, 7, 6]]

    def corner_boundary_faces(self) -> np.ndarray:
        """(k, 4) corner node ids of the boundary faces, outward, as quads."""
        p = self.order
        return self.boundary_faces[:, [0, p, (p + 1) ** 2 - 1, p * (p + 1)]]

    def vtk_cells(self) -> tuple[np.ndarray, int]:
        """Cells in VTK node order and their VTK cell type."""
        perm = tensor_to_vtk(self.order)
        return self.cells[:, perm], VTK_HEXAHEDRON if self.order == 1 else VTK_LAGRANGE_HEXAHEDRON

    def to_pyvista(self):
        """An UnstructuredGrid (linear or Lagrange hexahedra) with all cell data."""
        import pyvista as pv

        cells, ctype = self.vtk_cells()
        n = cells.shape[1]
        grid = pv.UnstructuredGrid(
            np.hstack([np.full((len(cells), 1), n), cells]).ravel(), np.full(len(cells), ctype, np.uint8), self.points
        )
        for k, v in self.cell_data.items():
            grid.cell_data[k] = v
        return grid

    def boundary_to_pyvista(self):
        """The boundary faces as a PolyData of quads with ``boundary_id`` cell data (linear corners)."""
        import pyvista as pv

        q = self.corner_boundary_faces()
        mesh = pv.PolyData(self.points, np.hstack([np.full((len(q), 1), 4), q]).ravel())
        mesh.cell_data["boundary_id"] = self.boundary_ids
        for k, v in self.cell_data.items():
            mesh.cell_data[k] = np.asarray(v)[self.boundary_cells]
        return mesh.clean() if False else mesh

    def to_meshio(self, hex27: bool = False):
        """A ``meshio.Mesh``: linear hexahedra, or for p = 2 ``hexahedron27`` (Gmsh hex27 on write)."""
        import meshio

        if self.order == 1:
            cells = [("hexahedron", self.corner_cells())]
        elif self.order == 2 and hex27:
            cells = [("hexahedron27", self.cells[:, tensor_to_hex27()])]
        else:
            cells = [("VTK_LAGRANGE_HEXAHEDRON", self.vtk_cells()[0])]
        data = {k: [np.asarray(v)] for k, v in self.cell_data.items()}
        return meshio.Mesh(self.points, cells, cell_data=data)

    def scaled(self, factor: float, units: str | None = None) -> "HexMesh":
        """A copy with the points multiplied by ``factor`` (a change of length unit to ``units``)."""
        from dataclasses import replace

        return replace(self, points=self.points * factor, units=units)

    def summary(self) -> dict:
        return {"elements": self.n_cells, "nodes": self.n_points, "order": self.order, "boundary_faces": len(self.boundary_faces), "units": self.units}
