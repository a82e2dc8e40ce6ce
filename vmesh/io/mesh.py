"""Write hexahedral meshes: VTU (VTK, linear or Lagrange) and boundary faces."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .atomic import atomic_path

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
    """Write ``mesh`` atomically. ``.vtu`` goes through VTK (Lagrange hexahedra for p > 1,
    label and boundary names as field data, :func:`name_field_data`); other extensions
    through meshio."""
    path = Path(path)
    with atomic_path(path) as tmp:
        if path.suffix.lower() == ".vtu":
            grid = mesh.to_pyvista()
            for key, ids in {**name_field_data(mesh.label_names, "label"), **name_field_data(mesh.boundary_names, "boundary")}.items():
                grid.field_data[key] = ids
            if getattr(mesh, "units", None):
                grid.field_data[f"units:{mesh.units}"] = np.array([UNIT_METRES[mesh.units]])  # metres per unit
            grid.save(str(tmp), binary=True)
        else:
            mesh.to_meshio().write(str(tmp))
    return path


def write_boundary(path, mesh) -> Path:
    """Boundary faces as quads with ``boundary_id`` (0 wall, k open end k) and the owning element's data."""
    path = Path(path)
    with atomic_path(path) as tmp:
        b = mesh.boundary_to_pyvista()
        for key, ids in name_field_data(mesh.boundary_names, "boundary").items():
            b.field_data[key] = ids
        b.save(str(tmp), binary=True)
    return path
