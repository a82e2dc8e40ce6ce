"""Gmsh MSH 4.1 (ASCII) writer: hexahedra of order 1-4 with physical groups.

One volume entity (and 3D physical group) per element label and one surface entity (and
2D physical group) per boundary (wall, inlet, outlet_k), named in ``$PhysicalNames``. Volume
and surface groups never share a name (:mod:`vmesh.io.names`: labels such as ``vessel`` or
``aneurysm`` name regions, ``wall``/``inlet``/``outlet_k`` name boundaries), since readers
such as meshio key groups by name alone. The length unit is recorded in a ``$Units`` section
(``mm``), which Gmsh and meshio skip as an unknown section.
Nodes are stored once, on the first volume entity. Node orders are Gmsh's own
(``gmsh.model.mesh.getElementProperties``), kept here as tables over the tensor order.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .atomic import atomic_path
from .export import boundary_groups, cell_labels
from .names import distinct_volume_names

#: Gmsh element type ids of hexahedra and quadrilaterals by order.
HEX_TYPES = {1: 5, 2: 12, 3: 92, 4: 93}
QUAD_TYPES = {1: 3, 2: 10, 3: 36, 4: 37}

#: ``gmsh_cell = tensor_cell[:, GMSH_HEX[p]]``, from Gmsh's reference node coordinates.
GMSH_HEX = {
    1: [0, 1, 3, 2, 4, 5, 7, 6],
    2: [0, 2, 8, 6, 18, 20, 26, 24, 1, 3, 9, 5, 11, 7, 17, 15, 19, 21, 23, 25, 4, 10, 12, 14, 16, 22, 13],
    3: [0, 3, 15, 12, 48, 51, 63, 60, 1, 2, 4, 8, 16, 32, 7, 11, 19, 35, 14, 13, 31, 47, 28, 44, 49, 50, 52, 56,
        55, 59, 62, 61, 5, 9, 10, 6, 17, 18, 34, 33, 20, 36, 40, 24, 23, 27, 43, 39, 30, 29, 45, 46, 53, 54, 58,
        57, 21, 22, 26, 25, 37, 38, 42, 41],
    4: [0, 4, 24, 20, 100, 104, 124, 120, 1, 2, 3, 5, 10, 15, 25, 50, 75, 9, 14, 19, 29, 54, 79, 23, 22, 21, 49,
        74, 99, 45, 70, 95, 101, 102, 103, 105, 110, 115, 109, 114, 119, 123, 122, 121, 6, 16, 18, 8, 11, 17, 13,
        7, 12, 26, 28, 78, 76, 27, 53, 77, 51, 52, 30, 80, 90, 40, 55, 85, 65, 35, 60, 34, 44, 94, 84, 39, 69, 89,
        59, 64, 48, 46, 96, 98, 47, 71, 97, 73, 72, 106, 108, 118, 116, 107, 113, 117, 111, 112, 31, 33, 43, 41,
        81, 83, 93, 91, 32, 36, 56, 38, 58, 42, 68, 66, 82, 86, 88, 92, 37, 57, 61, 63, 67, 87, 62],
}

#: ``gmsh_face = tensor_face[:, GMSH_QUAD[p]]``.
GMSH_QUAD = {
    1: [0, 1, 3, 2],
    2: [0, 2, 8, 6, 1, 5, 7, 3, 4],
    3: [0, 3, 15, 12, 1, 2, 7, 11, 14, 13, 8, 4, 5, 6, 10, 9],
    4: [0, 4, 24, 20, 1, 2, 3, 9, 14, 19, 23, 22, 21, 15, 10, 5, 6, 8, 18, 16, 7, 13, 17, 11, 12],
}


def _bbox(points: np.ndarray) -> str:
    lo, hi = (points.min(axis=0), points.max(axis=0)) if len(points) else (np.zeros(3), np.zeros(3))
    return " ".join(f"{v:.17g}" for v in (*lo, *hi))


def write(path, mesh) -> Path:
    """Write ``mesh`` as a Gmsh 4.1 ASCII ``.msh`` file (atomically).

    Physical groups: dimension 3, tag ``label + 1``, named by ``mesh.label_names``;
    dimension 2, tag ``boundary id + 1``, named ``wall``, ``inlet``, ``outlet_k``.
    """
    path = Path(path)
    p = mesh.order
    labels, names = cell_labels(mesh)
    bnames = boundary_groups(mesh)
    names = distinct_volume_names(names, bnames.values())
    hexes = mesh.cells[:, GMSH_HEX[p]] + 1
    quads = mesh.boundary_faces[:, GMSH_QUAD[p]] + 1
    n, m, k = mesh.n_points, len(hexes), len(quads)
    vol_tags = {lab: i + 1 for i, lab in enumerate(names)}
    surf_tags = {b: i + 1 for i, b in enumerate(bnames)}
    with atomic_path(path) as tmp, open(tmp, "w") as fh:
        fh.write("$MeshFormat\n4.1 0 8\n$EndMeshFormat\n")
        # duplicates: same shape as abaqus.py's header (units, then name tables): each format spells its own
        if mesh.units:
            fh.write(f"$Units\n{mesh.units}\n$EndUnits\n")
        fh.write(f"$PhysicalNames\n{len(names) + len(bnames)}\n")
        for lab, name in names.items():
            fh.write(f'3 {vol_tags[lab]} "{name}"\n')
        for b, name in bnames.items():
            fh.write(f'2 {surf_tags[b]} "{name}"\n')
        fh.write("$EndPhysicalNames\n$Entities\n")
        fh.write(f"0 0 {len(bnames)} {len(names)}\n")
        bid = np.asarray(mesh.boundary_ids)
        for b, tag in surf_tags.items():
            nodes = np.unique(mesh.boundary_faces[bid == b])
            fh.write(f"{tag} {_bbox(mesh.points[nodes])} 1 {tag} 0\n")
        for lab, tag in vol_tags.items():
            fh.write(f"{tag} {_bbox(mesh.points[np.unique(mesh.cells[labels == lab])])} 1 {tag} 0\n")
        fh.write("$EndEntities\n$Nodes\n")
        first = next(iter(vol_tags.values()))
        fh.write(f"1 {n} 1 {n}\n3 {first} 0 {n}\n")
        np.savetxt(fh, np.arange(1, n + 1)[:, None], fmt="%d")
        np.savetxt(fh, mesh.points, fmt="%.17g")
        fh.write("$EndNodes\n$Elements\n")
        fh.write(f"{len(vol_tags) + len(surf_tags)} {m + k} 1 {m + k}\n")
        # element tags: vmesh element index + 1, then m + boundary face index + 1
        for lab, etag in vol_tags.items():
            sel = np.flatnonzero(labels == lab)
            fh.write(f"3 {etag} {HEX_TYPES[p]} {len(sel)}\n")
            np.savetxt(fh, np.c_[sel + 1, hexes[sel]], fmt="%d")
        for b, etag in surf_tags.items():
            sel = np.flatnonzero(bid == b)
            fh.write(f"2 {etag} {QUAD_TYPES[p]} {len(sel)}\n")
            np.savetxt(fh, np.c_[m + sel + 1, quads[sel]], fmt="%d")
        fh.write("$EndElements\n")
    return path
