"""Throughput of the local optimiser as ``mesh_transfinite`` runs it: node updates per second.

Runs the default chain up to ``mesh_transfinite`` on a case (the real ICA at vascularmd's
resolution where ``../shared/data/real`` or ``$VMESH_REAL_DATA`` holds it, else the synthetic
Y-bifurcation), records the two optimiser calls of the filter (untangling, then the default
light pass) and runs each again ``--repeat`` times, printing per call: node updates
(attempted: every node whose neighbourhood changed since its last try), wall and CPU seconds,
updates per wall-second and per CPU-second (all threads), and the scaled Jacobian min / mean
before and after. A shared machine's load changes the wall-clock rate; the per CPU-second
rate is the steadier one. Issue 18's target is 10^6 updates per second.

Usage::

    python benchmarks/optimiser_speed.py [--case ica|y_bifurcation] [--repeat 3] [--smooth-tol 0 0.01] [--per-sweep]

``--smooth-tol`` runs the light pass once per value (``optimise(..., smooth_tol=)``, the
filter's ``light_pass_tol``) instead of the recorded one; ``NUMBA_NUM_THREADS=1`` gives the
steadiest CPU seconds on a loaded machine. ``--per-sweep`` runs the light pass once more and
prints, per sweep, the node updates, the nodes moved, the mesh's SJ min / mean after it and
its CPU seconds (:func:`per_sweep`).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
ICA = {"elements_around": 6, "elements_ring": 4, "elements_layer": 4, "element_length": 0.25}


def inputs(case: str):
    """(surface, skeleton, mesh_transfinite overrides) of a case."""
    if case == "ica":
        real = Path(os.environ.get("VMESH_REAL_DATA", ROOT.parent / "shared" / "data" / "real"))
        if (real / "ica_swc_surface.vtp").exists():
            return real / "ica_swc_surface.vtp", real / "ica_centerline.swc", ICA
        print(f"note: {real}/ica_swc_surface.vtp missing: the Y-bifurcation instead")
    synth = ROOT / "data_synthetic" / "y_bifurcation"
    return synth / "surface.ply", synth / "skeleton.json", {}


def record_calls(surface, skeleton, overrides):
    """Run the chain to mesh_transfinite; return the optimiser calls ``(args, kwargs)`` it made."""
    import vmesh
    import vmesh.geometry.optimize as O

    calls, original = [], O.optimise

    def recording(*args, **kw):
        calls.append(((np.array(args[0], copy=True), *args[1:]), kw))  # the mesher overwrites the points
        return original(*args, **kw)

    chain = vmesh.FilterChain.load("default").with_overrides({f"mesh_transfinite.{k}": v for k, v in overrides.items()})
    names = [s.filter for s in chain.steps]
    chain.steps = chain.steps[: names.index("mesh_transfinite") + 1]
    O.optimise = recording
    try:
        chain.run(surface=str(surface), skeleton=str(skeleton))
    finally:
        O.optimise = original
    return calls


def per_sweep(args, kw) -> None:
    """The light pass ``optimise(*args, **kw)`` once, with a table row per Gauss-Seidel sweep."""
    import vmesh.geometry.optimize as O
    from vmesh.geometry.quality import hex8_scaled_jacobian

    cells, original, rows = np.asarray(args[1]).reshape(-1, 8), O._sweep, []

    def counted(X, st, *rest):
        stats, before = rest[9], X[st.nodes].copy()
        u, c = stats["updates"], time.process_time()
        out = original(X, st, *rest)
        c = time.process_time() - c
        q = hex8_scaled_jacobian(X, cells)
        rows.append((stats["updates"] - u, int(np.any(X[st.nodes] != before, axis=1).sum()), float(q.min()), float(q.mean()), c))
        return out

    O._sweep = counted
    try:
        O.optimise(*args, **kw)
    finally:
        O._sweep = original
    print("| sweep | updates | nodes moved | SJ min / mean after | CPU s |\n|---|---|---|---|---|")
    for i, (u, moved, lo, mean, c) in enumerate(rows, 1):
        print(f"| {i} | {u:,} | {moved:,} | {lo:.5f} / {mean:.6f} | {c:.2f} |")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--case", choices=("ica", "y_bifurcation"), default="ica")
    ap.add_argument("--repeat", type=int, default=3, help="timed runs per call (best kept)")
    ap.add_argument("--smooth-tol", type=float, nargs="+", help="light-pass tolerances to compare (default: the recorded one)")
    ap.add_argument("--per-sweep", action="store_true", help="also print the light pass sweep by sweep")
    args = ap.parse_args(argv)
    from vmesh.geometry.optimize import optimise

    calls = record_calls(*inputs(args.case))
    print(f"load average {os.getloadavg()[0]:.1f}; {args.case}")
    print("| call | nodes | updates | wall s | CPU s | updates/s (per CPU-s) | SJ min / mean before | after |\n|---|---|---|---|---|---|---|---|")
    runs = list(zip(("untangling", "light pass"), calls))
    if args.smooth_tol and len(calls) > 1:
        a, kw = calls[1]
        runs = runs[:1] + [(f"light pass, tol {t:g}", (a, {**kw, "smooth_tol": t})) for t in args.smooth_tol]
    for name, (a, kw) in runs:
        best = None
        for _ in range(args.repeat):
            t, c = time.perf_counter(), time.process_time()
            X, info = optimise(*a, **kw)
            dt, dc = time.perf_counter() - t, time.process_time() - c
            if best is None or dt < best[0]:
                best = (dt, dc, info)
        dt, dc, info = best
        b, f, u = info["before"], info["after"], info["updates"]
        print(f"| {name} | {len(np.asarray(a[0])):,} | {u:,} | {dt:.2f} | {dc:.2f} | {u / dt:,.0f} ({u / max(dc, 1e-9):,.0f}) | {b['min']:.4f} / {b['mean']:.5f} | {f['min']:.4f} / {f['mean']:.5f} |", flush=True)
    if args.per_sweep and len(calls) > 1:
        per_sweep(*calls[1])
    return 0


if __name__ == "__main__":
    sys.exit(main())
