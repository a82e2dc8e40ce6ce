"""Write hexahedral meshes: VTU (VTK, linear or Lagrange) and boundary faces."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .atomic import atomic_path
from .vtk_xml import write_vtp_polygons, write_vtu

#: Metres per length unit (the ``units:<unit>`` field data of a VTU).
UNIT_METRES = {"m": 1.0, "cm": 1e-2, "mm": 1e-3, "um": 1e-6}


def units_from_field_data(field) -> str | None:
    """The length unit a VTU written by :func:`write_mesh` records (``units:<unit>``), or None."""
    found = [k.split(":", 1)[1] for k in field.keys() if k.startswith("units:")]
    return found[0] if found else None


def name_field_data(names: dict, kind: str) -> dict[str, np.ndarray]:
    """Names of ids as integer field-data arrays: ``{"<kind>:<name>": [ids]}``.

    ``kind`` is ``label`` (element labels) or ``boundary`` (boundary ids). meshio refuses
    VTK string arrays (``Illegal data type 'String'``), so the names are the arrays' names;
    ParaView lists them as, e.g., ``boundary:inlet 1``.
    """
    out: dict[str, list] = {}
    for key in sorted(names):
        out.setdefault(f"{kind}:{names[key]}", []).append(int(key))
    return {k: np.asarray(v, np.int64) for k, v in out.items()}


def names_from_field_data(field, kind: str) -> dict[int, str]:
    """The ``{id: name}`` written by :func:`name_field_data` (also reads the string arrays
    ``label_names`` / ``boundary_names`` of files written before)."""
    prefix = f"{kind}:"
    names = {int(i): key[len(prefix):] for key in field.keys() if key.startswith(prefix) for i in np.asarray(field[key]).ravel()}
    legacy = f"{kind}_names"
    if not names and legacy in field.keys():
        values = [str(v) for v in np.asarray(field[legacy]).ravel()]
        if kind == "boundary":
            return {int(k): v for k, _, v in (s.partition(":") for s in values)}
        return dict(enumerate(values))
    return dict(sorted(names.items()))


def write_mesh(path, mesh) -> Path:
    """Write ``mesh`` atomically. ``.vtu`` is raw binary VTK XML (:func:`vmesh.io.vtk_xml.write_vtu`:
    Lagrange hexahedra for p > 1, every cell array, label and boundary names as field data,
    :func:`name_field_data`); other extensions go through meshio."""
    path = Path(path)
    with atomic_path(path) as tmp:
        if path.suffix.lower() == ".vtu":
            cells, cell_type = mesh.vtk_cells()
            field = {**name_field_data(mesh.label_names, "label"), **name_field_data(mesh.boundary_names, "boundary")}
            if getattr(mesh, "units", None):
                field[f"units:{mesh.units}"] = np.array([UNIT_METRES[mesh.units]])  # metres per unit
            write_vtu(tmp, mesh.points, cells, cell_type, mesh.cell_data, field)
        else:
            mesh.to_meshio().write(str(tmp))
    return path


def write_boundary(path, mesh) -> Path:
    """Boundary faces as quads with ``boundary_id`` (0 wall, k open end k) and the owning element's data."""
    path = Path(path)
    with atomic_path(path) as tmp:
        # every mesh node is kept, so the faces' node ids are the mesh's
        data = {"boundary_id": mesh.boundary_ids, **{k: np.asarray(v)[mesh.boundary_cells] for k, v in mesh.cell_data.items()}}
        write_vtp_polygons(tmp, mesh.points, mesh.corner_boundary_faces(), data, name_field_data(mesh.boundary_names, "boundary"))
    return path
