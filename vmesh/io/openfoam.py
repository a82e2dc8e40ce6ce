"""OpenFOAM case writer: ``constant/polyMesh`` of a linear hexahedral mesh, one patch per
boundary (``wall`` of type wall, inlets and outlets of type patch), one cellZone per element
label (``cellZones``) and one cellSet per block layer (``sets/core``, ``sets/ring``,
``sets/boundary_layer``), plus ``system/`` and an empty ``<case>.foam`` for ParaView. With a
:class:`~vmesh.io.openfoam_case.FlowCase` the case runs as is (``0/``, ``constant/``,
``system/`` for simpleFoam or pimpleFoam, :mod:`vmesh.io.openfoam_case`).

Faces follow OpenFOAM's rules: internal faces first, in upper-triangular order (by owner,
then neighbour), each with its normal pointing from owner to neighbour (the lower cell
index); then the boundary faces patch by patch, normals pointing out of the domain.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from .. import __version__
from ..errors import InputError, ParameterError
from .atomic import atomic_path
from .export import boundary_groups, boundary_local_faces, face_corner_ids, safe_names, tensor_faces

_HEADER = """/*--------------------------------*- C++ -*----------------------------------*\\
  Written by vmesh {version}
\\*---------------------------------------------------------------------------*/
FoamFile
{{
    version     2.0;
    format      ascii;
    class       {cls};{note}
    location    "{location}";
    object      {obj};
}}
// * * * * * * * * * * * * * * * * * * * * * * * * * * * * * * * * * * * * * //

"""

_SYSTEM = {
    "controlDict": (
        "application     simpleFoam;\nstartFrom       startTime;\nstartTime       0;\n"
        "stopAt          endTime;\nendTime         1;\ndeltaT          1;\nwriteControl    timeStep;\nwriteInterval   1;\n"
    ),
    "fvSchemes": (
        "ddtSchemes { default steadyState; }\ngradSchemes { default Gauss linear; }\n"
        "divSchemes { default none; }\nlaplacianSchemes { default Gauss linear corrected; }\n"
        "interpolationSchemes { default linear; }\nsnGradSchemes { default corrected; }\n"
    ),
    "fvSolution": "solvers {}\n",
}


def _header(cls, location, obj, note=""):
    return _HEADER.format(version=__version__, cls=cls, location=location, obj=obj, note=f'\n    note        "{note}";' if note else "")


def poly_faces(mesh) -> dict:
    """OpenFOAM faces of a linear hexahedral mesh.

    Returns
    -------
    dict
        ``faces`` (nf, 4), ``owner`` (nf,), ``neighbour`` (n_internal,), ``patches``:
        list of ``(boundary id, n faces, start face)``.
    """
    if mesh.order != 1:
        raise ParameterError(f"OpenFOAM polyMesh holds linear cells only, the mesh has p = {mesh.order}")
    m = mesh.n_cells
    local = tensor_faces(1)[:, face_corner_ids(1)]  # (6, 4) outward corner loops
    faces = mesh.cells[:, local].reshape(-1, 4)
    cell = np.repeat(np.arange(m), 6)
    _, inv, cnt = np.unique(np.sort(faces, axis=1), axis=0, return_inverse=True, return_counts=True)
    inv = inv.ravel()
    if len(cnt) and cnt.max() > 2:
        raise ParameterError(f"{int((cnt > 2).sum())} faces are shared by more than two elements")
    order = np.lexsort((cell, inv))  # occurrences grouped by face, lower cell first
    inv_s = inv[order]
    start = np.flatnonzero(np.r_[True, inv_s[1:] != inv_s[:-1]])
    pair = start[cnt[inv_s[start]] == 2]
    own_occ, nb_occ = order[pair], order[pair + 1]
    own, nb = cell[own_occ], cell[nb_occ]
    sort = np.lexsort((nb, own))  # upper-triangular order
    own_occ, own, nb = own_occ[sort], own[sort], nb[sort]
    # boundary faces: the named boundary faces, by their element's local face
    bocc = np.asarray(mesh.boundary_cells) * 6 + boundary_local_faces(mesh)
    if len(bocc) != int((cnt == 1).sum()) or (cnt[inv[bocc]] != 1).any():
        raise ParameterError(
            f"the mesh has {int((cnt == 1).sum())} faces on one element only but {len(bocc)} named boundary faces"
        )
    bid = np.asarray(mesh.boundary_ids)
    border = np.lexsort((mesh.boundary_cells, bid))
    patches, startface = [], len(own)
    for b in boundary_groups(mesh):
        n = int((bid == b).sum())
        patches.append((b, n, startface))
        startface += n
    all_occ = np.concatenate([own_occ, bocc[border]])
    return {
        "faces": faces[all_occ],
        "owner": cell[all_occ],
        "neighbour": nb,
        "patches": patches,
    }


def _list(fh, header, rows: np.ndarray, fmt: str) -> None:
    fh.write(header)
    fh.write(f"{len(rows)}\n(\n")
    if len(rows):
        np.savetxt(fh, rows, fmt=fmt)
    fh.write(")\n")


def _cell_list(fh, header, ids) -> None:
    _list(fh, header, np.asarray(ids, np.int64)[:, None], "%d")


def _write_zones(pm: Path, mesh, loc: str) -> None:
    """``cellZones`` (one per label) and ``sets/<layer>`` cellSets (one per block layer)."""
    from ..blocks import LAYER_NAMES
    from .export import cell_labels

    labels, names = cell_labels(mesh)
    with open(pm / "cellZones", "w") as fh:
        fh.write(_header("regIOobject", loc, "cellZones") + f"{len(names)}\n(\n")
        for k, name in zip(names, safe_names(names.values())):
            fh.write(f"{name}\n{{\n    type cellZone;\ncellLabels      List<label> \n")
            _cell_list(fh, "", np.flatnonzero(labels == k))
            fh.write(";\n}\n")
        fh.write(")\n")
    layer = mesh.cell_data.get("layer")
    if layer is None:
        return
    (pm / "sets").mkdir()
    for k, name in LAYER_NAMES.items():
        ids = np.flatnonzero(np.asarray(layer) == k)
        if len(ids):
            with open(pm / "sets" / name, "w") as fh:
                _cell_list(fh, _header("cellSet", f"{loc}/sets", name), ids)


def write(path, mesh, case_name: str | None = None, flow=None) -> Path:
    """Write ``mesh`` as the OpenFOAM case folder ``path`` (atomically: the whole folder is
    written under a temporary name and renamed at the end).

    Parameters
    ----------
    flow : FlowCase, optional
        Also write ``0/``, ``constant/`` and ``system/`` for this flow (lengths must be in metres).
    """
    from .openfoam_case import case_files

    path = Path(path)
    if flow is not None and mesh.units != "m":
        raise ParameterError(
            f"an OpenFOAM {flow.kind} case needs lengths in metres, the mesh is in {mesh.units or 'unknown units'} (export with --to-units m)", path
        )
    poly = poly_faces(mesh)
    names = boundary_groups(mesh)
    safe = dict(zip(names, safe_names(names.values())))
    n_int = len(poly["neighbour"])
    note = f"nPoints:{mesh.n_points}  nCells:{mesh.n_cells}  nFaces:{len(poly['faces'])}  nInternalFaces:{n_int}"
    loc = "constant/polyMesh"
    with atomic_path(path, folder=True) as tmp:
        tmp.unlink()  # atomic_path made a file; a case is a folder
        pm = tmp / "constant" / "polyMesh"
        pm.mkdir(parents=True)
        (tmp / "system").mkdir()
        units_note = f"lengths in {mesh.units}" if mesh.units else "length unit unknown"
        files = {f"system/{k}": ("dictionary", v) for k, v in _SYSTEM.items()}
        if flow is not None:
            files.update(case_files(flow, [safe[b] for b in names], units_note))
        for rel, (cls, body) in files.items():
            (tmp / rel).parent.mkdir(parents=True, exist_ok=True)
            (tmp / rel).write_text(_header(cls, str(Path(rel).parent), Path(rel).name) + body)
        with open(pm / "points", "w") as fh:
            _list(fh, _header("vectorField", loc, "points", units_note), mesh.points, "(%.17g %.17g %.17g)")
        with open(pm / "faces", "w") as fh:
            _list(fh, _header("faceList", loc, "faces"), poly["faces"], "4(%d %d %d %d)")
        with open(pm / "owner", "w") as fh:
            _list(fh, _header("labelList", loc, "owner", note), poly["owner"][:, None], "%d")
        with open(pm / "neighbour", "w") as fh:
            _list(fh, _header("labelList", loc, "neighbour", note), poly["neighbour"][:, None], "%d")
        body = [f"{len(poly['patches'])}\n(\n"]
        for b, n, start in poly["patches"]:
            kind = "wall" if names[b] == "wall" else "patch"
            group = f"        inGroups        List<word> 1({kind});\n"
            body.append(f"    {safe[b]}\n    {{\n        type            {kind};\n{group}        nFaces          {n};\n        startFace       {start};\n    }}\n")
        body.append(")\n")
        (pm / "boundary").write_text(_header("polyBoundaryMesh", loc, "boundary") + "".join(body))
        _write_zones(pm, mesh, loc)
        (tmp / f"{case_name or path.name}.foam").write_text("")
    return path


# --- reading back (checks) -------------------------------------------------------------


def _strip(text: str) -> str:
    text = re.sub(r"/\*.*?\*/", "", text, flags=re.S)
    text = re.sub(r"//[^\n]*", "", text)
    return re.sub(r"FoamFile\s*\{.*?\}", "", text, count=1, flags=re.S)


def _read_list(path: Path) -> str:
    text = _strip(path.read_text())
    m = re.search(r"(\d+)\s*\((.*)\)", text, flags=re.S)
    if not m:
        raise InputError("no list found", path)
    return m.group(1), m.group(2)


def read_polymesh(case) -> dict:
    """Read ``constant/polyMesh`` of a case written by :func:`write` (ASCII): point, face,
    cell counts and the patches ``{name: {"type", "nFaces", "startFace"}}``."""
    pm = Path(case) / "constant" / "polyMesh"
    if not (pm / "points").is_file():
        raise InputError("no constant/polyMesh/points: not an OpenFOAM case", case)
    n, body = _read_list(pm / "points")
    points = np.array(re.findall(r"[-+0-9.eE]+", body), float).reshape(-1, 3)
    n, body = _read_list(pm / "faces")
    faces = np.array([f.split() for f in re.findall(r"\d+\(([^)]*)\)", body)], int)
    owner = np.array(_read_list(pm / "owner")[1].split(), int)
    neighbour = np.array(_read_list(pm / "neighbour")[1].split(), int)
    text = _strip((pm / "boundary").read_text())
    patches = {}
    for name, block in re.findall(r"(\w+)\s*\{([^}]*)\}", text):
        entries = dict(re.findall(r"(\w+)\s+([^;]+);", block))
        patches[name] = {"type": entries.get("type"), "nFaces": int(entries["nFaces"]), "startFace": int(entries["startFace"])}
    n_cells = int(max(owner.max(initial=-1), neighbour.max(initial=-1)) + 1)
    return {"points": points, "faces": faces, "owner": owner, "neighbour": neighbour, "patches": patches, "n_cells": n_cells}


def read_field(case, time, name) -> np.ndarray:
    """The internal field ``time/name`` of an ASCII case ((n,) or (n, 3); uniform fields
    expanded to the cell count)."""
    path = Path(case) / str(time) / name
    if not path.is_file():
        raise InputError("no such field", path)
    text = _strip(path.read_text())
    m = re.search(r"internalField\s+nonuniform\s+List<(\w+)>\s*(\d+)\s*\((.*?)\)\s*;", text, flags=re.S)
    if m:
        values = np.array(re.findall(r"[-+0-9.eE]+", m.group(3)), float)
        return values.reshape(int(m.group(2)), -1).squeeze()
    m = re.search(r"internalField\s+uniform\s+(\([^)]*\)|[-+0-9.eE]+)\s*;", text)
    if not m:
        raise InputError("no internalField", path)
    value = np.array(re.findall(r"[-+0-9.eE]+", m.group(1)), float)
    n = read_polymesh(case)["n_cells"]
    return np.tile(value, (n, 1)).squeeze()


def patch_cells(poly: dict, name: str) -> np.ndarray:
    """Cells next to the faces of patch ``name`` (one per face)."""
    p = poly["patches"][name]
    return poly["owner"][p["startFace"]: p["startFace"] + p["nFaces"]]
