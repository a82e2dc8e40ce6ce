"""Small generated hostile inputs: a straight tube (radius 3, length 40, open ends) with
the defects of real files, each written to a file of the format that carries them.

Each maker takes a folder and returns ``(surface path, skeleton path or None)``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

RADIUS, LENGTH = 3.0, 40.0


def tube(n_around: int = 40, n_along: int = 60, radius: float = RADIUS, length: float = LENGTH, quads: bool = False):
    """An open tube along x: ``(vertices, faces)`` with outward triangles (or quads)."""
    t = np.linspace(0.0, 2 * np.pi, n_around, endpoint=False)
    x = np.linspace(0.0, length, n_along)
    X, T = np.meshgrid(x, t, indexing="ij")
    v = np.column_stack([X.ravel(), radius * np.cos(T).ravel(), radius * np.sin(T).ravel()])
    i, j = np.meshgrid(np.arange(n_along - 1), np.arange(n_around), indexing="ij")
    i, j = i.ravel(), j.ravel()
    a = i * n_around + j
    b = i * n_around + (j + 1) % n_around
    c = (i + 1) * n_around + (j + 1) % n_around
    d = (i + 1) * n_around + j
    if quads:
        return v, np.column_stack([a, b, c, d])
    return v, np.concatenate([np.column_stack([a, b, c]), np.column_stack([a, c, d])])


def tube_skeleton(path: Path, scale: float = 1.0, length: float = LENGTH, radius: float = RADIUS) -> Path:
    """The tube's centerline as a vmesh JSON skeleton (nodes one radius apart)."""
    from vmesh.io.skeleton import write_skeleton
    from vmesh.skeleton import Skeleton

    n = int(length / radius) + 1
    pts = np.column_stack([np.linspace(0, length, n), np.zeros(n), np.zeros(n)]) * scale
    skel = Skeleton(pts, np.full(n, radius * scale), np.column_stack([np.arange(n - 1), np.arange(1, n)]))
    return write_skeleton(path, skel)


def _poly(vertices, faces, lines=None, verts=None):
    import pyvista as pv

    faces = np.asarray(faces, np.int64)
    cells = np.column_stack([np.full(len(faces), faces.shape[1]), faces]).ravel()
    kw = {}
    if lines is not None:
        kw["lines"] = np.column_stack([np.full(len(lines), 2), lines]).ravel()
    if verts is not None:
        kw["verts"] = np.column_stack([np.ones(len(verts), np.int64), verts]).ravel()
    return pv.PolyData(np.asarray(vertices, float), faces=cells, **kw)


def _write_ply(path: Path, vertices, faces) -> Path:
    """ASCII PLY written by hand: keeps NaN, duplicates and degenerate faces as they are."""
    lines = ["ply", "format ascii 1.0", f"element vertex {len(vertices)}", "property float x", "property float y", "property float z",
             f"element face {len(faces)}", "property list uchar int vertex_indices", "end_header"]
    lines += [" ".join(repr(float(c)) for c in p) for p in vertices]
    lines += [" ".join(map(str, [len(f), *f])) for f in faces]
    path.write_text("\n".join(lines) + "\n")
    return path


def stray_cells(d: Path):
    v, f = tube()
    p = _poly(v, f, lines=np.array([[0, 5], [3, 90]]), verts=np.array([7]))
    p.save(str(d / "stray_cells.vtp"))
    return d / "stray_cells.vtp", tube_skeleton(d / "stray_cells.json")


def degenerate_triangles(d: Path):
    """Repeated-vertex faces, duplicate faces, and zero-area slivers closing T-junctions."""
    v, f = tube()
    v = list(v)
    faces = [tuple(x) for x in f]
    n_around = 40
    new = []
    for k in (10, 25):  # split edge (a, b) of the quad strip on one side, sliver on the other
        row = k * n_around
        a, b = row + 3, row + 4  # an edge along the circumference shared by two rows of triangles
        m = len(v)
        v.append((np.asarray(v[a]) + np.asarray(v[b])) / 2)
        for idx, tri in enumerate(faces):
            for s in range(3):
                if tri[s] == a and tri[(s + 1) % 3] == b:  # (a, b, c) -> (a, m, c), (m, b, c)
                    c = tri[(s + 2) % 3]
                    faces[idx] = (a, m, c)
                    new.append((m, b, c))
        new.append((m, a, b))  # zero-area sliver closing the T-junction
    faces += new
    faces += [(0, 0, 1), (5, 6, 6)]  # repeated vertices
    faces += [faces[100], faces[200][::-1]]  # duplicates
    path = _write_ply(d / "degenerate.ply", np.asarray(v), np.asarray(faces))
    return path, tube_skeleton(d / "degenerate.json")


def duplicated_vertices(d: Path):
    """A triangle soup: every face has its own three vertices."""
    v, f = tube()
    soup_v = v[f].reshape(-1, 3)
    soup_f = np.arange(len(soup_v)).reshape(-1, 3)
    return _write_ply(d / "soup.ply", soup_v, soup_f), tube_skeleton(d / "soup.json")


def hole_in_wall(d: Path):
    """A few faces missing in the middle of the wall (a hole, not an open end)."""
    v, f = tube()
    centres = v[f].mean(axis=1)
    hole = (np.abs(centres[:, 0] - LENGTH / 2) < 1.5) & (centres[:, 1] > 2.0)
    return _write_ply(d / "hole.ply", v, f[~hole]), tube_skeleton(d / "hole.json")


def self_touching(d: Path):
    """The tube pinched in the middle until its walls (nearly) touch."""
    v, f = tube()
    squeeze = 1.0 - 0.995 * np.exp(-(((v[:, 0] - LENGTH / 2) / 2.0) ** 2))
    v = v * np.column_stack([np.ones(len(v)), squeeze, np.ones(len(v))])
    return _write_ply(d / "touching.ply", v, f), tube_skeleton(d / "touching.json")


def scaled(factor: float, name: str):
    def make(d: Path):
        v, f = tube()
        return _write_ply(d / f"{name}.ply", v * factor, f), tube_skeleton(d / f"{name}.json", scale=factor)

    make.__name__ = name
    return make


def empty_file(d: Path):
    (d / "empty.stl").write_bytes(b"")
    return d / "empty.stl", None


def not_a_mesh(d: Path):
    (d / "notes.vtp").write_text("these are my notes, not a surface\n" * 20)
    return d / "notes.vtp", None


def binary_garbage(d: Path):
    (d / "garbage.stl").write_bytes(np.random.default_rng(0).bytes(4000))
    return d / "garbage.stl", None


def nan_coordinates(d: Path):
    v, f = tube()
    v[17] = np.nan
    return _write_ply(d / "nan.ply", v, f), tube_skeleton(d / "nan.json")


def only_lines(d: Path):
    v, _ = tube()
    p = _poly(v[:10], np.zeros((0, 3), np.int64), lines=np.array([[0, 1], [1, 2]]))
    p.save(str(d / "lines.vtp"))
    return d / "lines.vtp", None


def volume_mesh(d: Path):
    """A tetrahedral cylinder (.vtu): the mesher uses its boundary surface."""
    v, f = tube(n_around=24, n_along=30)
    grid = _poly(v, f).delaunay_3d()
    grid.save(str(d / "volume.vtu"))
    return d / "volume.vtu", tube_skeleton(d / "volume.json")


def mixed_quads(d: Path):
    """Quads with one row of triangles (a VTP of mixed polygons)."""
    v, q = tube(quads=True)
    tris = np.concatenate([q[:40][:, [0, 1, 2]], q[:40][:, [0, 2, 3]]])
    faces = [np.column_stack([np.full(len(q) - 40, 4), q[40:]]).ravel(), np.column_stack([np.full(len(tris), 3), tris]).ravel()]
    import pyvista as pv

    pv.PolyData(v, faces=np.concatenate(faces)).save(str(d / "mixed.vtp"))
    return d / "mixed.vtp", tube_skeleton(d / "mixed.json")


def two_pieces(d: Path):
    """The tube, a small closed box far away (a second vessel piece) and a debris triangle."""
    v, f = tube()
    bv = np.array([[x, y, z] for x in (0, 2) for y in (0, 2) for z in (0, 2)], float) + [100.0, 0, 0]
    bf = np.array([[0, 2, 1], [1, 2, 3], [4, 5, 6], [5, 7, 6], [0, 1, 4], [1, 5, 4], [2, 6, 3], [3, 6, 7], [0, 4, 2], [2, 4, 6], [1, 3, 5], [3, 7, 5]])
    debris_v = np.array([[-50.0, 0, 0], [-50, 0.01, 0], [-50, 0, 0.01]])
    allv = np.vstack([v, bv, debris_v])
    allf = np.vstack([f, bf + len(v), np.array([[0, 1, 2]]) + len(v) + 8])
    return _write_ply(d / "pieces.ply", allv, allf), tube_skeleton(d / "pieces.json")


#: name -> maker; every case runs through ``vmesh run default``.
HOSTILE_INPUTS = {
    m.__name__: m
    for m in (
        stray_cells, degenerate_triangles, duplicated_vertices, hole_in_wall, self_touching, scaled(1e-6, "tiny"),
        scaled(1e6, "huge"), empty_file, not_a_mesh, binary_garbage, nan_coordinates, only_lines, volume_mesh,
        mixed_quads, two_pieces,
    )
}
