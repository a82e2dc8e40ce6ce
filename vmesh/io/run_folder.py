"""Read back a finished run folder (``vmesh run ... -o DIR``) for export and pictures.

A run folder holds ``mesh.vtu`` (hexahedra, linear or Lagrange, with every cell array and
the label/boundary names as field data), ``boundary.vtp`` (boundary quads with
``boundary_id``), ``blocks.vtu``, ``skeleton.json``, ``report.json``, ``chain.toml`` and,
when the chain ran ``export_meshlab``, ``meshlab/`` with the input and coarse surfaces.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from .._toml import tomllib
from ..errors import InputError
from ..mesh import VTK_HEXAHEDRON, VTK_LAGRANGE_HEXAHEDRON, tensor_to_vtk
from .mesh import names_from_field_data

#: Where a run folder keeps what the MeshLab export wrote.
MESHLAB_DIR = "meshlab"


def check_run_dir(run_dir) -> Path:
    """Raise a one-line :class:`InputError` unless ``run_dir`` is a finished run folder."""
    run_dir = Path(run_dir)
    if not run_dir.exists():
        raise InputError("run folder not found", run_dir)
    if not run_dir.is_dir():
        raise InputError("is not a folder, expected a run folder (vmesh run ... -o DIR)", run_dir)
    if not (run_dir / "mesh.vtu").is_file():
        raise InputError("no mesh.vtu: not a finished run folder (vmesh run ... -o DIR)", run_dir)
    return run_dir


def match_rows(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """For each row of ``b`` the index of the equal row of ``a`` (rows of ``a`` unique), or -1."""
    both = np.concatenate([a, b])
    _, inv = np.unique(both, axis=0, return_inverse=True)
    inv = inv.ravel()
    where = np.full(inv.max() + 1 if len(inv) else 0, -1, np.int64)
    where[inv[: len(a)]] = np.arange(len(a))
    return where[inv[len(a):]]


def read_mesh_vtu(path, boundary_path=None, node_distribution: str = "gauss_lobatto"):
    """Read a ``mesh.vtu`` written by vmesh back into a :class:`~vmesh.mesh.HexMesh`.

    The full (high-order) boundary faces are the element faces used by one element only;
    their ``boundary_id`` comes from ``boundary_path`` (``boundary.vtp``, matched by corner
    nodes), else every boundary face is wall.
    """
    import pyvista as pv

    from ..mesh import HexMesh
    from .export import face_corner_ids, tensor_faces

    path = Path(path)
    if not path.is_file():
        raise InputError("file not found", path)
    try:
        grid = pv.read(str(path))
    except Exception as exc:
        raise InputError(f"could not read as VTK UnstructuredGrid: {' '.join(str(exc).split())[:160]}", path) from None
    types = np.unique(np.asarray(grid.celltypes))
    if grid.n_cells == 0 or not set(types.tolist()) <= {VTK_HEXAHEDRON, VTK_LAGRANGE_HEXAHEDRON} or len(types) != 1:
        raise InputError(f"expected only hexahedra, found VTK cell types {types.tolist()}", path)
    conn = np.asarray(grid.cell_connectivity, np.int64)
    npc = len(conn) // grid.n_cells
    p = int(round(npc ** (1 / 3))) - 1
    if (p + 1) ** 3 != npc:
        raise InputError(f"cells of {npc} nodes are no tensor hexahedra", path)
    vtk_cells = conn.reshape(grid.n_cells, npc)
    cells = np.empty_like(vtk_cells)
    cells[:, tensor_to_vtk(p)] = vtk_cells  # vtk = tensor[perm]
    cell_data = {k: np.asarray(grid.cell_data[k]) for k in grid.cell_data.keys() if not k.startswith("vtk")}
    # boundary: faces used once
    faces = cells[:, tensor_faces(p)]  # (m, 6, (p+1)^2)
    corners = np.sort(faces[:, :, face_corner_ids(p)].reshape(-1, 4), axis=1)
    _, inv, cnt = np.unique(corners, axis=0, return_inverse=True, return_counts=True)
    once = np.flatnonzero(cnt[inv.ravel()] == 1)
    bfaces = faces.reshape(-1, (p + 1) ** 2)[once]
    bcells = once // 6
    bids = np.zeros(len(once), np.int64)
    bnames = names_from_field_data(grid.field_data, "boundary") or {0: "wall"}
    if boundary_path is not None and Path(boundary_path).is_file():
        b = pv.read(str(boundary_path))
        if "boundary_id" in b.cell_data and b.n_cells:
            quads = np.asarray(b.faces).reshape(-1, 5)[:, 1:]
            hit = match_rows(corners[once], np.sort(quads, axis=1))
            ok = hit >= 0
            bids[hit[ok]] = np.asarray(b.cell_data["boundary_id"])[ok]
        bnames = names_from_field_data(b.field_data, "boundary") or bnames
    return HexMesh(
        points=np.asarray(grid.points, np.float64),
        cells=cells,
        order=p,
        cell_data=cell_data,
        boundary_faces=bfaces,
        boundary_ids=bids,
        boundary_cells=bcells,
        boundary_names=bnames,
        label_names=names_from_field_data(grid.field_data, "label"),
        node_distribution=node_distribution,
    )


def read_report(run_dir) -> dict:
    """``report.json`` of a run folder ({} when absent or unreadable)."""
    try:
        return json.loads((Path(run_dir) / "report.json").read_text())
    except (OSError, ValueError):
        return {}


def chain_parameter(run_dir, filter_name: str, parameter: str, default=None):
    """A parameter of the chain as run (``chain.toml``), or ``default``."""
    try:
        data = tomllib.loads((Path(run_dir) / "chain.toml").read_text())
    except (OSError, tomllib.TOMLDecodeError):
        return default
    for step in data.get("step", []):
        if step.get("filter") == filter_name:
            return step.get("params", {}).get(parameter, default)
    return default


def read_run_mesh(run_dir):
    """The hexahedral mesh of a run folder, with named boundaries."""
    run_dir = check_run_dir(run_dir)
    nodes = chain_parameter(run_dir, "mesh_transfinite", "node_distribution", "gauss_lobatto")
    return read_mesh_vtu(run_dir / "mesh.vtu", run_dir / "boundary.vtp", node_distribution=nodes)


def run_surface_path(run_dir, layer: str = "surface") -> Path | None:
    """The run's (preprocessed) input or coarse surface file, else the input file named in
    ``report.json`` (for ``surface`` only), else ``None``."""
    run_dir = Path(run_dir)
    for name in (f"{MESHLAB_DIR}/{layer}.ply", f"{layer}.ply", f"{layer}.vtp", f"{layer}.stl"):
        if (run_dir / name).is_file():
            return run_dir / name
    if layer == "surface":
        src = read_report(run_dir).get("inputs", {}).get("surface")
        if src and Path(src).is_file():
            return Path(src)
    return None
