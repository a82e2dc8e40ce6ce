"""The local mesh optimiser (vmesh.geometry.optimize) against the former L-BFGS untangler.

Rows (one per mesh and optimiser): nodes, node updates, updates per second, scaled
Jacobian min / mean before -> after (linear elements, corner-based), invalid elements
after, nodes moved and seconds:

* folded O-grid cylinders (tests/cylinder_blocks.py) of growing size, with element
  corners pushed through their neighbours, and the same cylinders perturbed everywhere
  with a light pass over every node (``smooth_below=0.99``: the throughput of full sweeps);
* meshes from the default chain with untangling off (``mesh_transfinite.untangle=false``):
  synthetic ``two_junctions`` and ``y_bifurcation``, and the real ICA at vascularmd's
  resolution (elements_around=6, elements_ring=4, elements_layer=4, element_length=0.25)
  when ``VMESH_REAL_DATA`` holds it; each is then optimised by both optimisers exactly as
  ``mesh_transfinite`` does, and by the local one followed by the default light pass;
* the cylinders with curved cross-sections (``curved_sections``, nudged by 1e-4 radius off
  exact symmetry) and the default light pass (``light_pass_below = 0.95``).

Timings are wall-clock on whatever else runs on the machine (best of ``--repeat``); the
rate per CPU-second (all threads' CPU time) is printed beside the wall-clock rate, as it
depends less on the machine's load.

Usage::

    python benchmarks/optimiser.py            # everything
    python benchmarks/optimiser.py --quick    # the cylinders only
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from vmesh.geometry.optimize import corner_index, optimise  # noqa: E402
from vmesh.geometry.quality import hex8_scaled_jacobian  # noqa: E402

ICA = {"elements_around": 6, "elements_ring": 4, "elements_layer": 4, "element_length": 0.25}


def cylinder_case(scale: int, seed: int = 1, curved: bool = False):
    """Folded O-grid cylinder: (points, cells, keyword arguments of optimise)."""
    from cylinder_blocks import cylinder_blocks, optimiser_constraints, project_cylinder
    from vmesh.geometry.transfinite import Refinement, mesh_blocks

    R = 2.0
    blocks = cylinder_blocks(radius=R, sections=5)
    sm = mesh_blocks(blocks, project_cylinder(R), Refinement(around=4 * scale, core=4 * scale, ring=3 * scale, layer=4 * scale, element_length=0.5 / scale, first_layer=0.02 / scale, curved_sections=curved))
    return sm, optimiser_constraints(sm, R)


def fold(sm, count, seed=1):
    rng = np.random.default_rng(seed)
    X = sm.points.copy()
    inner = np.flatnonzero((np.abs(X[:, 2] - 5) < 4) & (np.linalg.norm(X[:, :2], axis=1) < 1.5))
    pick = rng.choice(inner, count, replace=False)
    size = 0.5 / max(1, round(len(X) ** (1 / 3) / 16))
    X[pick] += rng.normal(size=(count, 3)) * 1.2 * size
    return X


def jitter(sm, kw, seed=2):
    rng = np.random.default_rng(seed)
    X = sm.points.copy()
    free = ~kw["boundary"] & (np.linalg.norm(X[:, :2], axis=1) < 1.5)
    X[free] += rng.normal(size=(free.sum(), 3)) * 0.01
    return X


def nudge(sm, kw, seed=3):
    """The curved cylinder with its free nodes moved by 1e-4 radius: a mesh of a real vessel is
    never exactly symmetric (at an exactly symmetric node mirror elements tie for the worst)."""
    rng = np.random.default_rng(seed)
    X = sm.points.copy()
    free = ~kw["boundary"] & ~kw["wall"]
    X[free] += rng.normal(size=(free.sum(), 3)) * 2e-4
    return X


def row(case, name, X0, cells, run, repeat):
    q0 = hex8_scaled_jacobian(X0, cells)
    best = cpu = None
    for _ in range(repeat):
        t, c = time.perf_counter(), time.process_time()
        X, info = run()
        dt, dc = time.perf_counter() - t, time.process_time() - c
        best = dt if best is None else min(best, dt)
        cpu = dc if cpu is None else min(cpu, dc)
    q = hex8_scaled_jacobian(X, cells)
    moved = int(np.any(X != X0, axis=1).sum())
    updates = info.get("updates")
    return {
        "case": case, "optimiser": name, "nodes": len(X0), "updates": updates, "rate": updates / best if updates else None, "cpu_rate": updates / cpu if updates and cpu else None,
        "before": (q0.min(), q0.mean(), int((q0 <= 0).sum())), "after": (q.min(), q.mean(), int((q <= 0).sum())), "moved": moved, "seconds": best,
    }


def chain_case(surface, skeleton, overrides):
    """Run the default chain up to mesh_transfinite without untangling; return its context."""
    import vmesh

    ov = {"mesh_transfinite.untangle": False, **{f"mesh_transfinite.{k}": v for k, v in overrides.items()}}
    chain = vmesh.FilterChain.load("default").with_overrides(ov)
    names = [s.filter for s in chain.steps]
    chain.steps = chain.steps[: names.index("mesh_transfinite") + 1]
    return chain.run(surface=str(surface), skeleton=str(skeleton) if skeleton else None)


def chain_rows(case, ctx, repeat):
    """Both optimisers on the raw mesh of ``ctx`` (as mesh_transfinite calls them)."""
    from vmesh.filters.mesh_filters import _light_pass, _untangle
    from vmesh.geometry.projection import wall_projector

    m = ctx.mesh
    projector = wall_projector(ctx.surface, ctx.caps)
    cells = m.cells[:, corner_index(m.order)]  # tensor corner order
    out = []
    for name in ("local", "local + light pass", "lbfgs"):
        sm = SimpleNamespace(points=m.points.copy(), cells=m.cells, order=m.order, boundary_faces=m.boundary_faces, boundary_ids=m.boundary_ids, on_wall=m.on_wall)
        captured = {}

        def run(sm=sm, name=name):
            sm.points[:] = m.points
            for key in ("untangle", "light_pass"):
                ctx.report.sections.pop(key, None)
            _untangle(ctx, sm, projector, ctx.sdf, 0.3, 0.2, name.split()[0], 0.5)
            captured.update(ctx.report.sections.get("untangle", {}))
            if name.endswith("light pass"):
                _light_pass(ctx, sm, projector, ctx.sdf, 0.95, m.node_distribution)
                captured["updates"] = captured.get("updates", 0) + ctx.report.sections["light_pass"]["updates"]
            return sm.points.copy(), captured

        out.append(row(case, name, m.points, cells, run, repeat if name.startswith("local") else 1))
    return out


def fmt_row(r):
    b, a = r["before"], r["after"]
    rate = f"{r['rate']:,.0f} ({r['cpu_rate']:,.0f})" if r["rate"] else "-"
    upd = f"{r['updates']:,}" if r["updates"] else "-"
    return f"| {r['case']} | {r['optimiser']} | {r['nodes']:,} | {upd} | {rate} | {b[0]:.3f} / {b[1]:.4f} ({b[2]}) | {a[0]:.3f} / {a[1]:.4f} ({a[2]}) | {r['moved']:,} | {r['seconds']:.2f} |"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="folded cylinders only")
    ap.add_argument("--repeat", type=int, default=3, help="runs per row of the local optimiser (best time kept)")
    args = ap.parse_args(argv)
    head = "| case | optimiser | nodes | updates | updates/s (per CPU-s) | SJ min / mean before (invalid) | after | nodes moved | s |\n|---|---|---|---|---|---|---|---|---|"
    rows = []
    # warm-up: compile the kernels outside the timings
    sm, kw = cylinder_case(1)
    optimise(fold(sm, 3), sm.cells, 1, **kw)
    for scale in (1, 2, 4):
        sm, kw = cylinder_case(scale)
        X0 = fold(sm, 6 * scale)
        rows.append(row(f"folded cylinder x{scale}", "local", X0, sm.cells, lambda: optimise(X0, sm.cells, 1, **kw), args.repeat))
        print(fmt_row(rows[-1]), flush=True)
        X1 = jitter(sm, kw)
        rows.append(row(f"jittered cylinder x{scale}, light pass on all", "local", X1, sm.cells, lambda: optimise(X1, sm.cells, 1, untangle_below=0.0, smooth_below=0.99, smooth_sweeps=3, **kw), args.repeat))
        print(fmt_row(rows[-1]), flush=True)
        sm, kw = cylinder_case(scale, curved=True)
        X2 = nudge(sm, kw)
        rows.append(row(f"curved cylinder x{scale}, default light pass", "local", X2, sm.cells, lambda: optimise(X2, sm.cells, 1, untangle_below=0.0, smooth_below=0.95, **kw), args.repeat))
        print(fmt_row(rows[-1]), flush=True)
    if not args.quick:
        import _common as C

        cases = [(n, C.SYNTHETIC / n / "surface.ply", C.SYNTHETIC / n / "skeleton.json", {}) for n in ("two_junctions", "y_bifurcation")]
        root = Path(os.environ.get("VMESH_REAL_DATA", ""))
        if (root / "ica_swc_surface.vtp").exists() and (root / "ica_centerline.swc").exists():
            cases.append(("real ICA, vascularmd resolution", root / "ica_swc_surface.vtp", root / "ica_centerline.swc", ICA))
        else:
            print("note: real ICA skipped (set VMESH_REAL_DATA to the folder holding ica_swc_surface.vtp and ica_centerline.swc)")
        for name, surface, skeleton, ov in cases:
            print(f"{name}: meshing without untangling ...", flush=True)
            ctx = chain_case(surface, skeleton, ov)
            for r in chain_rows(name, ctx, args.repeat):
                rows.append(r)
                print(fmt_row(r), flush=True)
    print()
    print(head)
    for r in rows:
        print(fmt_row(r))
    return 0


if __name__ == "__main__":
    sys.exit(main())
