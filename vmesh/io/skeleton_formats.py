"""Centerline file formats: VTK (VMTK, SimVascular, plain polylines), SWC, CSV and PLY.

Readers return a :class:`~vmesh.skeleton.Skeleton`; writers write one atomically.
All of them are registered by suffix in :data:`vmesh.io.skeleton.SKELETON_READERS` and
:data:`~vmesh.io.skeleton.SKELETON_WRITERS`.

VTK files (``.vtp``, ``.vtk``) hold one of three kinds of centerline, told apart by
their content (:func:`vtk_centerline_kind`):

``vmtk``
    Several polylines from the inlet to each outlet that coincide along shared trunks
    (``vmtkcenterlines``), radius in ``MaximumInscribedSphereRadius``. The trunks are
    merged into one tree (:func:`~vmesh.geometry.skeleton.polylines.merge_overlapping_polylines`).
``simvascular``
    A centerline graph of two-point segments with ``GlobalNodeId``, ``BranchId`` and
    ``BifurcationId`` point arrays (``sv.centerlines``); points sharing a global id are
    one node.
``polylines``
    Any other lines or polylines; points with identical coordinates are welded. The
    radius is read from the first of :data:`RADIUS_ARRAYS` present, NaN otherwise.

Tags are read from point (node) and cell (segment) arrays: string arrays named like
:data:`TAG_ARRAYS` (several tags separated by ``;``) and integer label arrays
(:data:`LABEL_ARRAYS`, e.g. ``BranchId`` 3 -> ``branch_3``; negative values mean
"none"). Writers store tags in a ``Tags`` string array, so files round-trip.
"""

from __future__ import annotations

import csv
import io
import re
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..geometry.skeleton import graph as sk_graph, polylines as sk_polylines, tags as sk_tags
from ..skeleton import Skeleton
from .atomic import atomic_path, write_text_atomic
from .ply import _TYPES as _PLY_TYPES, UnsupportedPLY, ply_header

#: Point-array names holding the vessel radius, in order of preference (case-insensitive).
RADIUS_ARRAYS = ("MaximumInscribedSphereRadius", "Radius", "Radii", "radius", "R", "InscribedSphereRadius")
#: String arrays holding tags, several per entry separated by ``;`` (case-insensitive).
TAG_ARRAYS = ("Tags", "Tag", "Labels", "Label", "Names", "Name")
#: Integer label arrays and the tag prefix of their values.
LABEL_ARRAYS = {
    "branchid": "branch",
    "bifurcationid": "bifurcation",
    "groupids": "group",
    "groupid": "group",
    "tags": "tag",
    "tag": "tag",
    "labels": "label",
    "label": "label",
}

VTK_KINDS = ("auto", "vmtk", "simvascular", "polylines")


# ---------------------------------------------------------------------------
# VTK
# ---------------------------------------------------------------------------


def _load_vtk(path: Path):
    import pyvista as pv
    import vtk

    vtk.vtkObject.GlobalWarningDisplayOff()
    mesh = pv.read(str(path))
    if isinstance(mesh, pv.MultiBlock):
        mesh = mesh.combine()
    if mesh is not None and not isinstance(mesh, pv.PolyData):
        mesh = mesh.extract_surface()  # keeps line cells and point data
    if mesh is None or mesh.n_points == 0:
        raise InputError("no points found (empty or corrupt VTK file)", path)
    return mesh


def vtk_lines(mesh) -> list[np.ndarray]:
    """Point-id arrays of every line and polyline cell of a pyvista data set (other data
    sets are first reduced to their PolyData geometry, which keeps line cells)."""
    import pyvista as pv

    if not isinstance(mesh, pv.PolyData):
        mesh = mesh.extract_surface()
    flat = np.asarray(mesh.lines, np.int64)
    out, i = [], 0
    while i < len(flat):  # one Python step per cell: cells are few compared with points
        n = int(flat[i])
        out.append(flat[i + 1 : i + 1 + n])
        i += n + 1
    return out


def _array(data, names) -> tuple[str, np.ndarray] | tuple[None, None]:
    lower = {k.lower(): k for k in data.keys()}
    for name in names:
        key = lower.get(name.lower())
        if key is not None:
            return key, np.asarray(data[key])
    return None, None


def point_radius(mesh) -> np.ndarray:
    """Radius per point from the first known radius array (point data, else cell data
    averaged onto points); NaN where there is none."""
    key, r = _array(mesh.point_data, RADIUS_ARRAYS)
    if r is None:
        key, rc = _array(mesh.cell_data, RADIUS_ARRAYS)
        if rc is None or rc.ndim != 1:
            return np.full(mesh.n_points, np.nan)
        r = np.asarray(mesh.cell_data_to_point_data().point_data[key])
    r = np.asarray(r, float).reshape(len(r), -1)[:, 0]
    return np.where(r > 0, r, np.nan)


def _tags_from_arrays(data, n: int) -> list[tuple]:
    """Tags per entry of a point- or cell-data collection (see the module docstring)."""
    tags: list[tuple] = [()] * n
    found = []
    for key in data.keys():
        arr = np.asarray(data[key])
        if len(arr) != n or arr.ndim != 1:
            continue
        low = key.lower()
        if arr.dtype.kind in "US" and low in {t.lower() for t in TAG_ARRAYS}:
            found.append([tuple(x for x in re.split(r"[;,]", str(v)) if x.strip()) for v in arr.tolist()])
        elif arr.dtype.kind in "iu" and low in LABEL_ARRAYS:
            prefix = LABEL_ARRAYS[low]
            found.append([(f"{prefix}_{v}",) if v >= 0 else () for v in arr.tolist()])
    for column in found:
        tags = [sk_graph._union(a, b) for a, b in zip(tags, column)]
    return [tuple(t.strip() for t in x) for x in tags]


def vtk_centerline_kind(mesh, lines: list[np.ndarray] | None = None) -> str:
    """``"simvascular"``, ``"vmtk"`` or ``"polylines"`` (see the module docstring)."""
    names = {k.lower() for k in mesh.point_data.keys()}
    if "globalnodeid" in names and ({"branchid", "bifurcationid"} & names):
        return "simvascular"
    lines = vtk_lines(mesh) if lines is None else lines
    if len(lines) >= 2:
        pts = np.asarray(mesh.points, float)
        r = point_radius(mesh)
        if sk_polylines.polylines_overlap([pts[l] for l in lines], [r[l] for l in lines]):
            return "vmtk"
    return "polylines"


def read_centerline_vtk(path, kind: str = "auto", merge_tolerance: float = 0.2) -> Skeleton:
    """Read a centerline from a ``.vtp``/``.vtk`` file.

    Parameters
    ----------
    path : path
    kind : {"auto", "vmtk", "simvascular", "polylines"}
        What the file holds; ``"auto"`` tells from the content.
    merge_tolerance : float
        VMTK only: points of different lines closer than this many radii are one.

    Raises
    ------
    InputError
        The file has no line cells, or a kind that does not fit its content.
    """
    path = Path(path)
    if kind not in VTK_KINDS:
        raise InputError(f"unknown centerline kind '{kind}' (choose {', '.join(VTK_KINDS)})", path)
    mesh = _load_vtk(path)
    lines = vtk_lines(mesh)
    if not any(len(l) for l in lines):
        raise InputError("no line or polyline cells (is it a surface rather than a centerline?)", path)
    if kind == "auto":
        kind = vtk_centerline_kind(mesh, lines)
    name = path.name
    pts = np.asarray(mesh.points, float)
    if not np.isfinite(pts).all():
        raise InputError("point coordinates contain NaN or infinite values", path)
    radius = point_radius(mesh)
    ptags = _tags_from_arrays(mesh.point_data, mesh.n_points)
    ctags = _tags_from_arrays(mesh.cell_data, mesh.n_cells)[mesh.n_verts : mesh.n_verts + len(lines)]
    if kind == "vmtk":
        cell_tags = _point_cell_tags(lines, ctags, pts)  # before the tracts are joined: a line is a cell
        lines = join_tracts(lines, mesh.cell_data, mesh.n_verts, pts)
        return _vmtk_skeleton(pts, radius, ptags, [l for l in lines if len(l)], merge_tolerance, name, cell_tags)
    if kind == "simvascular":
        key, gid = _array(mesh.point_data, ("GlobalNodeId",))
        if gid is None:
            raise InputError("SimVascular centerlines need a GlobalNodeId point array", path)
        _, path_len = _array(mesh.point_data, ("Path",))
        return _graph_skeleton(pts, radius, ptags, lines, ctags, name, node_ids=gid.astype(np.int64), path_length=path_len)
    return _graph_skeleton(pts, radius, ptags, lines, ctags, name)


def join_tracts(lines: list[np.ndarray], cell_data, n_verts: int, points: np.ndarray) -> list[np.ndarray]:
    """Join the tracts of branch-split VMTK centerlines into one line per centerline.

    ``vmtkbranchextractor`` cuts every inlet-to-outlet centerline into tracts (cell
    arrays ``CenterlineIds`` and ``TractIds``; ``Blanking`` marks the tracts inside a
    bifurcation) whose end points repeat the next tract's first point under another
    id. Merged as separate lines, the tracts fall apart into pieces; joined in tract
    order they are the centerlines again. Lines without these arrays are returned as
    they are.
    """
    _, centerline = _array(cell_data, ("CenterlineIds",))
    _, tract = _array(cell_data, ("TractIds",))
    if centerline is None or tract is None:
        return lines
    centerline = np.asarray(centerline).reshape(-1)[n_verts : n_verts + len(lines)]
    tract = np.asarray(tract).reshape(-1)[n_verts : n_verts + len(lines)]
    if len(centerline) != len(lines) or len(np.unique(np.c_[centerline, tract], axis=0)) != len(lines):
        return lines  # not one cell per (centerline, tract): leave the lines alone
    scale = float(np.ptp(points, axis=0).max()) or 1.0
    joined = []
    for c in np.unique(centerline):
        cells = np.flatnonzero(centerline == c)
        cells = cells[np.argsort(tract[cells], kind="stable")]
        parts = [lines[cells[0]]]
        for k in cells[1:].tolist():
            nxt = lines[k]
            if len(nxt) and len(parts[-1]) and np.linalg.norm(points[nxt[0]] - points[parts[-1][-1]]) <= 1e-6 * scale:
                nxt = nxt[1:]  # the joint point, repeated
            parts.append(nxt)
        joined.append(np.concatenate(parts))
    return joined


def _line_cells(mesh_lines: list[np.ndarray]) -> np.ndarray:
    """Position in ``mesh_lines`` of the line every segment comes from, in segment order."""
    return np.concatenate([np.full(max(len(l) - 1, 0), k) for k, l in enumerate(mesh_lines)]).astype(np.int64)


def _graph_skeleton(pts, radius, ptags, lines, ctags, name, node_ids=None, path_length=None) -> Skeleton:
    """Skeleton of lines that share points (by id, by ``node_ids`` or by coordinates)."""
    seg = np.concatenate([np.c_[l[:-1], l[1:]] for l in lines if len(l) > 1]) if any(len(l) > 1 for l in lines) else np.zeros((0, 2), np.int64)
    seg_cell = _line_cells(lines)
    if node_ids is not None:
        _, first, inv = np.unique(node_ids, return_index=True, return_inverse=True)
        rep = first[inv.ravel()]
    else:
        scale = float(np.ptp(pts, axis=0).max()) or 1.0
        rep, _ = sk_polylines.merge_coincident_points(pts, seg, 1e-9 * scale)
    used = np.unique(np.r_[rep[seg.ravel()], rep[np.concatenate(lines)]])
    index = np.full(len(pts), -1, np.int64)
    index[used] = np.arange(len(used))
    node_of = index[rep]
    # a node's radius/tags: those of its representative point, tags united over duplicates
    tags = [()] * len(used)
    for p in np.flatnonzero(node_of >= 0).tolist():
        if ptags[p]:
            tags[node_of[p]] = sk_graph._union(tags[node_of[p]], ptags[p])
    rad = np.full(len(used), np.nan)
    ok = np.isfinite(radius) & (node_of >= 0)
    np.fmax.at(rad, node_of[ok], radius[ok])
    edges = node_of[seg]
    etags = [ctags[c] if len(ctags) else () for c in seg_cell.tolist()]
    edges, etags = sk_graph.simplify_edges(edges, etags)
    skel = Skeleton(pts[used], rad, edges, tags, etags, name=name)
    if path_length is not None:
        skel = _tag_ends_by_path(skel, np.asarray(path_length, float)[used])
    return skel


def _tag_ends_by_path(skel: Skeleton, path_length: np.ndarray) -> Skeleton:
    """SimVascular: the endpoint at path length 0 is the inlet, the others are outlets."""
    ends = skel.endpoints
    if len(ends) < 2:
        return skel
    inlet = ends[np.argmin(path_length[ends])]
    tags = list(skel.node_tags)
    for e in ends.tolist():
        tags[e] = sk_graph._union(tags[e], ("inlet",) if e == inlet else ("outlet",))
    return skel.copy(node_tags=tags)


def _point_cell_tags(lines: list[np.ndarray], ctags: list[tuple], pts: np.ndarray) -> list[tuple]:
    """The tags of the line cells through each point (VMTK's ``GroupIds`` -> ``group_3``...),
    united over points at one position: a VMTK tract's first point repeats the previous
    tract's last under another id, so a joint point carries both tracts' tags."""
    out: list[tuple] = [()] * len(pts)
    tagged = [(l, t) for l, t in zip(lines, ctags) if t and len(l)]
    if not tagged:
        return out
    scale = float(np.ptp(pts, axis=0).max()) or 1.0
    rep, _ = sk_polylines.merge_coincident_points(pts, np.zeros((0, 2), np.int64), 1e-6 * scale)
    for line, t in tagged:  # one step per cell and point of it: cells are few
        for r in np.unique(rep[line]).tolist():
            out[r] = sk_graph._union(out[r], t)
    return [out[r] for r in rep.tolist()]


def _vmtk_skeleton(pts, radius, ptags, lines, tolerance, name, cell_tags=None) -> Skeleton:
    """The tree of overlapping VMTK centerlines; a segment's tags are those of the cells
    through both its end points (``cell_tags``, :func:`_point_cell_tags`)."""
    merged = sk_polylines.merge_overlapping_polylines([pts[l] for l in lines], [radius[l] for l in lines], tolerance)
    src = np.array([lines[li][k] for li, k in merged.origin.tolist()], np.int64)
    tags = [ptags[p] for p in src.tolist()]
    edge_tags = None
    if cell_tags is not None and any(cell_tags):
        ends = [cell_tags[p] for p in src.tolist()]
        edge_tags = [tuple(t for t in ends[a] if t in ends[b]) for a, b in merged.edges.tolist()]
    skel = Skeleton(merged.points, merged.radii, merged.edges, tags, edge_tags or [], name=name)
    deg = skel.degrees
    ends = np.flatnonzero(deg == 1)
    last = {(li, len(lines[li]) - 1) for li in range(len(lines))}
    for e in ends.tolist():
        li, k = merged.origin[e]
        if e == merged.source:
            tags[e] = sk_graph._union(tags[e], ("inlet",))
        elif merged.source >= 0 and (int(li), int(k)) in last:
            tags[e] = sk_graph._union(tags[e], ("outlet",))
    return skel.copy(node_tags=tags)


def write_skeleton_vtk(path, skeleton: Skeleton) -> Path:
    """Write polylines (one per branch, split where segment tags change) with point data
    ``Radius``, ``Degree`` and ``Tags`` and cell data ``Tags``, for ParaView.

    The suffix picks XML (``.vtp``) or legacy (``.vtk``) VTK.
    """
    import pyvista as pv

    path = Path(path)
    paths = sk_graph.branch_paths(skeleton.n_nodes, skeleton.edges)
    path_e = sk_graph.path_edge_ids(skeleton.n_nodes, skeleton.edges, paths)
    cells, cell_tags = [], []
    for p, pe in zip(paths, path_e):
        tags = [skeleton.edge_tags[e] for e in pe.tolist()]
        cut = [0] + [i for i in range(1, len(tags)) if tags[i] != tags[i - 1]] + [len(tags)]
        for a, b in zip(cut[:-1], cut[1:]):
            cells.append(p[a : b + 1])
            cell_tags.append(";".join(tags[a]))
    isolated = np.flatnonzero(skeleton.degrees == 0)
    flat = np.concatenate([np.r_[len(c), c] for c in cells]).astype(np.int64) if cells else np.zeros(0, np.int64)
    cell_kw = {}
    if len(flat):
        cell_kw["lines"] = flat
    if len(isolated):
        cell_kw["verts"] = np.c_[np.ones(len(isolated), np.int64), isolated].ravel()
    if not cell_kw:  # PolyData(points) alone would make every point a vertex cell
        cell_kw["lines"] = np.zeros(0, np.int64)
    mesh = pv.PolyData(skeleton.points.copy(), **cell_kw)
    mesh.point_data["Radius"] = skeleton.radii
    mesh.point_data["Degree"] = skeleton.degrees.astype(np.int32)
    mesh.point_data["Tags"] = np.array([";".join(t) for t in skeleton.node_tags], dtype=str)
    if mesh.n_cells:
        ctags = [""] * len(isolated) + cell_tags  # VTK orders cells: vertices, then lines
        mesh.cell_data["Tags"] = np.array(ctags, dtype=str)
    with atomic_path(path) as tmp:
        mesh.save(str(tmp), binary=True)
    return path


# ---------------------------------------------------------------------------
# SWC
# ---------------------------------------------------------------------------


_SWC_TYPE_TAG = re.compile(r"swc_type_(-?\d+)")  # the node tag read_swc gives each SWC type


def _swc_type(tags) -> int | None:
    """The SWC type named by one of ``tags`` (``swc_type_<n>``), else None."""
    return next((int(m.group(1)) for m in map(_SWC_TYPE_TAG.fullmatch, tags) if m), None)


def read_swc(path) -> Skeleton:
    """Read an SWC file (``id type x y z radius parent`` per line, ``#`` comments).

    The type column becomes the node tag ``swc_type_<n>``, or the tags named for that
    type by ``# vmesh tag <type> <tag>[+<tag>...]`` comments (written by
    :func:`write_swc`), which also tag the segment to the sample's parent; radii <= 0 are
    unknown (NaN).
    """
    path = Path(path)
    rows = []
    try:
        text = path.read_text()
    except UnicodeDecodeError:
        raise InputError("not a text (SWC) file", path) from None
    named: dict[int, tuple] = {}
    for lineno, line in enumerate(text.splitlines(), 1):
        tag_line = re.fullmatch(r"\s*#\s*vmesh tag (-?\d+) (\S+)\s*", line)
        if tag_line:
            named[int(tag_line.group(1))] = tuple(tag_line.group(2).split("+"))
        body = line.split("#", 1)[0].strip()
        if not body:
            continue
        parts = body.split()
        if len(parts) < 7:
            raise InputError(f"line {lineno}: expected 7 columns (id type x y z radius parent), got {len(parts)}", path)
        try:
            rows.append([float(x) for x in parts[:7]])
        except ValueError:
            raise InputError(f"line {lineno}: non-numeric value in {body!r}", path) from None
    if not rows:
        raise InputError("no SWC samples found", path)
    a = np.asarray(rows)
    ids, types, pts, rad, parent = a[:, 0].astype(np.int64), a[:, 1].astype(np.int64), a[:, 2:5], a[:, 5], a[:, 6].astype(np.int64)
    if not np.isfinite(pts).all():
        raise InputError("coordinates contain NaN or infinite values", path)
    order = np.argsort(ids, kind="stable")
    sorted_ids = ids[order]
    dup = sorted_ids[1:][sorted_ids[1:] == sorted_ids[:-1]]
    if len(dup):
        raise InputError(f"sample id {dup[0]} appears twice", path)
    has_parent = parent >= 0
    pos = np.searchsorted(sorted_ids, parent[has_parent])
    pos = np.minimum(pos, len(ids) - 1)
    missing = sorted_ids[pos] != parent[has_parent]
    if missing.any():
        bad = parent[has_parent][missing][0]
        raise InputError(f"parent id {bad} does not exist", path)
    child = np.flatnonzero(has_parent)
    edges = np.c_[order[pos], child]
    if (edges[:, 0] == edges[:, 1]).any():
        raise InputError("a sample is its own parent", path)
    tags = [named.get(t, (f"swc_type_{t}",)) for t in types.tolist()]
    edge_tags = [tags[c] if types[c] in named else () for c in child.tolist()]
    return Skeleton(pts, np.where(rad > 0, rad, np.nan), edges, tags, edge_tags, name=path.name)


def write_swc(path, skeleton: Skeleton) -> Path:
    """Write SWC: samples in breadth-first order from each tree's root (the inlet), so that
    parents precede children. SWC stores trees only, and one type per sample: a node's
    ``swc_type_<n>`` tag gives its type; other tags (of the node and of the segment to its
    parent, e.g. ``branch_<k>``) get custom types from 10 up, named in ``# vmesh tag``
    comments that :func:`read_swc` reads back; untagged samples are type 0 (undefined).

    Raises
    ------
    InputError
        The skeleton has cycles.
    """
    path = Path(path)
    if skeleton.n_cycles:
        raise InputError(f"skeleton has {skeleton.n_cycles} cycle(s); SWC stores trees only (use .json or .vtp)", path)
    import scipy.sparse.csgraph as csg

    adj = skeleton.adjacency()
    label = sk_graph.component_labels(skeleton.n_nodes, skeleton.edges)
    order, parent = [], []
    for comp in np.unique(label).tolist():
        root = sk_tags.choose_root(skeleton, np.flatnonzero(label == comp))
        nodes, preds = csg.breadth_first_order(adj, root, directed=False, return_predecessors=True)
        order.extend(nodes.tolist())
        parent.extend(preds[nodes].tolist())
    new_id = np.empty(skeleton.n_nodes, np.int64)
    new_id[order] = np.arange(1, len(order) + 1)
    lines = [
        f"# vmesh skeleton {skeleton.name}".rstrip(),
        "# id type x y z radius parent",
    ]
    edge_of = {(int(a), int(b)): k for k, (a, b) in enumerate(skeleton.edges.tolist())}
    given = [_swc_type(tags) for tags in skeleton.node_tags]
    used = {t for t in given if t is not None}
    custom: dict[tuple, int] = {}
    types = []
    for i, p in zip(order, parent):
        swc_type = given[i]
        if swc_type is None:
            k = edge_of.get((p, i), edge_of.get((i, p))) if p >= 0 else None
            own = set(skeleton.node_tags[i]) | (set(skeleton.edge_tags[k]) if k is not None else set())
            key = tuple(sorted(t for t in own if not _SWC_TYPE_TAG.fullmatch(t) and t.strip() and "+" not in t))
            swc_type = 0
            if key:
                if key not in custom:
                    number = 10 + len(custom)
                    while number in used:
                        number += 1
                    used.add(number)
                    custom[key] = number
                swc_type = custom[key]
        types.append(swc_type)
    lines += [f"# vmesh tag {number} {'+'.join(key)}" for key, number in custom.items()]
    for (i, p), swc_type in zip(zip(order, parent), types):
        x, y, z = skeleton.points[i]
        r = skeleton.radii[i]
        lines.append(f"{new_id[i]} {swc_type} {x:.9g} {y:.9g} {z:.9g} {0.0 if not np.isfinite(r) else r:.9g} {new_id[p] if p >= 0 else -1}")
    return write_text_atomic(path, "\n".join(lines) + "\n")


# ---------------------------------------------------------------------------
# CSV (nodes.csv + edges.csv)
# ---------------------------------------------------------------------------


def csv_pair(path, reading: bool = False) -> tuple[Path, Path]:
    """The (nodes, edges) files of a CSV skeleton named by ``path``.

    A folder holds ``nodes.csv`` and ``edges.csv``; ``X_nodes.csv`` / ``Xnodes.csv`` pairs
    with ``X_edges.csv`` / ``Xedges.csv`` and the other way round; any other ``X.csv``
    stands for ``X_nodes.csv`` + ``X_edges.csv`` - except when reading an ``X.csv`` that
    exists: it is the node file then (edges in ``X_edges.csv`` or a parent column).
    """
    path = Path(path)
    if path.is_dir() or path.suffix == "":
        return path / "nodes.csv", path / "edges.csv"
    stem = path.stem
    for a, b in (("nodes", "edges"), ("edges", "nodes")):
        if stem.lower().endswith(a):
            other = path.with_name(stem[: len(stem) - len(a)] + (b if stem[-len(a) :].islower() else b.capitalize()) + path.suffix)
            return (path, other) if a == "nodes" else (other, path)
    if reading and path.is_file():
        return path, path.with_name(stem + "_edges.csv")
    return path.with_name(stem + "_nodes.csv"), path.with_name(stem + "_edges.csv")


def _csv_rows(path: Path) -> tuple[list[str], list[list[str]]]:
    try:
        text = path.read_text()
    except UnicodeDecodeError:
        raise InputError("not a text (CSV) file", path) from None
    rows = [r for r in csv.reader(io.StringIO(text)) if r and not r[0].lstrip().startswith("#")]
    if not rows:
        raise InputError("CSV file has no rows", path)
    header = [h.strip().lower() for h in rows[0]]
    return header, rows[1:]


def _column(header: list[str], names, path: Path, required=True) -> int | None:
    for n in names:
        if n in header:
            return header.index(n)
    if required:
        raise InputError(f"CSV header needs a column named {' or '.join(map(repr, names))} (found {', '.join(header)})", path)
    return None


def _split_tags(text: str) -> tuple:
    return tuple(t.strip() for t in re.split(r"[;|]", text or "") if t.strip())


def read_skeleton_csv(path) -> Skeleton:
    """Read a CSV skeleton: ``nodes.csv`` (``id,x,y,z[,radius][,tags]``) and ``edges.csv``
    (``source,target[,tags]``; ``;``-separated tags). ``path`` may be either file or their
    folder (see :func:`csv_pair`). Without an edges file a ``parent`` column in the node
    file gives the edges (as in SWC)."""
    nodes_path, edges_path = csv_pair(path, reading=True)
    if not nodes_path.is_file():
        raise InputError("CSV skeleton node file not found", nodes_path)
    header, rows = _csv_rows(nodes_path)
    c_id = _column(header, ("id", "node", "node_id"), nodes_path)
    cx, cy, cz = (_column(header, (k,), nodes_path) for k in ("x", "y", "z"))
    c_r = _column(header, ("radius", "r", "maximuminscribedsphereradius"), nodes_path, required=False)
    c_t = _column(header, ("tags", "tag", "labels", "label"), nodes_path, required=False)
    c_p = _column(header, ("parent", "parent_id"), nodes_path, required=False)
    ids, pts, rad, tags, parents = [], [], [], [], []
    for k, row in enumerate(rows, 2):
        try:
            ids.append(int(float(row[c_id])))
            pts.append([float(row[cx]), float(row[cy]), float(row[cz])])
            rv = row[c_r].strip() if c_r is not None and c_r < len(row) else ""
            rad.append(float(rv) if rv else np.nan)
            parents.append(int(float(row[c_p])) if c_p is not None and row[c_p].strip() else -1)
        except (ValueError, IndexError):
            raise InputError(f"line {k}: malformed node row {','.join(row)!r}", nodes_path) from None
        tags.append(_split_tags(row[c_t]) if c_t is not None and c_t < len(row) else ())
    if not ids:
        raise InputError("no nodes", nodes_path)
    index = {nid: i for i, nid in enumerate(ids)}
    if len(index) != len(ids):
        raise InputError("duplicate node ids", nodes_path)
    pts = np.asarray(pts, float)
    if not np.isfinite(pts).all():
        raise InputError("node coordinates contain NaN or infinite values", nodes_path)
    edges, etags = [], []
    if edges_path.is_file():
        eh, erows = _csv_rows(edges_path)
        ca = _column(eh, ("source", "a", "i", "node1", "from", "start"), edges_path, required=False)
        cb = _column(eh, ("target", "b", "j", "node2", "to", "end"), edges_path, required=False)
        ca, cb = (0, 1) if ca is None or cb is None else (ca, cb)
        ct = _column(eh, ("tags", "tag", "labels", "label"), edges_path, required=False)
        for k, row in enumerate(erows, 2):
            try:
                a, b = int(float(row[ca])), int(float(row[cb]))
            except (ValueError, IndexError):
                raise InputError(f"line {k}: malformed edge row {','.join(row)!r}", edges_path) from None
            if a not in index or b not in index:
                raise InputError(f"line {k}: edge ({a}, {b}) refers to a node id that does not exist", edges_path)
            edges.append((index[a], index[b]))
            etags.append(_split_tags(row[ct]) if ct is not None and ct < len(row) else ())
    elif c_p is not None:
        for i, p in enumerate(parents):
            if p >= 0:
                if p not in index:
                    raise InputError(f"parent id {p} does not exist", nodes_path)
                edges.append((index[p], i))
                etags.append(())
    else:
        raise InputError("CSV skeleton edge file not found (and the node file has no parent column)", edges_path)
    e, et = sk_graph.simplify_edges(np.asarray(edges, np.int64).reshape(-1, 2), etags)
    rad = np.asarray(rad, float)
    return Skeleton(pts, np.where(rad > 0, rad, np.nan), e, tags, et, name=nodes_path.name)


def write_skeleton_csv(path, skeleton: Skeleton) -> Path:
    """Write ``nodes.csv`` and ``edges.csv`` (names from :func:`csv_pair`); returns the node file."""
    nodes_path, edges_path = csv_pair(path)
    out = io.StringIO()
    w = csv.writer(out, lineterminator="\n")
    w.writerow(["id", "x", "y", "z", "radius", "tags"])
    for i, (p, r, t) in enumerate(zip(skeleton.points, skeleton.radii, skeleton.node_tags)):
        w.writerow([i, f"{p[0]:.9g}", f"{p[1]:.9g}", f"{p[2]:.9g}", "" if not np.isfinite(r) else f"{r:.9g}", ";".join(t)])
    eout = io.StringIO()
    we = csv.writer(eout, lineterminator="\n")
    we.writerow(["source", "target", "tags"])
    for (a, b), t in zip(skeleton.edges.tolist(), skeleton.edge_tags):
        we.writerow([a, b, ";".join(t)])
    write_text_atomic(edges_path, eout.getvalue())
    return write_text_atomic(nodes_path, out.getvalue())


# ---------------------------------------------------------------------------
# PLY edge meshes
# ---------------------------------------------------------------------------



def write_skeleton_ply(path, skeleton: Skeleton) -> Path:
    """Write an ASCII PLY edge mesh (``vertex`` x y z radius quality, ``edge`` vertex1
    vertex2) that MeshLab opens; ``quality`` repeats the radius so MeshLab can colour by it
    (unknown radii are written as 0)."""
    r = np.nan_to_num(skeleton.radii, nan=0.0)
    head = [
        "ply",
        "format ascii 1.0",
        f"comment vmesh skeleton {skeleton.name}".rstrip(),
        f"element vertex {skeleton.n_nodes}",
        "property double x",
        "property double y",
        "property double z",
        "property float radius",
        "property float quality",
        f"element edge {skeleton.n_edges}",
        "property int vertex1",
        "property int vertex2",
        "end_header",
    ]
    buf = io.StringIO()
    np.savetxt(buf, np.c_[skeleton.points, r, r], fmt="%.9g")
    np.savetxt(buf, skeleton.edges, fmt="%d")
    return write_text_atomic(path, "\n".join(head) + "\n" + buf.getvalue())


def read_skeleton_ply(path) -> Skeleton:
    """Read a PLY edge mesh (ASCII or binary): ``vertex`` (x, y, z, optional ``radius``)
    and ``edge`` (``vertex1``, ``vertex2``) elements; other elements are skipped."""
    path = Path(path)
    raw = path.read_bytes()
    try:
        fmt, elements, body_start = ply_header(raw)
    except UnsupportedPLY as exc:
        what = "not a PLY file (no 'ply' magic or no end_header)" if str(exc) == "no PLY header" else str(exc)
        raise InputError(what, path) from None
    # properties as (type, name) or ("list", count type, item type, name)
    elements = [(name, count, [("list", p[1], p[2], p[0]) if len(p) == 3 else (p[1], p[0]) for p in props])
                for name, count, props in elements]
    for _, _, props in elements:
        for p in props:
            if p[0] != "list" and p[0] not in _PLY_TYPES:
                raise InputError(f"unknown PLY property type '{p[0]}'", path)
    data = {}
    if fmt == "ascii":
        tokens = raw[body_start:].split()
        pos = 0
        for name, count, props in elements:
            if any(p[0] == "list" for p in props):
                for _ in range(count):  # list rows: their length is in the row
                    for p in props:
                        pos += 1 + int(tokens[pos]) if p[0] == "list" else 1
                continue
            width = len(props)
            chunk = tokens[pos : pos + count * width]
            if len(chunk) < count * width:
                raise InputError(f"PLY file ends inside element '{name}'", path)
            data[name] = (np.array(chunk, dtype=float).reshape(count, width), [p[1] for p in props])
            pos += count * width
    else:
        order = "<" if fmt == "binary_little_endian" else ">"
        pos = body_start
        for name, count, props in elements:
            if any(p[0] == "list" for p in props):
                for _ in range(count):
                    for p in props:
                        if p[0] == "list":
                            ct, it = np.dtype(order + _PLY_TYPES[p[1]]), np.dtype(order + _PLY_TYPES[p[2]])
                            n = int(np.frombuffer(raw, ct, 1, pos)[0])
                            pos += ct.itemsize + n * it.itemsize
                        else:
                            pos += np.dtype(_PLY_TYPES[p[0]]).itemsize
                continue
            dt = np.dtype([(p[1], order + _PLY_TYPES[p[0]]) for p in props])
            if pos + count * dt.itemsize > len(raw):
                raise InputError(f"PLY file ends inside element '{name}'", path)
            rec = np.frombuffer(raw, dt, count, pos)
            pos += count * dt.itemsize
            data[name] = (np.stack([rec[p[1]].astype(float) for p in props], axis=1) if props else np.zeros((count, 0)), [p[1] for p in props])
    if "vertex" not in data:
        raise InputError("PLY file has no vertex element", path)
    if "edge" not in data:
        raise InputError("PLY file has no edge element (a surface, not a skeleton?)", path)
    v, vnames = data["vertex"]
    e, enames = data["edge"]
    try:
        xyz = v[:, [vnames.index(c) for c in ("x", "y", "z")]]
    except ValueError:
        raise InputError("PLY vertices need x, y and z", path) from None
    rad = v[:, vnames.index("radius")] if "radius" in vnames else np.full(len(v), np.nan)
    cols = [enames.index(c) for c in ("vertex1", "vertex2")] if {"vertex1", "vertex2"} <= set(enames) else [0, 1]
    edges = e[:, cols].astype(np.int64)
    if len(edges) and (edges.min() < 0 or edges.max() >= len(xyz)):
        raise InputError("edge vertex indices are out of range", path)
    edges, _ = sk_graph.simplify_edges(edges)
    return Skeleton(xyz, np.where(rad > 0, rad, np.nan), edges, name=path.name)


# duplicates: the READERS and WRITERS tables below share their shape: they are data
#: Readers and writers added to :mod:`vmesh.io.skeleton`'s suffix tables.
READERS = {
    ".vtp": ("VTK PolyData centerline (VMTK, SimVascular or polylines)", read_centerline_vtk),
    ".vtk": ("legacy VTK centerline (VMTK, SimVascular or polylines)", read_centerline_vtk),
    ".swc": ("SWC", read_swc),
    ".csv": ("CSV nodes + edges", read_skeleton_csv),
    ".ply": ("PLY edge mesh", read_skeleton_ply),
}
WRITERS = {
    ".vtp": ("VTK PolyData polylines", write_skeleton_vtk),
    ".vtk": ("legacy VTK polylines", write_skeleton_vtk),
    ".swc": ("SWC", write_swc),
    ".csv": ("CSV nodes + edges", write_skeleton_csv),
    ".ply": ("PLY edge mesh", write_skeleton_ply),
}
