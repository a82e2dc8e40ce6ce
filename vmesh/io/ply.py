"""PLY triangle surfaces read with numpy (VTK's reader costs ~1 s of imports per run).

Handles the common case: a ``vertex`` element with scalar properties (``x, y, z`` among
them) and a ``face`` element whose only property is its vertex list, all triangles, in
ascii or binary of either byte order. Anything else raises :class:`UnsupportedPLY`, and
the caller hands the file to VTK.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4", "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}


class UnsupportedPLY(Exception):
    """The file is valid PLY, perhaps, but not the plain triangle surface read here."""


class TruncatedPLY(UnsupportedPLY):
    """A binary PLY shorter than its header's counts need: not to be handed to VTK, whose
    reader ends the process on it (a segmentation fault, found in session 21)."""


def ply_header(data: bytes):
    """The header of any PLY file: ``(format, [(element, count, properties)], header
    length)``, a property ``(name, type)`` or, for a list, ``(name, count type, item
    type)``. Raises :class:`UnsupportedPLY` without a header or with an unknown format.
    The one PLY header parser (surfaces here, edge-mesh skeletons in
    :mod:`vmesh.io.skeleton_formats`)."""
    end = data.find(b"end_header")
    if not data.startswith(b"ply") or end < 0:
        raise UnsupportedPLY("no PLY header")
    stop = data.find(b"\n", end) + 1
    fmt, elements = None, []
    for line in data[:end].decode("ascii", "replace").splitlines()[1:]:
        words = line.split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        if words[0] == "format":
            fmt = words[1]
        elif words[0] == "element":
            elements.append((words[1], int(words[2]), []))
        elif words[0] == "property" and elements:
            elements[-1][2].append(tuple(words[:0:-1]) if words[1] != "list" else (words[4], words[2], words[3]))
    if fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
        raise UnsupportedPLY(f"unknown PLY format '{fmt}'")
    return fmt, elements, stop


def read_ply_triangles(path: str | Path):
    """Vertices ``(n, 3)`` float64, triangles ``(m, 3)`` int64 and face data ``{}`` of a PLY file.

    Raises
    ------
    UnsupportedPLY
        For anything but the plain triangle surface described in the module docstring.
    """
    data = Path(path).read_bytes()
    fmt, elements, start = ply_header(data)
    _check_length(data, fmt, elements, start)  # before any layout test: VTK crashes on a short file
    if [e[0] for e in elements] != ["vertex", "face"]:
        raise UnsupportedPLY("not a vertex + face PLY")
    ((_, n, vprops), (_, m, fprops)) = elements
    if len(fprops) != 1 or len(fprops[0]) != 3 or fprops[0][0] not in ("vertex_indices", "vertex_index"):
        raise UnsupportedPLY("faces carry more than their vertex list")
    if any(len(p) != 2 or p[1] not in _TYPES for p in vprops) or [p[0] for p in vprops][:3] != ["x", "y", "z"]:
        raise UnsupportedPLY("vertex properties other than scalars after x, y, z")
    _, count_type, index_type = fprops[0]
    if count_type not in _TYPES or index_type not in _TYPES:
        raise UnsupportedPLY("unknown list types")
    if fmt == "ascii":
        rows = data[start:].decode("ascii").split("\n")
        vertices = np.array(" ".join(rows[:n]).split(), float).reshape(n, len(vprops))[:, :3]
        face_rows = np.array(" ".join(rows[n : n + m]).split(), np.int64)
        if len(face_rows) != 4 * m:
            raise UnsupportedPLY("faces other than triangles")
        face_rows = face_rows.reshape(m, 4)
        if np.any(face_rows[:, 0] != 3):
            raise UnsupportedPLY("faces other than triangles")
        return _first_use_order(vertices.astype(np.float64), face_rows[:, 1:].copy())
    order = "<" if fmt == "binary_little_endian" else ">"
    vtype = np.dtype([(name, order + _TYPES[t]) for name, t in vprops])
    ftype = np.dtype([("k", order + _TYPES[count_type]), ("v", order + _TYPES[index_type], (3,))])
    # long enough: _check_length counted these very sizes (scalars, and a face's count + 3 indices)
    vert = np.frombuffer(data, vtype, n, start)
    faces = np.frombuffer(data, ftype, m, start + n * vtype.itemsize)
    if np.any(faces["k"] != 3):
        raise UnsupportedPLY("faces other than triangles")
    vertices = np.stack([vert["x"], vert["y"], vert["z"]], axis=1).astype(np.float64)
    return _first_use_order(vertices, faces["v"].astype(np.int64))


def _check_length(data: bytes, fmt: str, elements, start: int) -> None:
    """Raise :class:`TruncatedPLY` when a binary file is shorter than any layout its header
    allows (scalars at their size; a list at its count plus 3 items for faces, none
    otherwise), whatever the properties: a layout read here or handed to VTK."""
    if fmt == "ascii":
        return
    least = start
    for name, count, props in elements:
        row = 0
        for prop in props:
            if len(prop) == 2:
                row += np.dtype(_TYPES.get(prop[1], "u1")).itemsize
            else:
                items = 3 if name == "face" else 0
                row += np.dtype(_TYPES.get(prop[1], "u1")).itemsize + items * np.dtype(_TYPES.get(prop[2], "u1")).itemsize
        least += count * row
    if len(data) < least:
        counts = ", ".join(f"{count} {name}" for name, count, _ in elements)
        raise TruncatedPLY(f"the file ends early: {len(data)} bytes, where its header's {counts} "
                           f"need at least {least} (a truncated download or copy?)")


def _first_use_order(vertices: np.ndarray, faces: np.ndarray):
    """Vertices renumbered in the order the faces first use them, unused ones dropped: the
    numbering VTK's reader and surface filter gave, so that meshes stay as they were."""
    if faces.size and (faces.min() < 0 or faces.max() >= len(vertices)):
        raise UnsupportedPLY("face vertex indices out of range")
    used, first = np.unique(faces.ravel(), return_index=True)
    order = used[np.argsort(first, kind="stable")]
    remap = np.empty(len(vertices), np.int64)
    remap[order] = np.arange(len(order))
    return vertices[order], remap[faces], {}
