"""XDMF 3 writer (through meshio, heavy data in HDF5): hexahedra and boundary quadrilaterals.

Linear meshes as ``Hexahedron`` + ``Quadrilateral``, p = 2 as ``Hexahedron_27`` +
``Quadrilateral_9``. Every cell array is written for the hexahedra (-1 on the boundary
faces), ``boundary_id`` for the faces (-1 on the hexahedra); the label and boundary names
go in a comment (JSON) at the top of the domain.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..errors import ParameterError
from ..mesh import tensor_to_hex27
from .atomic import atomic_path
from .export import boundary_element_faces, boundary_groups, cell_labels


def write(path, mesh) -> Path:
    """Write ``mesh`` (p <= 2) as ``<name>.xdmf`` + ``<name>.h5`` (both atomically)."""
    import meshio

    path = Path(path)
    if mesh.order == 1:
        cells = [("hexahedron", mesh.corner_cells()), ("quad", mesh.corner_boundary_faces())]
    elif mesh.order == 2:
        cells = [("hexahedron27", mesh.cells[:, tensor_to_hex27()]), ("quad9", boundary_element_faces(mesh))]
    else:
        raise ParameterError(f"xdmf export holds p <= 2, the mesh has p = {mesh.order}", path)
    nb = len(mesh.boundary_faces)
    data = {}
    for k, v in mesh.cell_data.items():
        v = np.asarray(v)
        if v.ndim == 1:
            data[k] = [v, np.full(nb, -1, v.dtype if v.dtype.kind in "if" else np.int64)]
    data["boundary_id"] = [np.full(mesh.n_cells, -1, np.int64), np.asarray(mesh.boundary_ids, np.int64)]
    out = meshio.Mesh(mesh.points, cells, cell_data=data)
    _, lnames = cell_labels(mesh)
    names = json.dumps({"label_names": lnames, "boundary_names": boundary_groups(mesh), "units": mesh.units})
    h5 = path.with_suffix(".h5")
    # the .xdmf names its HDF5 file: write both under temporary names, fix the reference, rename
    with atomic_path(h5) as tmp_h5, atomic_path(path) as tmp:
        meshio.write(tmp, out, file_format="xdmf")
        made = tmp.with_suffix(".h5")
        made.replace(tmp_h5)
        text = tmp.read_text().replace(made.name + ":", h5.name + ":")
        # a comment: an Information element breaks meshio's reader wherever it stands
        text = text.replace("<Domain>", f"<Domain><!-- vmesh {names.replace('--', '- -')} -->", 1)
        tmp.write_text(text)
    return path


#: Nodes per cell of the XDMF mixed-topology type ids written here.
_MIXED_NODES = {0x5: 4, 0x9: 8, 0x23: 9, 0x32: 27}
_MIXED_NAMES = {0x5: "quad", 0x9: "hexahedron", 0x23: "quad9", 0x32: "hexahedron27"}


def read_cell_counts(path) -> dict:
    """``{cell type: count}`` of an XDMF file written by :func:`write` (decoding its mixed
    topology from the HDF5 file; meshio's reader does not know mixed hexahedron27)."""
    import xml.etree.ElementTree as ET

    import h5py

    path = Path(path)
    topo = ET.parse(path).getroot().find(".//Topology")
    item = topo.find("DataItem")
    h5name, _, dataset = item.text.strip().partition(":")
    with h5py.File(path.parent / h5name, "r") as h5:
        data = np.asarray(h5[dataset]).ravel()
    counts, r = {}, 0
    while r < len(data):  # one step per run of records of one cell type
        t = int(data[r])
        step = 1 + _MIXED_NODES[t]
        same = data[r::step] == t
        run = int(same.argmin()) if not same.all() else len(same)
        counts[_MIXED_NAMES[t]] = counts.get(_MIXED_NAMES[t], 0) + run
        r += run * step
    return counts
