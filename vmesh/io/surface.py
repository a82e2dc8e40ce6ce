"""Read and write triangle surfaces (STL, OBJ, PLY, VTP, VTK, VTU, OFF).

VTK XML PolyData (.vtp) of triangles is read with numpy (:func:`vmesh.io.vtk_xml.read_vtp_triangles`);
other .vtp files, the other VTK-family files and STL/OBJ/PLY are read with pyvista (VTK's
readers), OFF (and NOFF, COFF...) with numpy. Quads and polygons are triangulated; per-face arrays are kept. Line
and vertex cells among the faces are dropped, and a volume mesh (tetrahedra, hexahedra...)
gives its boundary surface; both are noted for the run's warnings.
"""

from __future__ import annotations

import re
from contextlib import contextmanager
from itertools import chain
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..geometry.topology import triangulate_polygons
from ..surface import SurfaceMesh
from .atomic import atomic_path

SURFACE_FORMATS = {
    ".stl": "STL",
    ".obj": "Wavefront OBJ",
    ".ply": "PLY",
    ".vtp": "VTK PolyData (XML)",
    ".vtk": "legacy VTK",
    ".vtu": "VTK UnstructuredGrid (XML)",
    ".off": "OFF",
}


def check_input_file(path: str | Path, formats: dict, kind: str) -> Path:
    """Raise a one-line :class:`InputError` unless ``path`` is a readable, non-empty file
    of one of ``formats`` (suffix -> name)."""
    path = Path(path)
    if not path.exists():
        raise InputError("file not found", path)
    if path.is_dir():
        raise InputError(f"is a folder, expected a {kind} file", path)
    if path.stat().st_size == 0:
        raise InputError("file is empty", path)
    suffix = path.suffix.lower()
    if suffix not in formats:
        raise InputError(
            f"unknown {kind} format '{path.suffix or '(no extension)'}' "
            f"(supported: {', '.join(sorted(formats))})",
            path,
        )
    return path


def _quiet_vtk():
    import vtk

    vtk.vtkObject.GlobalWarningDisplayOff()


@contextmanager
def _vtk_errors():
    """Collect VTK's error and warning messages (a list of their texts, filled on exit)
    instead of printing them: VTK's legacy reader reports a file cut short only there and
    returns what it could read."""
    import vtk

    window, previous = vtk.vtkStringOutputWindow(), vtk.vtkOutputWindow.GetInstance()
    vtk.vtkLogger.SetStderrVerbosity(vtk.vtkLogger.VERBOSITY_OFF)  # its stderr copy of each message
    vtk.vtkOutputWindow.SetInstance(window)
    vtk.vtkObject.GlobalWarningDisplayOn()
    messages: list = []
    try:
        yield messages
    finally:
        vtk.vtkObject.GlobalWarningDisplayOff()
        vtk.vtkOutputWindow.SetInstance(previous)
        # each message is "ERROR: In file.cxx, line N" or "Generic Warning: ..." then its text
        lines = [line.strip() for line in window.GetOutput().splitlines() if line.strip()]
        messages += [re.sub(r"^vtk\w+ \(0x[0-9a-f]+\): ", "", text) for head, text in zip(lines, lines[1:]) if re.search(r", line \d+$", head)]


def read_surface(path: str | Path, notes: list | None = None) -> SurfaceMesh:
    """Read a surface file into a :class:`SurfaceMesh` of triangles.

    Whatever the file holds besides surface faces is handled, not fatal: line and vertex
    cells are dropped, quads and polygons are triangulated, and a volume mesh (tetrahedra,
    hexahedra...) gives its boundary surface. What was changed is appended to ``notes``
    (one sentence each) when given, for the run's log and report.

    Raises
    ------
    InputError
        One line naming the file and the problem: missing, empty, unknown format,
        unreadable, or without any surface faces.
    """
    path = check_input_file(path, SURFACE_FORMATS, "surface")
    suffix = path.suffix.lower()
    fmt = SURFACE_FORMATS[suffix]
    notes = [] if notes is None else notes
    try:
        if suffix == ".off":
            vertices, faces, face_data = _read_off(path)
        elif suffix == ".vtp":
            vertices, faces, face_data = _read_vtp(path, notes)
        elif suffix == ".ply":
            vertices, faces, face_data = _read_ply(path, notes)
        else:
            vertices, faces, face_data = _read_pyvista(path, notes)
    except InputError:
        raise
    except MemoryError:
        raise InputError(f"too large to read as {fmt} (out of memory)", path) from None
    except Exception as exc:  # readers raise anything on corrupt input
        raise InputError(f"could not read as {fmt}: {_short(exc)}", path) from None
    if len(faces) == 0 or len(vertices) == 0:
        raise InputError(f"no surface faces found (empty or corrupt {fmt} file)", path)
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise InputError("face vertex indices are out of range (corrupt file)", path)
    bad = ~np.all(np.isfinite(vertices[np.unique(faces)]), axis=1)
    if bad.any():
        raise InputError(f"{int(bad.sum())} vertex coordinate(s) are NaN or infinite: repair or re-export the surface", path)
    return SurfaceMesh(vertices, faces, name=path.name, face_data=face_data)


#: A file of lines only (a centerline, an edge-mesh skeleton) given as the surface.
_CENTERLINE_HINT = "no surface faces, only {n} {what}(s): is it a centerline rather than a surface? (a centerline goes to --skeleton)"


def _ply_edge_count(path: Path) -> int:
    """Edges declared by a PLY header without faces (an edge-mesh skeleton), else 0."""
    from .ply import UnsupportedPLY, ply_header

    try:
        with open(path, "rb") as fh:  # the header only, not the whole file
            _, elements, _ = ply_header(fh.read(65536))
    except (UnsupportedPLY, ValueError, IndexError, OSError):
        return 0
    counts = {name: count for name, count, _ in elements}
    return counts.get("edge", 0) if not counts.get("face") else 0


def _short(exc: Exception) -> str:
    """An exception's message without its class name (users see the problem, not Python)."""
    text = " ".join(str(exc).split())
    return text[:200] if text else "the file is not valid"


def _cell_dimensions(cell_types: np.ndarray) -> np.ndarray:
    """Topological dimension (0 vertex, 1 line, 2 surface, 3 volume) of each VTK cell type."""
    import vtk

    utilities = getattr(vtk, "vtkCellTypeUtilities", None) or vtk.vtkCellTypes
    kinds = np.unique(cell_types)
    dims = np.array([utilities.GetDimension(int(t)) for t in kinds], np.int64)
    return dims[np.searchsorted(kinds, cell_types)]


def _read_vtp(path: Path, notes: list):
    """VTK XML PolyData read with numpy (no VTK import, which costs more than reading);
    what that reader does not handle (strips, lines, other compressors...) goes to VTK."""
    from .vtk_xml import UnsupportedVTKXML, read_vtp_triangles

    try:
        return read_vtp_triangles(path)
    except UnsupportedVTKXML:
        return _read_pyvista(path, notes)


def _read_ply(path: Path, notes: list):
    """PLY triangles read with numpy (:mod:`vmesh.io.ply`); anything else goes to VTK."""
    from .ply import TruncatedPLY, UnsupportedPLY, read_ply_triangles

    try:
        return read_ply_triangles(path)
    except TruncatedPLY as exc:
        raise InputError(str(exc), path) from None
    except UnsupportedPLY:
        if edges := _ply_edge_count(path):
            raise InputError(_CENTERLINE_HINT.format(n=edges, what="edge"), path) from None
        return _read_pyvista(path, notes)


def _legacy_vtk_shortfall(path: Path) -> str | None:
    """The points an ASCII legacy ``.vtk`` file declares and does not hold (VTK's reader
    says nothing when its point list is cut at a number boundary), else None. A binary
    point list, and cell lists, cut short are VTK's own error."""
    with open(path, "rb") as fh:
        head = fh.read(256).split(b"\n", 3)
    if len(head) < 3 or head[2].strip().upper() != b"ASCII":
        return None
    data = path.read_bytes()
    # the numbers after "POINTS n type", up to the next keyword (keywords are upper case, nan is not)
    points = re.search(rb"(?ms)^POINTS[ \t]+(\d+)[^\n]*\n(.*?)(?=^[A-Z_]{3,}\b|\Z)", data)
    if points and (held := len(points.group(2).split())) < 3 * int(points.group(1)):
        return f"its header declares {int(points.group(1))} points, the file holds {held} coordinates"
    return None


def _read_legacy_vtk(path: Path):
    """A legacy ``.vtk`` file read by pyvista, refused in one line when VTK reports an error
    or the file holds fewer points than it declares: its reader returns a truncated file's
    first part without raising."""
    import pyvista as pv

    with _vtk_errors() as errors:
        mesh = pv.read(str(path))
    if errors:
        raise InputError(f"the file ends early or is corrupt: VTK's legacy reader says '{errors[0][:160]}' (a truncated download or copy?)", path)
    if shortfall := _legacy_vtk_shortfall(path):
        raise InputError(f"the file ends early: {shortfall} (a truncated download or copy?)", path)
    return mesh


def _read_pyvista(path: Path, notes: list):
    """Vertices, triangles and per-triangle arrays of any VTK-readable file: surface cells
    (triangulated) of a surface, the boundary of a volume mesh; other cells are dropped."""
    import pyvista as pv

    _quiet_vtk()
    mesh = _read_legacy_vtk(path) if path.suffix.lower() == ".vtk" else pv.read(str(path))
    if isinstance(mesh, pv.MultiBlock):
        mesh = mesh.combine()
    empty = np.zeros((0, 3)), np.zeros((0, 3), np.int64), {}
    if mesh is None or mesh.n_cells == 0 or mesh.n_points == 0:
        return empty
    # one cell-type array for every kind of data set (PolyData has none of its own);
    # the cast keeps the cells (vertices, lines, polygons, strips) and their arrays
    grid = mesh if isinstance(mesh, pv.UnstructuredGrid) else mesh.cast_to_unstructured_grid()
    dims = _cell_dimensions(np.asarray(grid.celltypes))
    n_by_dim = np.bincount(dims, minlength=4)
    if n_by_dim[3]:
        surface = grid.extract_cells(np.flatnonzero(dims == 3)).extract_surface(algorithm="dataset_surface")
        notes.append(
            f"{path.name} is a volume mesh ({n_by_dim[3]} cells): meshing its boundary surface ({surface.n_cells} faces)"
            + (f"; {n_by_dim[:3].sum()} lower-dimensional cells ignored" if n_by_dim[:3].sum() else "")
        )
    elif n_by_dim[2]:
        surface = grid if n_by_dim[2] == grid.n_cells else grid.extract_cells(np.flatnonzero(dims == 2))
        surface = surface.extract_surface(algorithm="dataset_surface")
        dropped = [f"{n} {what}" for n, what in ((n_by_dim[1], "line"), (n_by_dim[0], "vertex")) if n]
        if dropped:
            notes.append(f"{path.name}: dropped {' and '.join(dropped)} cell(s) among its {n_by_dim[2]} surface faces")
    elif n_by_dim[1]:
        raise InputError(_CENTERLINE_HINT.format(n=n_by_dim[1], what="line cell"), path)
    else:
        return empty
    if surface.n_cells == 0:
        return empty
    if not surface.is_all_triangles:  # quads and polygons: an ordinary surface, no note
        surface = surface.triangulate()
    faces = surface.faces.reshape(-1, 4)[:, 1:].astype(np.int64)
    face_data = {
        k: np.asarray(surface.cell_data[k])
        for k in surface.cell_data.keys()
        if len(surface.cell_data[k]) == len(faces) and not k.startswith("vtk")
    }
    return np.asarray(surface.points, float), faces, face_data


def _read_off(path: Path):
    """ASCII OFF and its variants with per-vertex normals, colours or texture coordinates
    (``NOFF``, ``COFF``, ``STOFF``..., as pymeshlab writes them; meshio reads plain ``OFF``
    only and ends the process with ``SystemExit`` on anything else)."""
    rows = [r.split("#", 1)[0].split() for r in path.read_text(errors="replace").splitlines()]
    rows = [r for r in rows if r]
    head = rows[0] if rows else [""]
    if not re.fullmatch(r"(ST)?C?N?(OFF)", head[0]):
        raise ValueError(f"first word '{head[0][:20]}' is not an OFF keyword (OFF, NOFF, COFF, STOFF...; binary and 4D OFF are not read)")
    if len(head) > 1 and head[1].upper() == "BINARY":
        raise ValueError("binary OFF is not read: save it as ASCII OFF, PLY or STL")
    counts, body = (head[1:], rows[1:]) if len(head) > 1 else (rows[1] if len(rows) > 1 else [], rows[2:])
    if len(counts) < 2:
        raise ValueError("no vertex and face counts after the OFF keyword")
    nv, nf = int(counts[0]), int(counts[1])
    if len(body) < nv + nf:
        raise ValueError(f"the file ends early: {len(body)} vertex and face lines, its header says {nv} + {nf}")
    vertices = np.array([r[:3] for r in body[:nv]], float)
    return vertices, triangulate_polygons(_off_faces_by_size(body[nv : nv + nf])), {}


def _off_faces_by_size(rows: list) -> list:
    """OFF face lines (token lists ``k i_1 ... i_k [colour]``) grouped by size ``k``: one
    ``(m, k)`` index array per size, sizes ascending, faces in file order within each."""
    lengths = np.fromiter(map(len, rows), np.int64, len(rows))
    if len(rows) == 0:
        return []
    tokens = np.array(list(chain.from_iterable(rows)))  # the lines' tokens, as text: colours stay unread
    starts = np.concatenate([[0], np.cumsum(lengths)[:-1]])
    sizes = tokens[starts].astype(np.int64)
    if (short := np.flatnonzero(lengths < sizes + 1)).size:
        raise ValueError(f"face {short[0]} lists fewer than the {sizes[short[0]]} vertex indices it declares")
    groups = []
    for k in np.unique(sizes):  # a few sizes (triangles, quads...), not one pass per line
        first = starts[sizes == k]
        groups.append(tokens[first[:, None] + 1 + np.arange(k)].astype(np.int64))
    return groups


def write_surface(path: str | Path, surface: SurfaceMesh, binary: bool = True) -> Path:
    """Write ``surface`` atomically; the format follows the file extension."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in SURFACE_FORMATS:
        raise InputError(f"unknown surface format '{path.suffix}' (supported: {', '.join(sorted(SURFACE_FORMATS))})", path)
    with atomic_path(path) as tmp:
        if suffix == ".off":
            import meshio

            meshio.write_points_cells(str(tmp), surface.vertices, [("triangle", surface.faces)], file_format="off")
        elif suffix == ".vtp":  # numpy writers: no VTK import for the common formats
            from .vtk_xml import write_vtp_polygons

            write_vtp_polygons(tmp, surface.vertices, surface.faces, getattr(surface, "face_data", None) or None)
        elif suffix == ".ply" and binary:
            _write_ply_triangles(tmp, surface.vertices, surface.faces)
        else:
            mesh = surface.to_pyvista()
            if suffix == ".vtu":
                mesh = mesh.cast_to_unstructured_grid()
            mesh.save(str(tmp), binary=binary) if suffix in (".stl", ".ply", ".vtk", ".vtp", ".vtu") else mesh.save(str(tmp))
    return path


def _write_ply_triangles(path, vertices: np.ndarray, faces: np.ndarray) -> None:
    """Binary little-endian PLY of triangles (double coordinates: nothing lost on a round trip)."""
    vertices = np.ascontiguousarray(vertices, "<f8").reshape(-1, 3)
    face = np.empty(len(faces), np.dtype([("n", "u1"), ("v", "<i4", (3,))]))
    face["n"] = 3
    face["v"] = faces
    header = ["ply", "format binary_little_endian 1.0", "comment vmesh surface", f"element vertex {len(vertices)}",
              "property double x", "property double y", "property double z", f"element face {len(face)}",
              "property list uchar int vertex_indices", "end_header"]
    with open(path, "wb") as f:
        f.write(("\n".join(header) + "\n").encode())
        f.write(vertices.tobytes())
        f.write(face.tobytes())
