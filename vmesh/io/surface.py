"""Read and write triangle surfaces (STL, OBJ, PLY, VTP, VTK, VTU, OFF).

VTK XML PolyData (.vtp) is read with numpy (:func:`vmesh.io.vtk_xml.read_vtp_triangles`,
VTK for what it does not handle), the other VTK-family files and STL/OBJ/PLY with
pyvista (VTK's readers), OFF with meshio. Quads and polygons are fan-triangulated; per-face arrays are kept.
"""

from __future__ import annotations

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


def read_surface(path: str | Path) -> SurfaceMesh:
    """Read a surface file into a :class:`SurfaceMesh` of triangles.

    Raises
    ------
    InputError
        One line naming the file and the problem: missing, empty, unknown format,
        unreadable, or without any surface faces.
    """
    path = check_input_file(path, SURFACE_FORMATS, "surface")
    suffix = path.suffix.lower()
    fmt = SURFACE_FORMATS[suffix]
    try:
        if suffix == ".off":
            vertices, faces, face_data = _read_meshio(path)
        elif suffix == ".vtp":
            vertices, faces, face_data = _read_vtp(path)
        else:
            vertices, faces, face_data = _read_pyvista(path)
    except InputError:
        raise
    except Exception as exc:  # readers raise anything on corrupt input
        raise InputError(f"could not read as {fmt}: {_short(exc)}", path) from None
    if len(faces) == 0 or len(vertices) == 0:
        raise InputError(f"no surface faces found (empty or corrupt {fmt} file)", path)
    if not np.all(np.isfinite(vertices)):
        raise InputError("vertex coordinates contain NaN or infinite values", path)
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise InputError("face vertex indices are out of range (corrupt file)", path)
    return SurfaceMesh(vertices, faces, name=path.name, face_data=face_data)


def _short(exc: Exception) -> str:
    text = " ".join(str(exc).split()) or type(exc).__name__
    return text[:200]


def _read_vtp(path: Path):
    """VTK XML PolyData read with numpy (no VTK import, which costs more than reading);
    what that reader does not handle (strips, lines, other compressors...) goes to VTK."""
    from .vtk_xml import UnsupportedVTKXML, read_vtp_triangles

    try:
        return read_vtp_triangles(path)
    except UnsupportedVTKXML:
        return _read_pyvista(path)


def _read_pyvista(path: Path):
    import pyvista as pv

    _quiet_vtk()
    mesh = pv.read(str(path))
    if isinstance(mesh, pv.MultiBlock):
        mesh = mesh.combine()
    if not isinstance(mesh, pv.PolyData):
        mesh = mesh.extract_surface(algorithm="dataset_surface")
    # drop lines/vertices, keep polygons, triangulate quads and polygons
    if mesh.n_cells == 0 or mesh.n_points == 0:
        return np.zeros((0, 3)), np.zeros((0, 3), np.int64), {}
    if mesh.n_lines or mesh.n_verts:
        mesh = mesh.extract_cells(np.flatnonzero(_polygon_mask(mesh))).extract_surface(algorithm="dataset_surface")
    if mesh.n_cells == 0:
        return np.zeros((0, 3)), np.zeros((0, 3), np.int64), {}
    if not mesh.is_all_triangles:
        mesh = mesh.triangulate()
    faces = mesh.faces.reshape(-1, 4)[:, 1:].astype(np.int64)
    face_data = {
        k: np.asarray(mesh.cell_data[k])
        for k in mesh.cell_data.keys()
        if len(mesh.cell_data[k]) == len(faces) and not k.startswith("vtk")
    }
    return np.asarray(mesh.points, float), faces, face_data


def _polygon_mask(mesh) -> np.ndarray:
    import pyvista as pv

    ctypes = np.asarray(mesh.celltypes)
    return np.isin(ctypes, [pv.CellType.TRIANGLE, pv.CellType.QUAD, pv.CellType.POLYGON, pv.CellType.TRIANGLE_STRIP])


def _read_meshio(path: Path):
    import meshio

    m = meshio.read(str(path))
    blocks = [c.data for c in m.cells if c.type in ("triangle", "quad", "polygon") or c.type.startswith("polygon")]
    return np.asarray(m.points, float)[:, :3], triangulate_polygons(blocks), {}


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
