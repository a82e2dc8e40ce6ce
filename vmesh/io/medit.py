"""Medit / INRIA ``.mesh`` writer (through meshio): hexahedra and boundary quadrilaterals.

Medit stores one integer reference per element: hexahedra get ``label + 1`` and boundary
quadrilaterals ``boundary id + 1`` (references are positive); the names are written as
comment lines at the top of the file.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .atomic import atomic_path
from .export import boundary_groups, cell_labels


def write(path, mesh) -> Path:
    """Write a linear hexahedral ``mesh`` as a Medit ``.mesh`` file (atomically)."""
    import meshio

    path = Path(path)
    labels, lnames = cell_labels(mesh)
    bnames = boundary_groups(mesh)
    out = meshio.Mesh(
        mesh.points,
        [("hexahedron", mesh.corner_cells()), ("quad", mesh.corner_boundary_faces())],
        cell_data={"medit:ref": [labels + 1, np.asarray(mesh.boundary_ids, np.int64) + 1]},
    )
    with atomic_path(path) as tmp:
        meshio.write(tmp, out, file_format="medit")
        head = f"# units: {mesh.units}\n" if mesh.units else ""
        head += "".join(f"# Hexahedra ref {k + 1}: {v}\n" for k, v in lnames.items())
        head += "".join(f"# Quadrilaterals ref {k + 1}: {v}\n" for k, v in bnames.items())
        tmp.write_text(head + tmp.read_text())
    return path
