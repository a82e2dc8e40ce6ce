"""One gmsh (or TetGen) tetrahedral mesh, run in a subprocess by vs_unstructured.py (so a hang or
crash of the mesher is bounded by a timeout and becomes a row). Prints one JSON line.

    python benchmarks/_gmsh_worker.py tet  WALL.stl     H  THREADS  [OUT_SURF.npz]
    python benchmarks/_gmsh_worker.py bl   WALL.stl     H  THREADS  HEIGHTS(comma, cumulative, signed)
    python benchmarks/_gmsh_worker.py tetgen SURF.npz   H
"""

from __future__ import annotations

import json
import math
import sys
import time

import numpy as np

ALGO2D = 6


def _setup(h: float, threads: int):
    import gmsh

    gmsh.initialize(["gmsh", "-v", "2"])
    gmsh.option.setNumber("General.Terminal", 0)
    gmsh.option.setNumber("General.NumThreads", threads)
    gmsh.option.setNumber("Mesh.MaxNumThreads1D", threads)
    gmsh.option.setNumber("Mesh.MaxNumThreads2D", threads)
    gmsh.option.setNumber("Mesh.MaxNumThreads3D", threads)
    gmsh.option.setNumber("Mesh.MeshSizeMin", h)
    gmsh.option.setNumber("Mesh.MeshSizeMax", h)
    gmsh.option.setNumber("Mesh.MeshSizeFromCurvature", 0)
    gmsh.option.setNumber("Mesh.MeshSizeExtendFromBoundary", 0)
    gmsh.option.setNumber("Mesh.MeshSizeFromPoints", 0)
    gmsh.option.setNumber("Mesh.Algorithm", ALGO2D)  # 6 Frontal-Delaunay, 1 MeshAdapt (rougher patches)
    gmsh.option.setNumber("Mesh.Algorithm3D", 10)  # HXT (parallel Delaunay)
    return gmsh


def _counts(gmsh) -> dict:
    out = {"nodes": int(len(gmsh.model.mesh.getNodes()[0]))}
    types, tags, _ = gmsh.model.mesh.getElements(3)
    names = {4: "tetrahedra", 6: "prisms", 5: "hexahedra", 7: "pyramids"}
    total = 0
    for t, tg in zip(types, tags):
        out[names.get(int(t), f"type{int(t)}")] = int(len(tg))
        total += len(tg)
    out["elements"] = int(total)
    vol = 0.0
    for t, tg in zip(types, tags):
        try:
            vol += float(np.sum(gmsh.model.mesh.getElementQualities(tg, "volume")))
        except Exception:
            pass
    out["volume"] = vol
    t2, g2, _ = gmsh.model.mesh.getElements(2)
    out["surface_triangles"] = int(sum(len(g) for t, g in zip(t2, g2) if int(t) == 2))
    return out


def _surface_arrays(gmsh):
    tags, xyz, _ = gmsh.model.mesh.getNodes()
    pts = xyz.reshape(-1, 3)
    index = np.full(int(tags.max()) + 1, -1, np.int64)
    index[tags.astype(np.int64)] = np.arange(len(tags))
    tris = []
    for t, _, nodes in zip(*gmsh.model.mesh.getElements(2)):
        if int(t) == 2:
            tris.append(index[nodes.astype(np.int64)].reshape(-1, 3))
    f = np.concatenate(tris)
    used = np.unique(f)
    remap = np.full(len(pts), -1, np.int64)
    remap[used] = np.arange(len(used))
    return pts[used], remap[f]


def volume_mesh(path: str, h: float, threads: int, heights: list[float] | None = None, surf_out: str | None = None) -> dict:
    """Tetrahedra (and, with ``heights``, inward boundary-layer prisms) inside an open wall surface.

    The wall is classified and reparametrised (``classifySurfaces`` + ``createGeometry``),
    remeshed at size ``h``; with ``heights`` a boundary layer is extruded inward along the
    mesh normals first (``extrudeBoundaryLayer``, recombined to prisms); the open ends
    (of the wall, or of the layer's top surface) are closed with plane surfaces, as in
    gmsh's examples/api/aneurysm.py.
    """
    gmsh = _setup(h, threads)
    t0 = time.perf_counter()
    gmsh.merge(path)
    gmsh.model.mesh.classifySurfaces(math.pi, True, True)
    gmsh.model.mesh.createGeometry()
    if heights:
        gmsh.option.setNumber("Geometry.ExtrudeReturnLateralEntities", 0)
        e = gmsh.model.geo.extrudeBoundaryLayer(gmsh.model.getEntities(2), [1] * len(heights), heights, True)
        top = [s for s in e if s[0] == 2]
    else:
        top = gmsh.model.getEntities(2)
    surfaces = [s[1] for s in top]
    gmsh.model.geo.synchronize()
    bnd = [c[1] for c in gmsh.model.getBoundary(top)]
    for loop in gmsh.model.geo.addCurveLoops(bnd):
        surfaces.append(gmsh.model.geo.addPlaneSurface([loop]))
    gmsh.model.geo.addVolume([gmsh.model.geo.addSurfaceLoop(surfaces)])
    gmsh.model.geo.synchronize()
    t1 = time.perf_counter()
    gmsh.model.mesh.generate(3)
    t2 = time.perf_counter()
    out = {"geometry_s": round(t1 - t0, 3), "mesh_s": round(t2 - t1, 3), "seconds": round(t2 - t0, 3), **_counts(gmsh)}
    if heights:  # prisms of positive volume: the layer went inward
        try:
            q = gmsh.model.mesh.getElementQualities(gmsh.model.mesh.getElementsByType(6)[0], "minSJ")
            out["prism_minSJ_min"] = float(np.min(q)) if len(q) else None
            out["prism_invalid"] = int(np.sum(q <= 0)) if len(q) else 0
        except Exception as exc:
            out["prism_check"] = str(exc)
    if surf_out:
        v, f = _surface_arrays(gmsh)
        np.savez(surf_out, v=v, f=f)
    gmsh.finalize()
    return out


def tetgen_mesh(npz: str, h: float) -> dict:
    import tetgen

    d = np.load(npz)
    t0 = time.perf_counter()
    tg = tetgen.TetGen(d["v"], d["f"].astype(np.int32))
    nodes, elems, *_ = tg.tetrahedralize(quality=True, minratio=1.5, maxvolume=h ** 3 / (6 * math.sqrt(2)), quiet=True)
    t1 = time.perf_counter()
    return {"seconds": round(t1 - t0, 3), "nodes": int(len(nodes)), "elements": int(len(elems)), "tetrahedra": int(len(elems)),
            "surface_triangles": int(len(d["f"]))}


def main(argv):
    mode = argv[0]
    if mode == "tet":
        res = volume_mesh(argv[1], float(argv[2]), int(argv[3]), None, argv[4] if len(argv) > 4 else None)
    elif mode == "bl":
        res = volume_mesh(argv[1], float(argv[2]), int(argv[3]), [float(x) for x in argv[4].split(",")])
    elif mode == "tetgen":
        res = tetgen_mesh(argv[1], float(argv[2]))
    else:
        raise SystemExit(f"unknown mode {mode}")
    print("RESULT " + json.dumps(res), flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
