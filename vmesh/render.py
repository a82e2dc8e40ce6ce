"""Pictures of every stage of a run (off-screen pyvista) and a one-page HTML report.

:func:`render_run` reads a finished run folder and writes, into ``OUT/pictures/``:
``surface.png`` (input surface), ``skeleton.png``, ``blocks.png`` (block structure),
``mesh.png`` (mesh boundary coloured by wall/inlet/outlets), ``mesh_clip.png`` (elements on
one side of a mid plane, coloured by core/ring/boundary layer, showing the graded boundary
layer), ``labels.png`` (boundary coloured by element label) and ``quality.png`` (histogram of
scaled Jacobians); then ``OUT/report.html`` shows them with report.json's tables.

Rendering needs no display: VTK falls back to EGL or OSMesa off screen.
"""

from __future__ import annotations

import html
import json
from pathlib import Path

import numpy as np

from .errors import InputError, stop_behind
from .io.atomic import atomic_path, replace_dir, write_text_atomic

#: Pictures in the order the HTML page shows them, with their captions.
PICTURES = {
    "surface": "Input surface (after repair and capping)",
    "skeleton": "Skeleton over the surface: radius colour, junctions red, endpoints blue",
    "blocks": "Block structure: blocks coloured by skeleton segment, block edges black",
    "mesh": "Hexahedral mesh boundary: wall and each inlet/outlet",
    "mesh_clip": "Clipped mesh: core, ring and graded boundary-layer elements",
    "labels": "Element labels (skeleton tags) on the boundary",
    "quality": "Scaled Jacobian histogram",
}

LAYER_NAMES = {0: "core", 1: "ring", 2: "boundary layer"}


def _setup():
    import pyvista as pv

    pv.OFF_SCREEN = True
    try:  # VTK first tries an X display, then EGL/OSMesa: the failed attempt is no error
        import vtk

        vtk.vtkLogger.SetStderrVerbosity(vtk.vtkLogger.VERBOSITY_OFF)
        vtk.vtkObject.GlobalWarningDisplayOff()
    except (ImportError, AttributeError) as exc:
        stop = stop_behind(exc)  # a signal during the import is a stop, not a missing module
        if stop is not None:
            raise stop from None
    return pv


def view_frame(points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """Centre, viewing direction (least principal axis), up vector and extent of ``points``,
    so that flat trees are seen face-on."""
    centre = points.mean(axis=0)
    if len(points) >= 3:
        _, _, vt = np.linalg.svd(points - centre, full_matrices=False)
        view, up = vt[2], vt[1]
    else:
        view, up = np.array([0, 0, 1.0]), np.array([0, 1.0, 0])
    return centre, view, up, float(np.ptp(points, axis=0).max()) or 1.0


def oblique_frame(frame, points: np.ndarray):
    """``frame`` turned 35 degrees towards the longest axis, so that end caps show."""
    centre, view, up, extent = frame
    _, _, vt = np.linalg.svd(points - centre, full_matrices=False)
    v = np.cos(np.radians(35)) * view + np.sin(np.radians(35)) * vt[0]
    return centre, v / np.linalg.norm(v), up, extent


class _Shot:
    """An off-screen plotter that saves one PNG atomically and is closed whatever happens."""

    def __init__(self, path, size, frame, title=""):
        pv = _setup()
        self.path, self.frame = Path(path), frame
        self.plotter = pv.Plotter(off_screen=True, window_size=list(size))
        self.plotter.set_background("white")
        if title:
            self.plotter.add_text(title, font_size=10, color="black")

    def __enter__(self):
        return self.plotter

    def __exit__(self, exc_type, exc, tb):
        try:
            if exc_type is None:
                centre, view, up, extent = self.frame
                self.plotter.camera_position = [tuple(centre + 3 * extent * view), tuple(centre), tuple(up)]
                self.plotter.reset_camera()
                self.plotter.camera.zoom(1.1)
                with atomic_path(self.path) as tmp:
                    self.plotter.screenshot(str(tmp))
        finally:
            self.plotter.close()
        return False


def _boundary_polydata(mesh):
    import pyvista as pv

    from .io.meshlab import boundary_quads

    verts, quads, owner = boundary_quads(mesh)
    poly = pv.PolyData(verts, np.c_[np.full(len(quads), 4), quads].ravel())
    cell = np.asarray(mesh.boundary_cells)[owner]
    poly.cell_data["boundary_id"] = np.asarray(mesh.boundary_ids)[owner]
    for k in ("label", "scaled_jacobian", "layer"):
        if k in mesh.cell_data:
            poly.cell_data[k] = np.asarray(mesh.cell_data[k])[cell]
    return poly


def _linear_grid(mesh, mask=None):
    import pyvista as pv

    cells = mesh.corner_cells() if mask is None else mesh.corner_cells()[mask]
    grid = pv.UnstructuredGrid(np.c_[np.full(len(cells), 8), cells].ravel(), np.full(len(cells), 12, np.uint8), mesh.points)
    for k, v in mesh.cell_data.items():
        grid.cell_data[k] = np.asarray(v) if mask is None else np.asarray(v)[mask]
    return grid


def _categorical(plotter, mesh, scalars, names: dict, **kw):
    """Add ``mesh`` coloured by integer ``scalars`` with a legend of ``names``."""
    from .io.meshlab import label_colors

    ids = sorted(names)
    values = np.asarray(mesh.cell_data[scalars])
    colors = label_colors(values)[:, :3]
    mesh = mesh.copy()
    mesh.cell_data["rgb"] = colors
    plotter.add_mesh(mesh, scalars="rgb", rgb=True, **kw)
    legend = [[str(names[i]), tuple(int(c) / 255 for c in label_colors(np.array([i]))[0, :3])] for i in ids]
    if legend:
        width = min(0.5, 0.08 + 0.022 * max(len(n) for n, _ in legend))
        plotter.add_legend(legend, bcolor="white", size=(width, 0.035 * min(len(legend), 10) + 0.01), face="rectangle", loc="lower left")


def _blocks_grid(blocks):
    """A chain's ``ctx.blocks`` (a BlockStructure) as the grid the pictures draw; a grid
    (``blocks.vtu`` read with pyvista) or None as given."""
    from .blocks import BlockStructure

    return blocks.to_pyvista() if isinstance(blocks, BlockStructure) else blocks


def render_pictures(out_dir, mesh, surface=None, skeleton=None, blocks=None, report=None, size=(1000, 750),
                    name: str = "") -> dict:
    """Render the run's pictures into ``out_dir`` (PNG files, each written atomically).

    Parameters
    ----------
    mesh : HexMesh
    surface : SurfaceMesh, optional
    skeleton : Skeleton, optional
    blocks : BlockStructure or pyvista.UnstructuredGrid, optional
        The block structure (``ctx.blocks``, or ``blocks.vtu`` read with pyvista).
    report : dict, optional
        ``report.json``'s content (for titles).

    Returns
    -------
    dict
        ``{picture name: path}`` of what was written.
    """
    from .plots import quality_histogram

    _setup()
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    report = report or {}
    pts = surface.vertices if surface is not None and surface.n_vertices else mesh.points
    frame = view_frame(pts)
    title = name or report.get("inputs", {}).get("surface", "")
    title = Path(title).name if title else ""
    done: dict = {}
    surf_pv = surface.to_pyvista() if surface is not None else None

    if surf_pv is not None:
        with _Shot(out_dir / "surface.png", size, frame, f"{title}: {surface.n_faces} triangles") as p:
            p.add_mesh(surf_pv, color="#d8b8a8", smooth_shading=True, specular=0.3)
        done["surface"] = out_dir / "surface.png"
    if skeleton is not None:
        from .filters.skeleton_filters import render_skeleton_png

        render_skeleton_png(out_dir / "skeleton.png", skeleton, surface, size, 0.2, title=title)
        done["skeleton"] = out_dir / "skeleton.png"
    blocks = _blocks_grid(blocks)
    if blocks is not None:
        with _Shot(out_dir / "blocks.png", size, frame, f"{blocks.n_cells} blocks") as p:
            if surf_pv is not None:
                p.add_mesh(surf_pv, color="#d8c8c0", opacity=0.15)
            shell = blocks.extract_surface(algorithm="dataset_surface")
            p.add_mesh(shell, scalars="segment_id" if "segment_id" in shell.cell_data else None, cmap="tab20",
                       opacity=0.45, show_scalar_bar=False)
            p.add_mesh(blocks.extract_all_edges(), color="black", line_width=1.5)
        done["blocks"] = out_dir / "blocks.png"

    boundary = _boundary_polydata(mesh)
    oblique = oblique_frame(frame, pts)
    counts = f"{mesh.n_cells} elements, {mesh.n_points} nodes, p = {mesh.order}"
    bnames = {int(k): v for k, v in mesh.boundary_names.items() if int(k) in set(np.unique(mesh.boundary_ids).tolist())}
    with _Shot(out_dir / "mesh.png", size, oblique, f"{title}: {counts}") as p:
        _categorical(p, boundary, "boundary_id", bnames, show_edges=True, edge_color="#303030", line_width=0.5)
    done["mesh"] = out_dir / "mesh.png"

    # elements behind the mid plane facing the camera: the cut shows the radial grading
    centre, view, up, extent = frame
    cc = mesh.points[mesh.corner_cells()].mean(axis=1)
    keep = (cc - centre) @ view <= 0
    grid = _linear_grid(mesh, keep)
    with _Shot(out_dir / "mesh_clip.png", size, frame, f"clipped at the mid plane: {int(keep.sum())} of {mesh.n_cells} elements") as p:
        if "layer" in grid.cell_data:
            names = {int(k): LAYER_NAMES.get(int(k), f"layer {k}") for k in np.unique(grid.cell_data["layer"])}
            _categorical(p, grid, "layer", names, show_edges=True, edge_color="#202020", line_width=0.5)
        else:
            p.add_mesh(grid, color="#c0c0d0", show_edges=True)
    done["mesh_clip"] = out_dir / "mesh_clip.png"

    if "label" in boundary.cell_data:
        lnames = {int(k): v for k, v in mesh.label_names.items()} or {int(k): f"label {k}" for k in np.unique(boundary.cell_data["label"])}
        present = set(np.unique(mesh.cell_data["label"]).tolist())
        with _Shot(out_dir / "labels.png", size, oblique, f"{len(present)} label" + ("s" if len(present) != 1 else "")) as p:
            _categorical(p, boundary, "label", {k: v for k, v in lnames.items() if k in present}, show_edges=False, smooth_shading=False)
        done["labels"] = out_dir / "labels.png"
    if "scaled_jacobian" in mesh.cell_data:
        quality_histogram(np.asarray(mesh.cell_data["scaled_jacobian"]), out_dir / "quality.png",
                          title=f"{title}: {counts}")
        done["quality"] = out_dir / "quality.png"
    return {k: done[k] for k in PICTURES if k in done}


def _table(rows, head=None) -> str:
    out = ["<table>"]
    if head:
        out.append("<tr>" + "".join(f"<th>{html.escape(str(h))}</th>" for h in head) + "</tr>")
    for r in rows:
        out.append("<tr>" + "".join(f"<td>{html.escape(_fmt(c))}</td>" for c in r) + "</tr>")
    out.append("</table>")
    return "\n".join(out)


def _fmt(v) -> str:
    if isinstance(v, float):
        return f"{v:.4g}"
    if isinstance(v, (dict, list)):
        return json.dumps(v)
    return str(v)


def html_report(path, report: dict, pictures: dict, title: str = "vmesh run") -> Path:
    """Write a one-page HTML report: the pictures (relative links) and report.json's tables."""
    path = Path(path)
    parts = [
        "<!DOCTYPE html>",
        "<html><head><meta charset='utf-8'>",
        f"<title>{html.escape(title)}</title>",
        "<style>body{font-family:sans-serif;margin:1.5em;max-width:1400px}"
        "table{border-collapse:collapse;margin:0.5em 0 1.5em}td,th{border:1px solid #ccc;padding:2px 8px;font-size:13px;text-align:left}"
        "th{background:#eee}figure{display:inline-block;margin:0.5em;width:45%;vertical-align:top}"
        "figure img{width:100%;border:1px solid #ddd}figcaption{font-size:13px;color:#444}</style>",
        "</head><body>",
        f"<h1>{html.escape(title)}</h1>",
    ]
    inputs = report.get("inputs", {})
    if inputs:
        parts += ["<h2>Inputs</h2>", _table(inputs.items())]
    parts.append("<h2>Pictures</h2>")
    for name, p in pictures.items():
        rel = Path(p).relative_to(path.parent) if Path(p).is_relative_to(path.parent) else Path(p)
        parts.append(f"<figure><a href='{html.escape(rel.as_posix())}'><img src='{html.escape(rel.as_posix())}' alt='{name}'></a>"
                     f"<figcaption>{html.escape(PICTURES.get(name, name))}</figcaption></figure>")
    if report.get("counts"):
        parts += ["<h2>Counts</h2>", _table(report["counts"].items(), ("what", "count"))]
    sj = report.get("quality", {}).get("scaled_jacobian")
    if sj:
        parts += ["<h2>Quality (scaled Jacobian)</h2>", _table(sj.items(), ("statistic", "value"))]
    if report.get("boundary_distance"):
        parts += ["<h2>Distance of the mesh boundary to the surface</h2>", _table(report["boundary_distance"].items(), ("measure", "value"))]
    labels = report.get("labels", {})
    if labels.get("elements"):
        parts += ["<h2>Elements per label</h2>", _table(labels["elements"].items(), ("label", "elements"))]
    if labels.get("boundary_faces"):
        parts += ["<h2>Boundary faces</h2>", _table(labels["boundary_faces"].items(), ("boundary", "faces"))]
    steps = report.get("steps", [])
    if steps:
        rows = [(s["filter"], s["seconds"], s.get("peak_memory_mb", ""), ", ".join(f"{k}={_fmt(v)}" for k, v in s.get("counts", {}).items())) for s in steps]
        rows.append(("total", report.get("total_s", ""), "", ""))
        parts += ["<h2>Filters</h2>", _table(rows, ("filter", "seconds", "peak MB", "results"))]
    if report.get("warnings"):
        parts += ["<h2>Warnings</h2>", "<ul>" + "".join(f"<li>{html.escape(w)}</li>" for w in report["warnings"]) + "</ul>"]
    parts.append("</body></html>\n")
    return write_text_atomic(path, "\n".join(parts))


def render_run(run_dir, out_dir=None, size=(1000, 750), html: bool = True) -> dict:
    """Render a finished run folder: pictures in ``OUT/pictures/`` and ``OUT/report.html``
    (``OUT`` defaults to the run folder).

    Returns
    -------
    dict
        ``{picture name: path}``, plus ``"html"`` when the page was written.
    """
    import pyvista as pv

    from .io.run_folder import check_run_dir, read_report, read_run_mesh, run_surface_path
    from .io.skeleton import read_skeleton
    from .io.surface import read_surface

    run_dir = check_run_dir(run_dir)
    out_dir = Path(out_dir) if out_dir is not None else run_dir
    if out_dir.exists() and not out_dir.is_dir():
        raise InputError("is not a folder", out_dir)
    mesh = read_run_mesh(run_dir)
    sp = run_surface_path(run_dir, "surface")
    surface = read_surface(sp) if sp is not None else None
    skeleton = read_skeleton(run_dir / "skeleton.json") if (run_dir / "skeleton.json").is_file() else None
    blocks = pv.read(str(run_dir / "blocks.vtu")) if (run_dir / "blocks.vtu").is_file() else None
    report = read_report(run_dir)
    # render into a staging folder and swap it in: a failure leaves the old pictures, not half of new ones
    import shutil
    import tempfile

    out_dir.mkdir(parents=True, exist_ok=True)
    final = out_dir / "pictures"
    stage = Path(tempfile.mkdtemp(prefix=".pictures.", dir=out_dir))
    try:
        staged = render_pictures(stage, mesh, surface, skeleton, blocks, report, size=size)
        replace_dir(stage, final)
    finally:
        if stage.exists():
            shutil.rmtree(stage, ignore_errors=True)
    pictures = {name: final / path.name for name, path in staged.items()}
    if html:
        name = Path(report.get("inputs", {}).get("surface", run_dir.name)).name
        pictures["html"] = html_report(out_dir / "report.html", report, dict(pictures), title=f"vmesh: {name}")
    return pictures
