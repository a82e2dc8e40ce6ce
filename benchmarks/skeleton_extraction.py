"""Skeleton extraction from the surface: time, memory and accuracy.

For every real surface (../shared/data/real; open ones capped first, flat caps of
closed ones detected) and the synthetic 500-600-node cerebral tree, or for the
cases given with ``--cases``:

* the surface is repaired and capped and its signed distance built (not timed
  as extraction: those are their own filters);
* ``extract_skeleton`` runs under a resource monitor: wall time, peak memory above
  the start, time of each stage (radius estimate, voxelise, thin, trace, clean,
  ends, resample), voxel size, grid size, inside voxels and SDF evaluations
  (the hierarchical voxelisation evaluates a small fraction of the grid);
* the result is checked: synthetic cases against their ground truth (endpoints,
  junctions, cycles; largest node distance to the true centerline in local radii),
  real ones against their caps (one end per cap).

Usage::

    python benchmarks/skeleton_extraction.py                    # real + cerebral_tree
    python benchmarks/skeleton_extraction.py --cases thoracic_aorta synthetic:cerebral_tree synthetic:ring
    python benchmarks/skeleton_extraction.py --voxels-per-radius 2.5 3 4

Rows go to ``benchmarks/results/skeleton_extraction.json``.
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from vmesh import realdata  # noqa: E402
from vmesh.chain import FilterChain  # noqa: E402
from vmesh.context import Context  # noqa: E402
from vmesh.io.atomic import write_text_atomic  # noqa: E402
from vmesh.io.skeleton import read_skeleton_json  # noqa: E402
from vmesh.io.surface import read_surface  # noqa: E402
from vmesh.monitor import ResourceMonitor  # noqa: E402

RESULTS = ROOT / "benchmarks" / "results"
SYNTHETIC = ROOT / "data_synthetic"
from data_synthetic.generate import CASES as SYNTHETIC_CASES  # noqa: E402


def node_error(points: np.ndarray, truth) -> float:
    """Largest distance from a node to the true centerline, in local true radii."""
    a, b = truth.points[truth.edges[:, 0]], truth.points[truth.edges[:, 1]]
    ra, rb = truth.radii[truth.edges[:, 0]], truth.radii[truth.edges[:, 1]]
    worst = 0.0
    for chunk in np.array_split(points, max(1, len(points) // 256)):
        ab = b - a
        t = np.clip(np.einsum("pej,ej->pe", chunk[:, None] - a[None], ab) / np.einsum("ej,ej->e", ab, ab), 0, 1)
        d = np.linalg.norm(chunk[:, None] - (a[None] + t[..., None] * ab[None]), axis=2)
        i = d.argmin(axis=1)
        rows = np.arange(len(chunk))
        r = ra[i] + t[rows, i] * (rb[i] - ra[i])
        worst = max(worst, float(np.max(d[rows, i] / r)))
    return worst


def synthetic_name(name: str) -> str | None:
    """The synthetic case a name refers to (``synthetic:ring``, or ``ring`` when no real
    case has that name), else ``None``."""
    if name.startswith("synthetic:"):
        return name.split(":", 1)[1]
    return name if name in SYNTHETIC_CASES and name not in realdata.REAL_CASES else None


def load_case(name: str):
    """(surface, ground-truth skeleton or None, prepare steps) of a case."""
    synthetic = synthetic_name(name)
    if synthetic is not None:
        surface = read_surface(SYNTHETIC / synthetic / "surface.ply")
        return surface, read_skeleton_json(SYNTHETIC / synthetic / "skeleton.json"), []
    surface_file, _, n_open = realdata.REAL_CASES[name]
    path = realdata.real_file(surface_file)
    if path is None:
        return None, None, None
    return read_surface(path), None, ["repair_surface", "cap_open_ends" if n_open else "detect_caps"]


def run_case(name: str, voxels_per_radius: float) -> dict | None:
    surface, truth, prepare = load_case(name)
    if surface is None:
        print(f"skip {name}: {realdata.missing_reason()}")
        return None
    # synthetic cases run without caps: the flat-end detection is measured too
    t0 = time.perf_counter()
    ready = FilterChain([*prepare, "build_sdf"]).run(surface=surface)
    prepare_s = time.perf_counter() - t0
    extract = FilterChain([("extract_skeleton", {"voxels_per_radius": voxels_per_radius})])
    with ResourceMonitor() as monitor:
        ctx = extract.run(context=Context(surface=ready.surface, sdf=ready.sdf, caps=ready.caps))
    skeleton = ctx.skeleton
    stats = ctx.report.sections["skeleton_extraction"]
    lo, hi = ctx.surface.bounds
    summary = skeleton.summary()
    row = {
        "case": name,
        "triangles": int(ctx.surface.n_faces),
        "extent_mm": round(float(np.max(hi - lo)), 1),
        "voxels_per_radius": voxels_per_radius,
        "min_radius_mm": round(stats.get("min_radius", float("nan")), 3),
        "voxel_mm": round(stats["spacing"], 4),
        "grid_voxels": int(np.prod(stats["grid"])),
        "inside_voxels": stats["inside_voxels"],
        "mask_evaluations": stats["sdf_evaluations_mask"],
        "sdf_evaluations": stats["sdf_evaluations"],
        "skeleton_voxels": stats["skeleton_voxels"],
        "nodes": summary["nodes"],
        "junctions": summary["junctions"],
        "endpoints": summary["endpoints"],
        "cycles": summary["cycles"],
        "components": summary["components"],
        "max_degree": summary["max_degree"],
        "ends": stats["ends"],
        "removed": {k: stats[k] for k in ("spurs", "merged_junctions", "small_cycles", "specks")},
        "stage_s": stats["timings"],
        "extract_s": round(monitor.seconds, 3),
        "extra_mb": round(monitor.extra_mb, 1),
        "prepare_and_sdf_s": round(prepare_s, 3),
    }
    if truth is not None:
        t = truth.summary()
        row["truth"] = {k: t[k] for k in ("junctions", "endpoints", "cycles", "max_degree")}
        row["topology_ok"] = all(t[k] == summary[k] for k in ("junctions", "endpoints", "cycles", "components", "max_degree"))
        row["max_node_error_radii"] = round(node_error(skeleton.points, truth), 4)
    else:
        n_caps = len(ctx.caps or [])
        row["caps"] = n_caps
        row["topology_ok"] = summary["components"] == 1 and (n_caps == 0 or summary["endpoints"] == n_caps)
    return row


def table(rows: list) -> str:
    head = ("case", "tris", "extent", "voxel", "grid", "inside", "evals", "nodes", "J", "E", "C", "ok", "err/r", "voxelise", "thin", "extract s", "+MB")
    lines = [head]
    for r in rows:
        st = r["stage_s"]
        lines.append(
            (
                r["case"],
                f"{r['triangles']}",
                f"{r['extent_mm']:.0f}",
                f"{r['voxel_mm']:.3f}",
                f"{r['grid_voxels'] / 1e6:.1f}M",
                f"{r['inside_voxels'] / 1e3:.0f}k",
                f"{r['sdf_evaluations'] / 1e3:.0f}k",
                f"{r['nodes']}",
                f"{r['junctions']}",
                f"{r['endpoints']}",
                f"{r['cycles']}",
                "yes" if r["topology_ok"] else "NO",
                f"{r['max_node_error_radii']:.3f}" if "max_node_error_radii" in r else "-",
                f"{st['voxelise']:.2f}",
                f"{st['thin']:.2f}",
                f"{r['extract_s']:.2f}",
                f"{r['extra_mb']:.0f}",
            )
        )
    widths = [max(len(line[i]) for line in lines) for i in range(len(head))]
    out = []
    for k, line in enumerate(lines):
        out.append("  ".join(c.ljust(w) if i == 0 else c.rjust(w) for i, (c, w) in enumerate(zip(line, widths))))
        if k == 0:
            out.append("-" * len(out[0]))
    return "\n".join(out)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--cases",
        nargs="+",
        help=f"cases (real: {', '.join(realdata.REAL_CASES)}; synthetic: synthetic:NAME with NAME in {', '.join(SYNTHETIC_CASES)})",
    )
    parser.add_argument("--voxels-per-radius", nargs="+", type=float, default=[3.0], help="voxels across the thinnest radius (several values: a sweep)")
    parser.add_argument("--output", default=str(RESULTS / "skeleton_extraction.json"))
    args = parser.parse_args(argv)
    cases = args.cases or [*realdata.REAL_CASES, "synthetic:cerebral_tree"]
    unknown = [c for c in cases if c not in realdata.REAL_CASES and synthetic_name(c) not in SYNTHETIC_CASES]
    if unknown:
        parser.error(f"unknown case(s): {', '.join(unknown)}")
    rows = []
    for vpr in args.voxels_per_radius:
        for name in cases:
            row = run_case(name, vpr)
            if row is not None:
                rows.append(row)
                print(f"{name} (voxels/radius {vpr}): {row['extract_s']:.2f} s, {row['nodes']} nodes", flush=True)
    print()
    print(table(rows))
    result = {
        "benchmark": "skeleton_extraction",
        "machine": {"platform": platform.platform(), "python": platform.python_version(), "cpus": __import__("os").cpu_count()},
        "rows": rows,
    }
    write_text_atomic(Path(args.output), json.dumps(result, indent=1))
    print(f"\nwrote {args.output}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
