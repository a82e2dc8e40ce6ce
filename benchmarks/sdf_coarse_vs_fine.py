"""Coarse against fine signed distance: build time, query throughput, projection error.

For every real surface (../shared/data/real, open ones capped first) and the largest
synthetic case, or for the surfaces given with ``--input``:

* the fine surface is repaired and capped (``repair_surface``, ``cap_open_ends`` or
  ``detect_caps``), then decimated to each ``--coarse`` face count;
* 10^4..10^6 query points are placed like a mesher's (wall samples moved along the
  inward normal from 0.3 radii outside to the centreline, see
  ``vmesh.geometry.sdf.vessel_query_points``);
* each point set is projected with the fine, the coarse and the two-step SDF, and with
  the octree index (``OctreeSignedDistance``, ``build_sdf index=octree``) over every coarse
  surface and over the fine one (rows whose coarse level ends in ", octree"; ``--no-octree``
  leaves them out). Times are the best of 3 runs.

Columns: ``qps`` = points per wall-clock second (2 cores), ``cpu_qps`` = points per
CPU-second (less sensitive to other jobs on the machine), ``err`` = distance of the
coarse projection from the fine surface divided by the local radius (max / mean),
``dist_err`` = difference of signed distances / local radius, two-step = coarse
projection refined on the fine surface. Coarse levels: fixed face counts (``--coarse``)
and one decimated to a tolerance of the local radius (``--coarse-error``,
``decimate_surface max_error``).

Usage::

    python benchmarks/sdf_coarse_vs_fine.py                 # all cases, table + JSON
    python benchmarks/sdf_coarse_vs_fine.py --input vessel.stl --points 100000
    python benchmarks/sdf_coarse_vs_fine.py --backends      # closest-point backends compared

The same measurement runs as a chain: ``vmesh run sdf_benchmark -i SURFACE -o OUT``
(``filters/sdf_benchmark.toml``). Rows go to ``benchmarks/results/sdf_coarse_vs_fine.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from vmesh.chain import FilterChain  # noqa: E402
from vmesh.geometry.sdf import SignedDistance, morton_order, vessel_query_points  # noqa: E402
from vmesh.geometry.sdf_measure import compare_coarse_fine  # noqa: E402
from vmesh.io.atomic import write_text_atomic  # noqa: E402
from vmesh.io.surface import read_surface  # noqa: E402
from vmesh import realdata  # noqa: E402

RESULTS = ROOT / "benchmarks" / "results"


def prepare(path) -> tuple:
    """Fine surface (repaired, closed, caps labelled) of a surface file."""
    from vmesh.geometry import topology

    surface = read_surface(path)
    is_open = bool(topology.boundary_loops(surface.faces))
    steps = ["repair_surface", "cap_open_ends" if is_open else "detect_caps"]
    ctx = FilterChain(steps).run(surface=surface)
    return ctx.surface, is_open


def coarse_versions(surface, targets, backend, max_error=None):
    """``(label, coarse surface)`` pairs: one per face count in ``targets``, plus the
    coarsest decimation, starting from the smallest target, within the tolerance
    ``max_error`` (relative to the local radius; ``decimate_surface max_error``)."""
    out = []
    for target in targets:
        if target >= surface.n_faces:
            continue
        ctx = FilterChain([("decimate_surface", {"target_faces": int(target), "backend": backend})]).run(surface=surface)
        out.append((f"{int(target)} faces", ctx.coarse_surface))
    if max_error is not None and targets:
        start = min(min(targets), surface.n_faces)
        ctx = FilterChain([("decimate_surface", {"target_faces": int(start), "backend": backend, "max_error": float(max_error)})]).run(surface=surface)
        if ctx.coarse_surface.n_faces < surface.n_faces:
            out.append((f"tolerance {100 * max_error:g} %R", ctx.coarse_surface))
    return out


def default_cases() -> list[tuple[str, Path]]:
    cases = []
    for key, (surface_file, _, _) in realdata.REAL_CASES.items():
        p = realdata.real_file(surface_file)
        if p is not None:
            cases.append((key, p))
    if not cases:
        print(f"note: {realdata.missing_reason()}")
    synthetic = sorted((ROOT / "data_synthetic").glob("*/surface.ply"))
    if synthetic:
        sizes = {p: read_surface(p).n_faces for p in synthetic}
        biggest = max(sizes, key=sizes.get)
        cases.append((f"synthetic_{biggest.parent.name}", biggest))
    return cases


def print_table(rows) -> str:
    head = ("case", "tri fine", "coarse level", "tri coarse", "points", "build f/c s", "qps fine", "qps coarse", "speedup", "cpu qps c", "err max %R", "err mean %R", "dist max %R", "2-step qps", "2-step dist max %R")
    lines = [head]
    for r in rows:
        lines.append(
            (
                r["case"],
                str(r["triangles_fine"]),
                r.get("coarse_level", ""),
                str(r["triangles_coarse"]),
                f"{r['points']:.0e}",
                f"{r['build_s_fine']:.2f}/{r['build_s_coarse']:.2f}",
                f"{r['qps_fine']:,}",
                f"{r['qps_coarse']:,}",
                f"{r['speedup']:.1f}",
                f"{r['cpu_qps_coarse']:,}",
                f"{100 * r['err_max_rel']:.2f}",
                f"{100 * r['err_mean_rel']:.3f}",
                f"{100 * r['dist_err_max_rel']:.2f}",
                f"{r['qps_two_step']:,}",
                f"{100 * r['two_step_dist_err_max_rel']:.2f}",
            )
        )
    widths = [max(len(line[i]) for line in lines) for i in range(len(head))]
    print("\n".join("  ".join(c.rjust(w) if i else c.ljust(w) for i, (c, w) in enumerate(zip(line, widths))) for line in lines))
    markdown = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    markdown += ["| " + " | ".join(line) + " |" for line in lines[1:]]
    return "\n".join(markdown)


# ---------------------------------------------------------------------------
# backends
# ---------------------------------------------------------------------------
def backend_rows(surface, n_points: int, label: str) -> list[dict]:
    """Closest-point / signed-distance backends on one surface, same query points."""
    import igl

    sdf = SignedDistance.from_surface(surface)
    points, _ = vessel_query_points(sdf, n_points, seed=1)
    v, f = sdf.vertices, sdf.faces
    rows = []

    def timed(name, fn, n=n_points, note=""):
        fn_small = None
        w0, c0 = time.perf_counter(), time.process_time()
        try:
            fn_small = fn()
        except Exception as exc:  # an optional backend failing is a result too
            rows.append({"surface": label, "triangles": len(f), "backend": name, "points": n, "error": f"{type(exc).__name__}: {exc}"})
            return None
        wall, cpu = time.perf_counter() - w0, time.process_time() - c0
        rows.append({"surface": label, "triangles": len(f), "backend": name, "points": n, "qps": round(n / wall), "cpu_qps": round(n / max(cpu, 1e-9)), "note": note})
        return fn_small

    tree = igl.AABB()
    tree.init(v, f)
    order = morton_order(points)
    sorted_pts = np.ascontiguousarray(points[order])
    sdf.project(points[:100])
    from vmesh.geometry.bvh import TriangleBVH

    bvh = TriangleBVH(v, f)
    bvh.closest(points[:100])  # compiled code loaded
    timed("vmesh SignedDistance.project (numba BVH on all cores, Morton order, pseudonormal sign)", lambda: sdf.project(points))
    timed("vmesh TriangleBVH.closest (numba, all cores; closest point + feature only)", lambda: bvh.closest(points))
    timed("igl.AABB.squared_distance, input order (closest point only)", lambda: tree.squared_distance(v, f, points))
    timed("igl.AABB.squared_distance, Morton order (closest point only)", lambda: tree.squared_distance(v, f, sorted_pts))
    timed("igl.point_mesh_squared_distance (builds its tree per call)", lambda: igl.point_mesh_squared_distance(points, v, f))
    timed("igl.signed_distance pseudonormal (builds its tree per call)", lambda: igl.signed_distance(points, v, f, igl.SIGNED_DISTANCE_TYPE_PSEUDONORMAL))
    timed("igl.signed_distance fast winding number", lambda: igl.signed_distance(points, v, f, igl.SIGNED_DISTANCE_TYPE_FAST_WINDING_NUMBER))
    wn = igl.FastWindingNumberBVH()
    wn.init(v, f)
    timed("igl.FastWindingNumberBVH (inside test only, no distance)", lambda: wn.winding_number(points))
    small = min(n_points, 20_000)
    import pyvista as pv

    mesh = pv.PolyData(v, np.hstack([np.full((len(f), 1), 3), f]).ravel())
    cloud = pv.PolyData(points[:small])
    timed("VTK vtkImplicitPolyDataDistance (pyvista compute_implicit_distance)", lambda: cloud.compute_implicit_distance(mesh), n=small)
    try:
        import fcpw  # optional, float32 SIMD BVH
    except ImportError:
        rows.append({"surface": label, "triangles": len(f), "backend": "fcpw", "points": 0, "error": "not installed (pip install fcpw)"})
    else:
        def fcpw_query():
            scene = fcpw.scene_3D()
            scene.set_object_count(1)
            scene.set_object_vertices(np.asfortranarray(v.astype(np.float32)), 0)
            scene.set_object_triangles(np.asfortranarray(f.astype(np.int32)), 0)
            scene.build(fcpw.aggregate_type.bvh_surface_area, True, False, False)
            hits = fcpw.interaction_3D_list()
            scene.find_closest_points(np.asfortranarray(sorted_pts.astype(np.float32)), np.full(len(points), np.inf, np.float32), hits)
            return np.array([h.p for h in hits])

        timed("fcpw (float32 SIMD BVH, build + query + conversion to numpy)", fcpw_query)
    try:
        import open3d as o3d  # optional
    except ImportError:
        rows.append({"surface": label, "triangles": len(f), "backend": "open3d", "points": 0, "error": "not installed"})
    else:
        def o3d_query():
            scene = o3d.t.geometry.RaycastingScene()
            scene.add_triangles(o3d.core.Tensor(v.astype(np.float32)), o3d.core.Tensor(f.astype(np.uint32)))
            return scene.compute_closest_points(o3d.core.Tensor(points.astype(np.float32)))

        timed("open3d RaycastingScene.compute_closest_points", o3d_query)
    return rows


def run_backends(args):
    path = realdata.real_file("ica_swc_surface.vtp")
    if path is None:
        print(f"skipped: {realdata.missing_reason()}")
        return
    fine, _ = prepare(path)
    coarse = coarse_versions(fine, [5000], "fast_simplification")[0][1]
    rows = backend_rows(fine, args.backend_points, "ica_swc fine") + backend_rows(coarse, args.backend_points, "ica_swc coarse")
    width = max(len(r["backend"]) for r in rows)
    print(f"\n{'surface':<15} {'triangles':>9}  {'backend':<{width}}  {'points':>8}  {'qps':>10}  {'cpu qps':>10}")
    for r in rows:
        if "error" in r:
            print(f"{r['surface']:<15} {r['triangles']:>9}  {r['backend']:<{width}}  {'-':>8}  {r['error']}")
        else:
            print(f"{r['surface']:<15} {r['triangles']:>9}  {r['backend']:<{width}}  {r['points']:>8}  {r['qps']:>10,}  {r['cpu_qps']:>10,}")
    out = RESULTS / "sdf_backends.json"
    write_text_atomic(out, json.dumps(rows, indent=2))
    print(f"\nwritten {out.relative_to(ROOT)}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--input", action="append", help="surface file to measure (repeatable); default: every real case and the largest synthetic one")
    ap.add_argument("--points", type=int, nargs="+", default=[10_000, 100_000, 1_000_000], help="numbers of query points")
    ap.add_argument("--coarse", type=int, nargs="+", default=[5_000, 20_000], help="coarse surface face counts")
    ap.add_argument("--coarse-error", type=float, default=0.015, help="also decimate to this tolerance (fraction of the local radius; decimate_surface max_error); 0 = off")
    ap.add_argument("--decimation", default="fast_simplification", choices=("fast_simplification", "pymeshlab"), help="decimation backend")
    ap.add_argument("--no-octree", action="store_true", help="leave out the octree index rows")
    ap.add_argument("--backends", action="store_true", help="compare closest-point backends instead")
    ap.add_argument("--backend-points", type=int, default=100_000)
    ap.add_argument("--out", help="JSON rows output (default: benchmarks/results/sdf_coarse_vs_fine.json; with --input, sdf_coarse_vs_fine_<name>.json in the current folder, so the shipped results stay)")
    args = ap.parse_args(argv)
    if args.backends:
        run_backends(args)
        return 0
    cases = [(Path(p).stem, Path(p)) for p in args.input] if args.input else default_cases()
    if args.out is None:
        args.out = f"sdf_coarse_vs_fine_{cases[0][0]}.json" if args.input else str(RESULTS / "sdf_coarse_vs_fine.json")
    rows = []
    for name, path in cases:
        t0 = time.perf_counter()
        fine, was_open = prepare(path)
        coarse = coarse_versions(fine, args.coarse, args.decimation, args.coarse_error or None)
        if not coarse:
            print(f"{name}: {fine.n_faces} triangles, no coarse level below it; skipped", file=sys.stderr)
            continue
        labels, surfaces = zip(*coarse)
        case_rows = compare_coarse_fine(fine, surfaces, counts=args.points, case=name, labels=labels, octree=not args.no_octree)
        rows += case_rows
        print(f"{name}: {fine.n_faces} triangles{' (capped)' if was_open else ''}, {time.perf_counter() - t0:.0f} s", file=sys.stderr)
    print(f"\nload average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores; decimation: {args.decimation}\n")
    markdown = print_table(rows)
    write_text_atomic(args.out, json.dumps(rows, indent=2))
    header = f"Load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores; decimation backend {args.decimation}; columns as in benchmarks/sdf_coarse_vs_fine.py.\n\n"
    write_text_atomic(Path(args.out).with_suffix(".md"), header + markdown + "\n")
    print(f"\nwritten {args.out} and {Path(args.out).with_suffix('.md').name}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
