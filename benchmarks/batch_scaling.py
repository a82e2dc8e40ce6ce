"""Batch meshing throughput on Dask: meshes per minute with 1 and 2 local workers.

The sweep is the one of ``tests/test_batch.py``: the synthetic Y-bifurcation with the
radius scaled by 0.9, 1.0, 1.1 (``scale_radius.scale``) times four first boundary-layer
thicknesses (``mesh_transfinite.first_layer`` 0.005 .. 0.04), 12 meshes, chain
``batch_sweep`` with its default meshing parameters.

For each worker count a local cluster (single-threaded worker processes, as
``vmesh batch --workers N`` starts) is started and warmed up (every worker meshes a
small straight tube) before the clock starts, so the numbers are steady-state
throughput; the start-up time (cluster and warm-up) is reported separately. Wall-clock
numbers depend on other load on the machine: the 1-minute load average is recorded. Each configuration runs into a fresh output
folder. A row with the per-worker signed-distance cache switched off
(``cache_entries = 0``) shows what the cache saves.

Usage::

    python benchmarks/batch_scaling.py                     # 1 and 2 workers (+ 2 without cache)
    python benchmarks/batch_scaling.py --workers 1 2 4 --repeat 2
    python benchmarks/batch_scaling.py --set mesh_transfinite.element_length=0.75

Rows go to ``benchmarks/results/batch_scaling.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from vmesh import batch  # noqa: E402
from vmesh.cli import parse_overrides  # noqa: E402
from vmesh.io.atomic import write_text_atomic  # noqa: E402

RESULTS = ROOT / "benchmarks" / "results"
SCALES = [0.9, 1.0, 1.1]
LAYERS = [0.005, 0.01, 0.02, 0.04]


def sweep_rows(case: str) -> list[dict]:
    surface = ROOT / "data_synthetic" / case / "surface.ply"
    skeleton = ROOT / "data_synthetic" / case / "skeleton.json"
    return [
        {"name": f"{case}_s{s:g}_t{t:g}", "surface": str(surface), "skeleton": str(skeleton), "scale_radius.scale": s, "mesh_transfinite.first_layer": t}
        for s in SCALES
        for t in LAYERS
    ]


def _warm_up() -> None:
    """Mesh a small straight tube without the cache: imports and first-call costs of every
    library the chain uses are paid off the clock, and the sweep's cache stays cold."""
    import vmesh

    case = ROOT / "data_synthetic" / "straight_tube"
    chain = vmesh.FilterChain.load("batch_sweep").with_overrides({"mesh_transfinite.element_length": 0.75})
    with tempfile.TemporaryDirectory(prefix="vmesh-warm-") as tmp:
        chain.run(surface=case / "surface.ply", skeleton=case / "skeleton.json", out_dir=Path(tmp) / "o")


def measure(rows, n_workers: int, overrides: dict, cache_entries: int) -> dict:
    from distributed import Client

    t0 = time.perf_counter()
    cluster = batch._local_cluster(n_workers)
    client = Client(cluster)
    try:
        client.wait_for_workers(n_workers, timeout=120)
        client.run(_warm_up)
        startup = time.perf_counter() - t0
        load_before = round(os.getloadavg()[0], 2)
        with tempfile.TemporaryDirectory(prefix="vmesh-batch-bench-") as tmp:
            t1 = time.perf_counter()
            res = batch.run(rows, "batch_sweep", out=Path(tmp) / "out", client=client, overrides=overrides, progress=False, parquet=False, cache_entries=cache_entries)
            wall = time.perf_counter() - t1
    finally:
        client.close()
        cluster.close()
    ok = [r for r in res.rows if r["status"] == "ok"]
    return {
        "workers": n_workers,
        "cache_entries": cache_entries,
        "rows": len(rows),
        "ok": len(ok),
        "failed": len(rows) - len(ok),
        "wall_s": round(wall, 3),
        "meshes_per_minute": round(60.0 * len(ok) / wall, 2),
        "mean_row_s": round(sum(r["seconds"] for r in ok) / max(len(ok), 1), 3),
        "mean_row_cpu_s": round(sum(r["cpu_seconds"] for r in ok) / max(len(ok), 1), 3),
        # what the workers could reach if each had a core to itself
        "cpu_bound_meshes_per_minute": round(60.0 * n_workers / max(sum(r["cpu_seconds"] for r in ok) / max(len(ok), 1), 1e-9), 1),
        "sdf_builds": sum(not r["sdf_reused"] for r in ok),
        "elements": sorted({r["elements"] for r in ok}),
        "startup_s": round(startup, 2),
        "load_average_1min_before": load_before,
        "load_average_1min_after": round(os.getloadavg()[0], 2),
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2], help="worker counts to measure (default: 1 2)")
    ap.add_argument("--case", default="y_bifurcation", help="synthetic case (default: y_bifurcation)")
    ap.add_argument("--repeat", type=int, default=1, help="runs per configuration; the fastest is kept")
    ap.add_argument("--no-cache-row", action="store_true", help="skip the run without the signed-distance cache")
    ap.add_argument("--set", action="append", metavar="FILTER.PARAM=VALUE", help="override a parameter in every row")
    ap.add_argument("--out", default=str(RESULTS / "batch_scaling.json"))
    args = ap.parse_args(argv)

    rows = sweep_rows(args.case)
    overrides = parse_overrides(args.set)
    configs = [(n, 2) for n in args.workers]
    if not args.no_cache_row:
        configs.append((max(args.workers), 0))
    results = []
    for n, entries in configs:
        runs = [measure(rows, n, overrides, entries) for _ in range(max(args.repeat, 1))]
        best = min(runs, key=lambda r: r["wall_s"])
        results.append(best)
        print(f"  {n} worker(s), cache {entries}: {best['meshes_per_minute']:.1f} meshes/min ({best['wall_s']:.1f} s for {best['ok']} meshes)", file=sys.stderr, flush=True)

    base = next((r for r in results if r["workers"] == min(args.workers) and r["cache_entries"]), results[0])
    header = f"{'workers':>7}  {'cache':>5}  {'ok':>3}  {'wall s':>7}  {'meshes/min':>10}  {'speedup':>7}  {'row s':>6}  {'row CPU s':>9}  {'CPU-bound/min':>13}  {'SDF builds':>10}  {'start-up s':>10}  {'load':>9}"
    print(f"\nbatch_scaling: {len(rows)}-row sweep on {args.case} ({os.cpu_count()} cores, {platform.python_implementation()} {platform.python_version()})")
    print(header)
    print("-" * len(header))
    for r in results:
        r["speedup"] = round(r["meshes_per_minute"] / base["meshes_per_minute"], 2)
        load = f"{r['load_average_1min_before']:.1f}/{r['load_average_1min_after']:.1f}"
        print(f"{r['workers']:>7}  {r['cache_entries']:>5}  {r['ok']:>3}  {r['wall_s']:>7.1f}  {r['meshes_per_minute']:>10.1f}  {r['speedup']:>7.2f}  {r['mean_row_s']:>6.2f}  {r['mean_row_cpu_s']:>9.2f}  {r['cpu_bound_meshes_per_minute']:>13.1f}  {r['sdf_builds']:>10}  {r['startup_s']:>10.1f}  {load:>9}")
    print("(row s: wall seconds per row on its worker; row CPU s: that row's CPU seconds; CPU-bound/min: workers x 60 / row CPU s, the rate")
    print(" with a free core per worker; load: 1-minute load average before/after, other processes on the machine slow the wall-clock rates)")
    doc = {
        "benchmark": "batch_scaling",
        "case": args.case,
        "sweep": {"scale_radius.scale": SCALES, "mesh_transfinite.first_layer": LAYERS},
        "overrides": overrides,
        "cpu_count": os.cpu_count(),
        "python": platform.python_version(),
        "rows": results,
    }
    write_text_atomic(args.out, json.dumps(doc, indent=2, default=str))
    print(f"\nwritten {args.out}")
    return 0 if all(r["failed"] == 0 for r in results) else 1


if __name__ == "__main__":
    sys.exit(main())
