"""Abaqus ``.inp`` writer: C3D8 elements, element sets per label, node sets and
element-based surfaces per boundary (wall, inlet, outlet_k).

Set names are made safe for Abaqus (letters, digits, ``_``); ``**`` comment lines give the
original names.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .atomic import atomic_path
from .export import boundary_groups, boundary_local_faces, cell_labels, safe_names

#: Abaqus C3D8 face label (S1..S6) of each local face of :func:`vmesh.io.export.tensor_faces`
#: (i = 0, i = p, j = 0, j = p, k = 0, k = p): S1 = 1-2-3-4 (k = 0), S2 = 5-8-7-6, S3 = 1-5-6-2
#: (j = 0), S4 = 2-6-7-3 (i = p), S5 = 3-7-8-4 (j = p), S6 = 4-8-5-1 (i = 0).
ABAQUS_FACE = np.array([6, 4, 3, 5, 1, 2])


def _write_ids(fh, ids: np.ndarray) -> None:
    """Ids 16 to a line (Abaqus' limit), comma separated."""
    ids = np.asarray(ids, np.int64)
    full = len(ids) // 16 * 16
    if full:
        np.savetxt(fh, ids[:full].reshape(-1, 16), fmt="%d", delimiter=", ")
    if len(ids) > full:
        fh.write(", ".join(map(str, ids[full:].tolist())) + "\n")


def write(path, mesh) -> Path:
    """Write a linear hexahedral ``mesh`` as an Abaqus input file (atomically).

    Element sets: one per label (``ELSET=<label>``); per boundary a node set
    (``NSET=<boundary>``) and a surface (``*SURFACE, NAME=<boundary>, TYPE=ELEMENT``) made of
    internal element sets ``_<boundary>_S<n>`` with their face labels.
    """
    path = Path(path)
    labels, lnames = cell_labels(mesh)
    bnames = boundary_groups(mesh)
    lsafe = dict(zip(lnames, safe_names(lnames.values())))
    bsafe = dict(zip(bnames, safe_names(bnames.values())))
    side = ABAQUS_FACE[boundary_local_faces(mesh)]
    bid = np.asarray(mesh.boundary_ids)
    with atomic_path(path) as tmp, open(tmp, "w") as fh:
        fh.write(f"*HEADING\nvmesh block-structured hexahedral mesh{', lengths in ' + mesh.units if mesh.units else ''}\n")
        if mesh.units:
            fh.write(f"** units: {mesh.units}\n")
        for lab, name in lnames.items():
            fh.write(f"** label {lab}: {name} -> ELSET={lsafe[lab]}\n")
        for b, name in bnames.items():
            fh.write(f"** boundary {b}: {name} -> SURFACE={bsafe[b]}, NSET={bsafe[b]}\n")
        fh.write("*NODE\n")
        np.savetxt(fh, np.c_[np.arange(1, mesh.n_points + 1), mesh.points], fmt=["%d"] + ["%.17g"] * 3, delimiter=", ")
        fh.write("*ELEMENT, TYPE=C3D8, ELSET=ALL_ELEMENTS\n")
        np.savetxt(fh, np.c_[np.arange(1, mesh.n_cells + 1), mesh.corner_cells() + 1], fmt="%d", delimiter=", ")
        for lab in lnames:
            fh.write(f"*ELSET, ELSET={lsafe[lab]}\n")
            _write_ids(fh, np.flatnonzero(labels == lab) + 1)
        for b in bnames:
            on = bid == b
            fh.write(f"*NSET, NSET={bsafe[b]}\n")
            _write_ids(fh, np.unique(mesh.boundary_faces[on]) + 1)
            sides = np.unique(side[on])
            for s in sides:
                fh.write(f"*ELSET, ELSET=_{bsafe[b]}_S{s}, INTERNAL\n")
                _write_ids(fh, np.asarray(mesh.boundary_cells)[on & (side == s)] + 1)
            fh.write(f"*SURFACE, NAME={bsafe[b]}, TYPE=ELEMENT\n")
            for s in sides:
                fh.write(f"_{bsafe[b]}_S{s}, S{s}\n")
    return path


def read_surfaces(path) -> dict:
    """``{surface name: number of element faces}`` of the element-based surfaces of an
    ``.inp`` written by :func:`write` (to check a round trip; meshio skips surfaces)."""
    sets, surfaces, current, mode = {}, {}, None, None
    for line in Path(path).read_text().splitlines():
        if line.startswith("**"):
            continue
        if line.startswith("*"):
            head = [t.strip() for t in line[1:].split(",")]
            key = head[0].upper()
            opts = dict((t.split("=", 1) + [""])[:2] for t in head[1:])
            opts = {k.upper(): v for k, v in opts.items()}
            if key == "ELSET":
                current, mode = opts["ELSET"], "elset"
                sets[current] = 0
            elif key == "SURFACE":
                current, mode = opts["NAME"], "surface"
                surfaces[current] = 0
            else:
                mode = None
            continue
        if mode == "elset":
            sets[current] += len([t for t in line.split(",") if t.strip()])
        elif mode == "surface":
            surfaces[current] += sets[line.split(",")[0].strip()]
    return surfaces
