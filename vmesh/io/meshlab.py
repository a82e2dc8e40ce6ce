"""MeshLab export: coloured quad PLY surfaces, PLY edge meshes and a ``.mlp`` project.

:func:`write_meshlab_folder` writes, into one folder (atomically, as a whole):

- ``surface.ply``, ``coarse_surface.ply``: the (preprocessed) input and coarse surfaces;
- ``boundary_label.ply``: the mesh boundary as quads (p > 1: p x p sub-quads per face)
  coloured by element label, with the boundary id as face quality;
- ``boundary_quality.ply``: the same quads coloured by the owning element's scaled
  Jacobian, which is also the face quality (MeshLab's *Quality Mapper* reads it);
- ``skeleton.ply``, ``blocks_edges.ply``: edge meshes of the skeleton and the block edges;
- ``vmesh.mlp``: a MeshLab project opening all of them as layers.
"""

from __future__ import annotations

import shutil
from pathlib import Path
from xml.sax.saxutils import quoteattr

import numpy as np

from .atomic import atomic_path

#: Label colours (Tableau 10, then repeated darker), RGB.
PALETTE = np.array(
    [[31, 119, 180], [255, 127, 14], [44, 160, 44], [214, 39, 40], [148, 103, 189],
     [140, 86, 75], [227, 119, 194], [127, 127, 127], [188, 189, 34], [23, 190, 207]], np.uint8
)


def label_colors(labels: np.ndarray) -> np.ndarray:
    """(n, 4) RGBA colours of integer labels (a fixed categorical palette)."""
    labels = np.asarray(labels, np.int64)
    rgb = PALETTE[labels % len(PALETTE)]
    dark = (labels // len(PALETTE)) % 2 == 1  # a second round of the palette, darker
    rgb = np.where(dark[:, None], (rgb * 0.6).astype(np.uint8), rgb)
    return np.c_[rgb, np.full(len(labels), 255, np.uint8)]


#: ColorBrewer's RdYlGn, the anchors of matplotlib's colour map of that name
_RDYLGN = np.array([(165, 0, 38), (215, 48, 39), (244, 109, 67), (253, 174, 97), (254, 224, 139), (255, 255, 191),
                    (217, 239, 139), (166, 217, 106), (102, 189, 99), (26, 152, 80), (0, 104, 55)]) / 255.0


def quality_colors(values: np.ndarray, vmin: float = 0.0, vmax: float = 1.0, cmap: str = "RdYlGn") -> np.ndarray:
    """(n, 4) RGBA colours of values through a matplotlib colour map (red bad, green good).

    RdYlGn, the default, is matplotlib's 256-colour table rebuilt from its anchors, without
    importing matplotlib (~0.3 s of a run); other maps come from matplotlib."""
    t = np.clip((np.asarray(values, float) - vmin) / max(vmax - vmin, 1e-300), 0, 1)
    if cmap != "RdYlGn":
        from matplotlib import colormaps

        return (colormaps[cmap](t) * 255).round().astype(np.uint8)
    anchors = np.linspace(0.0, 1.0, len(_RDYLGN))
    lut = np.stack([np.interp(np.linspace(0.0, 1.0, 256), anchors, _RDYLGN[:, c]) for c in range(3)], axis=1)
    rgb = (lut[np.minimum((t * 256).astype(np.int64), 255)] * 255).round().astype(np.uint8)
    return np.c_[rgb, np.full(len(rgb), 255, np.uint8)]


def write_face_ply(path, vertices: np.ndarray, faces: np.ndarray, colors: np.ndarray | None = None,
                   quality: np.ndarray | None = None, comment: str = "vmesh") -> Path:
    """Write a binary PLY of polygons of one size (quads) with per-face colour and quality.

    Parameters
    ----------
    vertices : (n, 3) float
    faces : (m, k) int
        Vertex ids of each face (k = 4 for quads).
    colors : (m, 4) uint8, optional
        ``red green blue alpha`` face properties.
    quality : (m,) float, optional
        ``quality`` face property (MeshLab's per-face quality).
    """
    vertices = np.asarray(vertices, np.float64).reshape(-1, 3)
    faces = np.asarray(faces, np.int64)
    k = faces.shape[1]
    fields = [("n", "u1"), ("v", "<i4", (k,))]
    props = ["property list uchar int vertex_indices"]
    if colors is not None:
        fields += [(c, "u1") for c in ("red", "green", "blue", "alpha")]
        props += [f"property uchar {c}" for c in ("red", "green", "blue", "alpha")]
    if quality is not None:
        fields += [("quality", "<f4")]
        props += ["property float quality"]
    f = np.empty(len(faces), np.dtype(fields))
    f["n"], f["v"] = k, faces
    if colors is not None:
        for i, c in enumerate(("red", "green", "blue", "alpha")):
            f[c] = colors[:, i]
    if quality is not None:
        f["quality"] = quality
    return _write_binary_ply(path, comment, vertices, "face", f, props)


def write_edge_ply(path, vertices: np.ndarray, edges: np.ndarray, comment: str = "vmesh edges", edge_data: dict | None = None) -> Path:
    """Write a binary PLY edge mesh (``element edge``, read by MeshLab): float32 x, y, z
    per vertex, int32 ``vertex1``, ``vertex2`` per edge, then one int32 property per entry
    of ``edge_data`` (name -> (ne,) integers). The one edge-mesh writer (skeleton and block
    edges of the MeshLab folder, ``write_blocks``' edges file)."""
    vertices = np.asarray(vertices, np.float64).reshape(-1, 3)
    edges = np.asarray(edges, np.int64).reshape(-1, 2)
    edge_data = edge_data or {}
    e = np.empty(len(edges), np.dtype([("vertex1", "<i4"), ("vertex2", "<i4")] + [(k, "<i4") for k in edge_data]))
    e["vertex1"], e["vertex2"] = edges.T
    for k, val in edge_data.items():
        e[k] = np.asarray(val).astype(np.int32)
    props = ["property int vertex1", "property int vertex2"] + [f"property int {k}" for k in edge_data]
    return _write_binary_ply(path, comment, vertices, "edge", e, props)


def _write_binary_ply(path, comment: str, vertices: np.ndarray, element: str, rows: np.ndarray, props: list[str]) -> Path:
    """Write a little-endian binary PLY: float32 vertices, then ``rows`` (a structured
    array) as ``element`` with the ``props`` header lines, atomically."""
    header = ["ply", "format binary_little_endian 1.0", f"comment {comment}", f"element vertex {len(vertices)}",
              "property float x", "property float y", "property float z", f"element {element} {len(rows)}", *props, "end_header"]
    path = Path(path)
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        fh.write(("\n".join(header) + "\n").encode("ascii"))
        fh.write(np.asarray(vertices, np.float64).astype("<f4").tobytes())
        fh.write(rows.tobytes())
    return path


def boundary_quads(mesh) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The mesh boundary as linear quads: (compacted vertices, quads, boundary face of each quad).

    A face of order p is split into its p x p sub-quads so that curved faces keep their shape.
    """
    p = mesh.order
    n = p + 1
    a, b = np.meshgrid(np.arange(p), np.arange(p), indexing="xy")
    a, b = a.ravel(), b.ravel()
    sub = np.stack([a + n * b, a + 1 + n * b, a + 1 + n * (b + 1), a + n * (b + 1)], axis=1)  # outward loops
    quads = np.asarray(mesh.boundary_faces)[:, sub].reshape(-1, 4)
    owner = np.repeat(np.arange(len(mesh.boundary_faces)), p * p)
    used, inverse = np.unique(quads, return_inverse=True)
    return mesh.points[used], inverse.reshape(quads.shape), owner


def write_mlp(path, layers: list[tuple[str, str, bool]]) -> Path:
    """Write a MeshLab project with ``layers`` = ``[(label, file name relative to the project, visible)]``."""
    identity = "1 0 0 0 \n0 1 0 0 \n0 0 1 0 \n0 0 0 1 \n"
    lines = ["<!DOCTYPE MeshLabDocument>", "<MeshLabProject>", " <MeshGroup>"]
    for label, filename, visible in layers:
        lines.append(f"  <MLMesh label={quoteattr(label)} filename={quoteattr(filename)} idInFile=\"-1\" visible=\"{int(visible)}\">")
        lines.append(f"   <MLMatrix44>\n{identity}</MLMatrix44>")
        lines.append("  </MLMesh>")
    lines += [" </MeshGroup>", " <RasterGroup/>", "</MeshLabProject>", ""]
    path = Path(path)
    with atomic_path(path) as tmp:
        tmp.write_text("\n".join(lines))
    return path


def write_meshlab_folder(folder, mesh, surface=None, coarse_surface=None, skeleton=None, block_edges=None,
                         project: str = "vmesh.mlp") -> dict:
    """Write the MeshLab layers and project into ``folder`` (replaced as a whole, atomically).

    Parameters
    ----------
    mesh : HexMesh
    surface, coarse_surface : SurfaceMesh, optional
    skeleton : Skeleton, optional
    block_edges : (vertices, edges) tuple or path of an existing edge PLY, optional

    Returns
    -------
    dict
        ``{layer label: {"file", "vertices", "faces" or "edges"}}``, what was written.
    """
    from .surface import write_surface

    folder = Path(folder)
    written: dict = {}
    with atomic_path(folder, folder=True) as tmp:
        tmp.unlink()
        tmp.mkdir()
        for label, s in (("surface", surface), ("coarse_surface", coarse_surface)):
            if s is not None:
                write_surface(tmp / f"{label}.ply", s)
                written[label] = {"file": f"{label}.ply", "vertices": int(s.n_vertices), "faces": int(s.n_faces)}
        verts, quads, owner = boundary_quads(mesh)
        cell = np.asarray(mesh.boundary_cells)[owner]
        labels = np.asarray(mesh.cell_data.get("label", np.zeros(mesh.n_cells, np.int64)))[cell]
        bid = np.asarray(mesh.boundary_ids)[owner].astype(np.float32)
        write_face_ply(tmp / "boundary_label.ply", verts, quads, label_colors(labels), bid, comment="vmesh boundary by label; quality = boundary id")
        written["boundary_label"] = {"file": "boundary_label.ply", "vertices": len(verts), "quads": len(quads)}
        if "scaled_jacobian" in mesh.cell_data:
            sj = np.asarray(mesh.cell_data["scaled_jacobian"], float)[cell]
            write_face_ply(tmp / "boundary_quality.ply", verts, quads, quality_colors(sj), sj, comment="vmesh boundary by scaled Jacobian; quality = scaled Jacobian")
            written["boundary_quality"] = {"file": "boundary_quality.ply", "vertices": len(verts), "quads": len(quads)}
        if skeleton is not None and skeleton.n_nodes:
            write_edge_ply(tmp / "skeleton.ply", skeleton.points, skeleton.edges, comment="vmesh skeleton")
            written["skeleton"] = {"file": "skeleton.ply", "vertices": int(skeleton.n_nodes), "edges": int(skeleton.n_edges)}
        if block_edges is not None:
            if isinstance(block_edges, (str, Path)):
                shutil.copyfile(block_edges, tmp / "blocks_edges.ply")
                written["blocks_edges"] = {"file": "blocks_edges.ply"}
            else:
                v, e = block_edges
                write_edge_ply(tmp / "blocks_edges.ply", v, e, comment="vmesh block edges")
                written["blocks_edges"] = {"file": "blocks_edges.ply", "vertices": len(v), "edges": len(e)}
        # the input surface hidden: it hides the mesh boundary it coincides with
        layers = [(k, w["file"], k not in ("surface", "coarse_surface", "boundary_quality")) for k, w in written.items()]
        write_mlp(tmp / project, layers)
        written["project"] = {"file": project, "layers": len(layers)}
    return written
