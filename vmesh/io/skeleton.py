"""Read and write skeletons (centerline graphs).

Formats: vmesh JSON (node-edge) here; VTK (VMTK, SimVascular, polylines), SWC, CSV and
PLY in :mod:`vmesh.io.skeleton_formats`. Readers and writers are registered by suffix
in :data:`SKELETON_READERS` and :data:`SKELETON_WRITERS`.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..skeleton import Skeleton
from .atomic import write_text_atomic
from .surface import check_input_file


def read_skeleton_json(path: Path) -> Skeleton:
    """Read the vmesh node-edge JSON format::

        {"nodes": [{"id": 0, "xyz": [x, y, z], "radius": r, "tags": ["..."]}, ...],
         "edges": [[i, j], ...]}
    """
    try:
        data = json.loads(Path(path).read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"not valid JSON ({exc})", path) from None
    if not isinstance(data, dict) or "nodes" not in data or "edges" not in data:
        raise InputError("skeleton JSON needs top-level 'nodes' and 'edges'", path)
    try:
        nodes = data["nodes"]
        ids = [int(n["id"]) for n in nodes]
        index = {nid: k for k, nid in enumerate(ids)}
        if len(index) != len(ids):
            raise InputError("duplicate node ids", path)
        pts = np.array([n["xyz"] for n in nodes], float).reshape(-1, 3)
        rad = np.array([n.get("radius", np.nan) if n.get("radius") is not None else np.nan for n in nodes], float)
        tags = [tuple(n.get("tags", ()) or ()) for n in nodes]
        raw_edges = data["edges"]
        listed_tags = data.get("edge_tags")  # written by skeleton_to_json next to plain edges
        if listed_tags is not None and len(listed_tags) != len(raw_edges):
            raise InputError("'edge_tags' must have one entry per edge", path)
        edges, etags = [], []
        for e in raw_edges:
            if isinstance(e, dict):
                a, b = e["nodes"] if "nodes" in e else (e["source"], e["target"])
                etags.append(tuple(e.get("tags", ()) or ()))
            else:
                a, b = e[:2]
                etags.append(tuple(listed_tags[len(edges)] or ()) if listed_tags is not None else ())
            if a not in index or b not in index:
                raise InputError(f"edge [{a}, {b}] refers to a node id that does not exist", path)
            edges.append((index[a], index[b]))
    except InputError:
        raise
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(f"malformed skeleton JSON ({type(exc).__name__}: {exc})", path) from None
    if len(pts) == 0:
        raise InputError("skeleton has no nodes", path)
    if not np.all(np.isfinite(pts)):
        raise InputError("node coordinates contain NaN or infinite values", path)
    return Skeleton(pts, rad, np.array(edges, np.int64).reshape(-1, 2), tags, etags, name=Path(path).name)


def skeleton_to_json(skeleton: Skeleton) -> str:
    nodes = [
        {"id": i, "xyz": [round(float(x), 9) for x in p], "radius": None if np.isnan(r) else round(float(r), 9), "tags": list(t)}
        for i, (p, r, t) in enumerate(zip(skeleton.points, skeleton.radii, skeleton.node_tags))
    ]
    edges = [[int(a), int(b)] for a, b in skeleton.edges]
    data = {"name": skeleton.name, "units": "mm", "nodes": nodes, "edges": edges}
    if any(skeleton.edge_tags):
        data["edge_tags"] = [list(t) for t in skeleton.edge_tags]
    return json.dumps(data, indent=1)


def write_skeleton_json(path, skeleton: Skeleton) -> Path:
    return write_text_atomic(path, skeleton_to_json(skeleton))


#: suffix -> (format name, reader). Other modules add readers here.
SKELETON_READERS = {".json": ("vmesh JSON", read_skeleton_json)}
SKELETON_WRITERS = {".json": ("vmesh JSON", write_skeleton_json)}

from . import skeleton_formats as _formats  # noqa: E402  (registers VTK, SWC, CSV, PLY)

SKELETON_READERS.update(_formats.READERS)
SKELETON_WRITERS.update(_formats.WRITERS)


def read_skeleton(path, **options) -> Skeleton:
    """Read a skeleton file; the format follows the extension.

    A folder holding ``nodes.csv`` and ``edges.csv`` is read as a CSV skeleton. Segments
    without tags in the file get the tags both their end nodes carry. ``options`` go to
    the format's reader (``kind=`` and ``merge_tolerance=`` for VTK centerlines).
    """
    p = Path(path)
    if p.is_dir():
        nodes, _ = _formats.csv_pair(p, reading=True)
        if not nodes.is_file():
            raise InputError("is a folder without nodes.csv, expected a skeleton file", p)
        path = nodes
    elif p.suffix.lower() == ".csv" and not p.exists() and _formats.csv_pair(p)[0].is_file():
        path = _formats.csv_pair(p)[0]  # "x.csv" as written: x_nodes.csv + x_edges.csv
    formats = {k: v[0] for k, v in SKELETON_READERS.items()}
    path = check_input_file(path, formats, "skeleton")
    name, reader = SKELETON_READERS[path.suffix.lower()]
    try:
        skeleton = reader(path, **options)
    except InputError:
        raise
    except Exception as exc:
        raise InputError(f"could not read as {name}: {' '.join(str(exc).split())[:200]}", path) from None
    if skeleton.n_nodes == 0:
        raise InputError("skeleton has no nodes", path)
    if not any(skeleton.edge_tags):
        from ..geometry.skeleton.tags import derive_edge_tags

        skeleton.edge_tags = derive_edge_tags(skeleton)
    return skeleton


def write_skeleton(path, skeleton: Skeleton) -> Path:
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in SKELETON_WRITERS:
        raise InputError(f"unknown skeleton format '{path.suffix}' (supported: {', '.join(sorted(SKELETON_WRITERS))})", path)
    return SKELETON_WRITERS[suffix][1](path, skeleton)
