"""Export hexahedral meshes for solvers: format table, dispatch, and shared helpers.

Each format lives in its own small module (:mod:`vmesh.io.gmsh`, :mod:`vmesh.io.abaqus`,
:mod:`vmesh.io.exodus`, :mod:`vmesh.io.medit`, :mod:`vmesh.io.xdmf`,
:mod:`vmesh.io.openfoam`; VTU is :func:`vmesh.io.mesh.write_mesh`). This module picks the
format from a name or the file extension, refuses orders a format cannot hold, and holds
the helpers the writers share: element groups by label, boundary faces by name, the local
face of each boundary face, and linearisation of high-order meshes.

Every writer writes atomically (:func:`vmesh.io.atomic.atomic_path`): a failed export leaves
neither a partial file nor a temporary one behind.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from ..errors import ParameterError


@dataclass(frozen=True)
class ExportFormat:
    """One solver format: its name, file suffixes, highest mesh order and a description."""

    name: str
    suffixes: tuple
    max_order: int
    description: str
    folder: bool = False  # written as a folder (an OpenFOAM case)


#: Export formats by name, in the order ``vmesh export --help`` lists them.
EXPORT_FORMATS = {
    f.name: f
    for f in (
        ExportFormat("vtu", (".vtu",), 4, "VTK XML UnstructuredGrid: linear or Lagrange hexahedra, every cell array"),
        ExportFormat("gmsh", (".msh",), 4, "Gmsh 4.1 (ASCII): physical groups for labels (3D) and wall/inlet/outlets (2D); p = 2 as hex27"),
        ExportFormat("abaqus", (".inp",), 1, "Abaqus input: C3D8, element sets per label, node sets and element-based surfaces per boundary"),
        ExportFormat("exodus", (".exo", ".e", ".ex2"), 1, "Exodus II (netCDF): one element block per label, side sets and node sets per boundary, cell arrays as element variables"),
        ExportFormat("medit", (".mesh",), 1, "Medit / INRIA .mesh: hexahedra referenced by label + 1, boundary quadrilaterals by boundary id + 1"),
        ExportFormat("xdmf", (".xdmf",), 2, "XDMF 3 with HDF5 data: hexahedra (p = 2 as Hexahedron_27) and boundary quadrilaterals, label/boundary_id arrays"),
        ExportFormat("openfoam", ("",), 1, "OpenFOAM case folder (constant/polyMesh) with one patch per wall/inlet/outlet", folder=True),
    )
}

#: Aliases accepted for ``format``.
FORMAT_ALIASES = {"msh": "gmsh", "inp": "abaqus", "exo": "exodus", "exodusii": "exodus", "e": "exodus", "ex2": "exodus", "mesh": "medit", "foam": "openfoam", "polymesh": "openfoam"}


def resolve_format(path, fmt: str | None = None) -> ExportFormat:
    """The export format named ``fmt`` (or an alias), else the one of ``path``'s suffix.

    Raises
    ------
    ParameterError
        One line naming ``path`` and the unknown format.
    """
    path = Path(path)
    if fmt:
        key = FORMAT_ALIASES.get(fmt.lower().lstrip("."), fmt.lower().lstrip("."))
        if key not in EXPORT_FORMATS:
            names = sorted({*EXPORT_FORMATS, *FORMAT_ALIASES})
            raise ParameterError(f"unknown export format '{fmt}' (supported: {', '.join(names)}, and meshlab for 'vmesh export')", path)
        return EXPORT_FORMATS[key]
    suffix = path.suffix.lower()
    for f in EXPORT_FORMATS.values():
        if suffix and suffix in f.suffixes:
            return f
    raise ParameterError(
        f"unknown export format '{path.suffix or '(no extension)'}' (supported: "
        + ", ".join(s for f in EXPORT_FORMATS.values() for s in f.suffixes if s)
        + "; an OpenFOAM case needs format 'openfoam')",
        path,
    )


def default_filename(fmt: ExportFormat, stem: str = "mesh") -> str:
    """File (or folder) name of an export of ``fmt``: ``mesh.msh``, ``openfoam`` ..."""
    return "openfoam" if fmt.folder else stem + fmt.suffixes[0]


def export_mesh(path, mesh, fmt: str | None = None, linearize: bool = False, flow=None) -> Path:
    """Write ``mesh`` to ``path`` in format ``fmt`` (default: from the suffix), atomically.

    Parameters
    ----------
    path : path
        Output file, or the case folder for OpenFOAM.
    mesh : HexMesh
    fmt : str, optional
        A name of :data:`EXPORT_FORMATS` or an alias (``msh``, ``inp``, ``exo``...).
    linearize : bool
        Write only the corner nodes of a high-order mesh to a format that cannot hold its
        order, instead of refusing.
    flow : vmesh.io.openfoam_case.FlowCase, optional
        For OpenFOAM: also write the solver case (``0/``, ``constant/``, ``system/``).

    Raises
    ------
    ParameterError
        Unknown format, or a mesh order the format cannot hold (and ``linearize`` is off).
    """
    path = Path(path)
    f = resolve_format(path, fmt)
    if mesh.order > f.max_order:
        if not linearize:
            raise ParameterError(
                f"{f.name} export holds hexahedra of order p <= {f.max_order}, the mesh has p = {mesh.order} "
                f"(use vtu{', gmsh or xdmf' if mesh.order == 2 else ' or gmsh'}, --linearize (linearize = true) keeps only the corner nodes, or mesh with order = 1)",
                path,
            )
        mesh = linear_mesh(mesh)
    if f.name == "vtu":
        from .mesh import write_mesh

        return write_mesh(path, mesh)
    from importlib import import_module

    module = import_module(f"{__package__}.{f.name}")
    if flow is not None:
        if f.name != "openfoam":
            raise ParameterError(f"a solver case (--case) is written for OpenFOAM only, not {f.name}", path)
        return module.write(path, mesh, flow=flow)
    return module.write(path, mesh)


def convert_units(mesh, to_units: str | None = None, scale: float | None = None):
    """``mesh`` in ``to_units`` (from its recorded ``units``), or scaled by ``scale``
    (its units then unknown unless ``to_units`` names them too).

    Raises
    ------
    ParameterError
        ``to_units`` without known mesh units, an unknown unit, or a non-positive scale.
    """
    from .mesh import UNIT_METRES

    if to_units is not None and to_units not in UNIT_METRES:
        raise ParameterError(f"--to-units {to_units!r} is not one of {', '.join(UNIT_METRES)}")
    if scale is not None:
        if not scale > 0:
            raise ParameterError(f"--scale {scale} must be positive")
        return mesh.scaled(scale, to_units)
    if to_units is None or to_units == mesh.units:
        return mesh
    if mesh.units not in UNIT_METRES:
        raise ParameterError(f"--to-units {to_units}: the run does not record its length unit (rerun with --units, or give --scale)")
    return mesh.scaled(UNIT_METRES[mesh.units] / UNIT_METRES[to_units], to_units)


# --- shared helpers ---------------------------------------------------------------------


def cell_labels(mesh) -> tuple[np.ndarray, dict]:
    """Per-element label ids and their names (one ``vessel`` group when there are no labels)."""
    if "label" in mesh.cell_data:
        labels = np.asarray(mesh.cell_data["label"], np.int64)
        names = {int(k): str(v) for k, v in mesh.label_names.items()}
        for k in np.unique(labels):
            names.setdefault(int(k), f"label_{k}")
        return labels, {k: names[k] for k in sorted(names) if k in set(np.unique(labels).tolist())}
    return np.zeros(mesh.n_cells, np.int64), {0: "vessel"}


def boundary_groups(mesh) -> dict:
    """``{boundary id: name}`` of the boundary ids present, wall first."""
    names = {int(k): str(v) for k, v in mesh.boundary_names.items()}
    ids = np.unique(np.asarray(mesh.boundary_ids, np.int64)).tolist()
    return {i: names.get(i, f"boundary_{i}") for i in ids}


def safe_names(names, pattern=r"[^A-Za-z0-9_]", prefix="g") -> list[str]:
    """Names made of letters, digits and ``_`` (starting with a letter), kept unique.

    Abaqus, Exodus and OpenFOAM allow no ``+`` or spaces in set, block and patch names.
    """
    out, seen = [], set()
    for n in names:
        s = re.sub(pattern, "_", str(n)) or prefix
        if not s[0].isalpha():
            s = f"{prefix}_{s}"
        base, k = s, 2
        while s.lower() in seen:
            s, k = f"{base}_{k}", k + 1
        seen.add(s.lower())
        out.append(s)
    return out


@lru_cache(maxsize=None)
def tensor_faces(order: int) -> np.ndarray:
    """(6, (p+1)^2) local node ids of the faces of a tensor-order hexahedron.

    Faces in the order i = 0, i = p, j = 0, j = p, k = 0, k = p; each face's nodes in its own
    tensor order (a fastest, then b) with a × b pointing out of the element, so that the
    corners ``[0, p, (p+1)^2 - 1, p (p+1)]`` are an outward quad loop (as
    :attr:`HexMesh.boundary_faces`).
    """
    p = order
    n = p + 1
    a, b = np.meshgrid(np.arange(n), np.arange(n), indexing="xy")  # a fastest in ravel
    a, b = a.ravel(), b.ravel()
    z, e = np.zeros_like(a), np.full_like(a, p)

    def idx(i, j, k):
        return i + n * (j + n * k)

    return np.stack(
        [
            idx(z, b, a),  # i = 0: a = k, b = j  (k × j = -x)
            idx(e, a, b),  # i = p: a = j, b = k
            idx(a, z, b),  # j = 0: a = i, b = k  (i × k = -y)
            idx(b, e, a),  # j = p: a = k, b = i
            idx(b, a, z),  # k = 0: a = j, b = i  (j × i = -z)
            idx(a, b, e),  # k = p: a = i, b = j
        ]
    ).astype(np.int64)


def face_corner_ids(order: int) -> np.ndarray:
    """Positions of the 4 corners (an outward loop) inside a (p+1)^2 tensor face."""
    p = order
    return np.array([0, p, (p + 1) ** 2 - 1, p * (p + 1)])


def boundary_local_faces(mesh) -> np.ndarray:
    """(k,) local face index (0..5, as :func:`tensor_faces`) of each boundary face in its element.

    Raises
    ------
    ParameterError
        When a boundary face is no face of its owning element (an inconsistent mesh).
    """
    p = mesh.order
    corners = tensor_faces(p)[:, face_corner_ids(p)]  # (6, 4)
    owner = np.asarray(mesh.cells)[mesh.boundary_cells][:, corners]  # (k, 6, 4)
    face = np.sort(mesh.corner_boundary_faces(), axis=1)[:, None, :]
    hit = (np.sort(owner, axis=2) == face).all(axis=2)
    if len(hit) and not hit.any(axis=1).all():
        raise ParameterError(f"{int((~hit.any(axis=1)).sum())} boundary faces are not faces of their elements")
    return hit.argmax(axis=1)


def linear_mesh(mesh):
    """The p = 1 mesh of ``mesh``'s element corners (node ids compacted, data kept)."""
    from ..mesh import HexMesh

    if mesh.order == 1:
        return mesh
    p = mesh.order
    corner = np.array([i + (p + 1) * (j + (p + 1) * k) for k in (0, p) for j in (0, p) for i in (0, p)])
    cells = mesh.cells[:, corner]
    faces = mesh.boundary_faces[:, face_corner_ids(p)[[0, 1, 3, 2]]]  # corners in 2x2 tensor order
    used, inverse = np.unique(np.concatenate([cells.ravel(), faces.ravel()]), return_inverse=True)
    nc = cells.size
    return HexMesh(
        points=mesh.points[used],
        cells=inverse[:nc].reshape(cells.shape),
        order=1,
        cell_data=dict(mesh.cell_data),
        boundary_faces=inverse[nc:].reshape(faces.shape),
        boundary_ids=mesh.boundary_ids,
        boundary_cells=mesh.boundary_cells,
        boundary_names=dict(mesh.boundary_names),
        label_names=dict(mesh.label_names),
        on_wall=None if mesh.on_wall is None else mesh.on_wall[used],
        units=mesh.units,
    )


def boundary_element_faces(mesh) -> np.ndarray:
    """Boundary faces as (k, (p+1)^2) node ids in the element-face node order of Gmsh/VTK
    quads: corners as an outward loop, then edge nodes, then interior (via meshio's quad9
    order for p = 2); only used by writers that store boundary elements."""
    p = mesh.order
    if p == 1:
        return mesh.corner_boundary_faces()
    if p == 2:
        # VTK/meshio quad9: 4 corners, 4 edge midpoints (edge 0-1, 1-2, 2-3, 3-0), centre
        return mesh.boundary_faces[:, [0, 2, 8, 6, 1, 5, 7, 3, 4]]
    raise ParameterError(f"boundary elements of order {p} are not supported here")
