"""Write hexahedral meshes: VTU (VTK, linear or Lagrange) and boundary faces."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .atomic import atomic_path


def write_mesh(path, mesh) -> Path:
    """Write ``mesh`` atomically. ``.vtu`` goes through VTK (Lagrange hexahedra for p > 1,
    label names as field data); other extensions through meshio."""
    path = Path(path)
    with atomic_path(path) as tmp:
        if path.suffix.lower() == ".vtu":
            grid = mesh.to_pyvista()
            if mesh.label_names:
                grid.field_data["label_names"] = np.array([mesh.label_names[k] for k in sorted(mesh.label_names)])
            grid.field_data["boundary_names"] = np.array([f"{k}:{v}" for k, v in sorted(mesh.boundary_names.items())])
            grid.save(str(tmp), binary=True)
        else:
            mesh.to_meshio().write(str(tmp))
    return path


def write_boundary(path, mesh) -> Path:
    """Boundary faces as quads with ``boundary_id`` (0 wall, k open end k) and the owning element's data."""
    path = Path(path)
    with atomic_path(path) as tmp:
        b = mesh.boundary_to_pyvista()
        b.field_data["boundary_names"] = np.array([f"{k}:{v}" for k, v in sorted(mesh.boundary_names.items())])
        b.save(str(tmp), binary=True)
    return path
