"""vmesh's block-structured hexahedra against unstructured tetrahedral meshes of the same surfaces.

For each surface (by default the paper cases' analogues of paper_cases.py; ``--real`` adds
every real surface) vmesh's default chain runs first and gives the resolution to match:

* ``h`` = mean edge length of vmesh's wall faces (the surface edge length);
* the boundary layer: vmesh resolves it by grading ``elements_layer`` (3) hexahedra across a
  block ring of ``layer_thickness`` (0.3) x the wall distance, the first one
  ``first_layer`` (0.02) x the local radius thick. The prism baseline uses the same number
  of layers, the same first-layer thickness and the same total thickness (geometric
  growth), taken at the median skeleton radius (gmsh extrudes a uniform thickness).

Then, on vmesh's repaired and capped fine surface:

* ``gmsh tet``: the wall alone (vmesh's caps removed: on some real surfaces they cut
  the wall), classifySurfaces + createGeometry, the open ends closed by gmsh plane
  surfaces, one volume, mesh size ``h`` everywhere, Frontal-Delaunay 2D + HXT 3D,
  ``General.NumThreads`` 2;
* ``gmsh BL+tet``: the same wall, ``extrudeBoundaryLayer`` inward with the prism layers
  above (recombined: prisms), the holes closed by plane surfaces, tetrahedra inside; when
  the extruded layer folds (the 3D mesher reports intersecting facets) it is retried once
  with half the total thickness and the same first layer (``half thickness``) (gmsh's ``BoundaryLayer`` *field* is 2D-only, so extrusion is the way for 3D
  discrete geometry, as in gmsh's examples/api/aneurysm.py);
* ``TetGen``: tetgen (pyvista's wrapper) on gmsh's surface triangles of the ``gmsh tet``
  run, quality ``-q1.5`` and max volume of a regular tetrahedron of edge ``h``; no
  boundary layer.

Each mesher runs in a subprocess with a time limit (``--timeout``); a failure or a timeout
is a row with the reason. The claim to check: for the same boundary-layer resolution the
structured mesh needs far fewer elements (compare vmesh with ``gmsh BL+tet``).

Usage::

    python benchmarks/vs_unstructured.py              # paper cases (~8 min)
    python benchmarks/vs_unstructured.py --quick      # the two aneurysms
    python benchmarks/vs_unstructured.py --cases cerebral_tree --real --timeout 300

Writes ``benchmarks/results/vs_unstructured.json`` and ``.md``.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import _common as C  # noqa: E402
import paper_cases  # noqa: E402

WORKER = Path(__file__).resolve().parent / "_gmsh_worker.py"


def write_stl(path: Path, v: np.ndarray, f: np.ndarray) -> Path:
    tri = v[f]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.linalg.norm(n, axis=1, keepdims=True) + 1e-300
    rec = np.zeros(len(f), dtype=[("n", "<f4", 3), ("v", "<f4", (3, 3)), ("a", "<u2")])
    rec["n"], rec["v"] = n, tri
    with open(path, "wb") as fh:
        fh.write(b"vmesh benchmark".ljust(80, b" "))
        fh.write(np.uint32(len(f)).tobytes())
        fh.write(rec.tobytes())
    return path


def layer_heights(first: float, total: float, n: int) -> list[float]:
    """Cumulative heights of ``n`` geometric layers, the first ``first`` thick, ``total`` in all."""
    if n == 1:
        return [total]
    target = total / first
    lo, hi = 1.0, 100.0
    for _ in range(200):
        g = 0.5 * (lo + hi)
        s = (g ** n - 1) / (g - 1) if g != 1 else n
        lo, hi = (g, hi) if s < target else (lo, g)
    t = first * g ** np.arange(n)
    return np.cumsum(t * total / t.sum()).tolist()


def run_worker(args: list[str], timeout: float) -> dict:
    t0 = time.perf_counter()
    try:
        p = subprocess.run([sys.executable, str(WORKER), *map(str, args)], capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return {"status": "failed", "error": f"time limit {timeout:.0f} s reached", "wall_s": round(time.perf_counter() - t0, 2)}
    wall = round(time.perf_counter() - t0, 2)
    for line in p.stdout.splitlines()[::-1]:
        if line.startswith("RESULT "):
            return {"status": "ok", "wall_s": wall, **json.loads(line[7:])}
    tail = [ln.strip() for ln in (p.stderr + "\n" + p.stdout).strip().splitlines() if ln.strip()]
    final = next((ln for ln in tail[::-1] if ln.startswith(("Exception:", "Error", "RuntimeError", "MemoryError"))), tail[-1] if tail else "")
    cause = next((ln for ln in tail if ln.startswith(("PLC Error", "Error   :", "Error:"))), "")
    err = final + (f" ({cause})" if cause and cause not in final else "") or f"exit status {p.returncode}"
    return {"status": "failed", "error": f"exit {p.returncode}: {err[:300]}", "wall_s": wall}


def tetgen_available() -> str:
    try:
        import tetgen  # noqa: F401
    except Exception as exc:  # not installed: a reason, not a crash
        return f"tetgen not importable ({type(exc).__name__}: {exc}); pip install tetgen"
    return ""


def compare(name: str, surface, skeleton, args, tmp: Path) -> list[dict]:
    print(f"    vmesh ...", flush=True)
    vm = C.mesh_row(name, surface, skeleton, keep_context=True, label="vmesh")
    ctx = vm.pop("_ctx", None)
    vm.pop("_sj", None)
    rows = [{"case": name, "mesher": "vmesh (hex)", "status": vm["status"], "error": vm["error"], "elements": vm.get("elements"),
             "nodes": vm.get("nodes"), "seconds": vm.get("chain_s"), "hexahedra": vm.get("elements"), "blocks": vm.get("blocks"),
             "wall_faces": vm.get("wall_edge", {}).get("wall_faces"), "sj_min": vm.get("sj_min"), "sj_mean": vm.get("sj_mean"),
             "invalid": vm.get("invalid")}]
    print(C.progress_line(vm), flush=True)
    if vm["status"] != "ok" or ctx is None or ctx.mesh is None:
        return rows
    params = {s.filter: s.params for s in C.FilterChain.load("default").resolved().steps}
    mt, bb = params["mesh_transfinite"], params["build_block_structure"]
    h = vm["wall_edge"]["mean"]
    r_med = float(np.median(ctx.skeleton.radii))
    n_layers = int(mt["elements_layer"] * mt["refinement"])
    first = mt["first_layer"] * r_med
    total = bb["layer_thickness"] * r_med
    heights = layer_heights(first, total, n_layers)
    setting = {"h": round(h, 4), "median_radius": round(r_med, 4), "bl_layers": n_layers, "bl_first": round(first, 5),
               "bl_total": round(total, 4), "bl_heights": [round(x, 5) for x in heights]}
    rows[0].update(setting)
    s = ctx.surface
    cap_faces = np.concatenate([c.faces for c in ctx.caps]) if ctx.caps else np.zeros(0, np.int64)
    keep = np.ones(s.n_faces, bool)
    keep[cap_faces] = False
    wall = write_stl(tmp / f"{name}_wall.stl", s.vertices, s.faces[keep])
    surf_npz = tmp / f"{name}_gmsh_surface.npz"
    jobs = [("gmsh tet", ["tet", wall, h, args.threads, surf_npz], setting),
            ("gmsh BL+tet", ["bl", wall, h, args.threads, ",".join(f"{-x:.6g}" for x in heights)], setting)]
    while jobs:
        label, job, st = jobs.pop(0)
        print(f"    {label} (h = {h:.3g}) ...", flush=True)
        r = {"case": name, "mesher": label, **st, **run_worker(job, args.timeout)}
        rows.append(r)
        print(f"      {r['status']}: {r.get('elements', '-')} elements, {r.get('nodes', '-')} nodes, {r['wall_s']} s {r.get('error', '')}", flush=True)
        if label == "gmsh BL+tet" and r["status"] != "ok":
            # the extruded layer folded (thin or tightly curved vessels): same first layer, half the total thickness
            half = layer_heights(first, total / 2, n_layers)
            st2 = {**setting, "bl_total": round(total / 2, 4), "bl_heights": [round(x, 5) for x in half]}
            jobs.append(("gmsh BL+tet (half thickness)", ["bl", wall, h, args.threads, ",".join(f"{-x:.6g}" for x in half)], st2))
    why = tetgen_available()
    if why:
        rows.append({"case": name, "mesher": "TetGen", "status": "skipped", "error": why})
    elif not surf_npz.exists():
        rows.append({"case": name, "mesher": "TetGen", "status": "skipped", "error": "no gmsh surface mesh to start from (gmsh tet failed)"})
    else:
        print("    TetGen ...", flush=True)
        r = {"case": name, "mesher": "TetGen", **setting, **run_worker(["tetgen", surf_npz, h], args.timeout)}
        rows.append(r)
        print(f"      {r['status']}: {r.get('elements', '-')} elements, {r.get('nodes', '-')} nodes, {r['wall_s']} s {r.get('error', '')}", flush=True)
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", nargs="+", help="paper case names (see paper_cases.py) or, with --real, real keys")
    ap.add_argument("--quick", action="store_true", help="the two aneurysm cases only")
    ap.add_argument("--real", action="store_true", help="also every real surface of the data set")
    ap.add_argument("--timeout", type=float, default=240.0, help="seconds per mesher run")
    ap.add_argument("--threads", type=int, default=2, help="gmsh General.NumThreads")
    ap.add_argument("--name", default="vs_unstructured")
    ap.add_argument("--from-json", help="only re-render the tables of an earlier results JSON (no meshing)")
    args = ap.parse_args(argv)
    if args.from_json:
        import json

        data = json.loads(Path(args.from_json).read_text())
        render(data["rows"], args.name, data.get("load", ""))
        return 0
    cases = [(n, make, sk) for n, paper, how, make, sk in paper_cases.case_list()]
    if args.real:
        done = {"aneurysm", "coarctation"}  # their real surfaces are already paper-case analogues
        cases += [(k, (lambda s=s: s), c) for k, s, c in C.real_cases() if k not in done]
    if args.quick:
        cases = [c for c in cases if c[0].startswith("aneurysm")]
    if args.cases:
        cases = [c for c in cases if c[0] in args.cases]
    print(f"{len(cases)} cases; {C.load_line()}", flush=True)
    rows = []
    with tempfile.TemporaryDirectory(prefix="vmesh-vs-") as tmpd:
        for i, (name, make, skeleton) in enumerate(cases):
            print(f"[{i + 1}/{len(cases)}] {name} ...", flush=True)
            try:
                surface = make()
            except Exception as exc:
                rows.append({"case": name, "mesher": "-", "status": "failed", "error": f"surface preparation: {type(exc).__name__}: {exc}"})
                continue
            rows += compare(name, surface, skeleton, args, Path(tmpd))

    render(rows, args.name)
    return 0


def render(rows: list[dict], name: str, load: str = "") -> None:
    """Print the table and write the JSON and Markdown results."""
    head = ["case", "mesher", "elements", "nodes", "hex/prism/tet", "elements / vmesh", "nodes / vmesh", "seconds",
            "h", "BL layers: first/total", "inverted (SJ ≤ 0)", "status"]
    lines = []
    base = {r["case"]: r for r in rows if r["mesher"].startswith("vmesh") and r["status"] == "ok"}
    for r in rows:
        b = base.get(r["case"])
        el, nd = r.get("elements"), r.get("nodes")
        kinds = f"{C.fmt(r.get('hexahedra', 0))}/{C.fmt(r.get('prisms', 0))}/{C.fmt(r.get('tetrahedra', 0))}" if el else "-"
        bl = "graded hex" if r["mesher"].startswith("vmesh") else ("prisms" if r["mesher"].startswith("gmsh BL") else "none")
        if "bl_first" in r and bl != "none":
            bl += f" {r['bl_layers']}: {r['bl_first']:.3g}/{r['bl_total']:.3g}"
        lines.append([
            r["case"], r["mesher"], C.fmt(el), C.fmt(nd), kinds,
            f"{el / b['elements']:.2f}" if el and b else "-", f"{nd / b['nodes']:.2f}" if nd and b else "-",
            C.fmt(r.get("seconds"), ".1f"), C.fmt(r.get("h"), ".3g"), bl,
            C.fmt(r.get("invalid") if r["mesher"].startswith("vmesh") else r.get("prism_invalid", "-" if r.get("status") != "ok" else "n/c")),
            r["status"] + (f": {r['error'][:120]}" if r.get("error") else ""),
        ])
    print()
    md = C.table(head, lines)
    claim = []
    for case, b in base.items():
        blr = next((r for r in rows if r["case"] == case and r["mesher"].startswith("gmsh BL") and r["status"] == "ok"), None)
        tet = next((r for r in rows if r["case"] == case and r["mesher"] == "gmsh tet" and r["status"] == "ok"), None)
        text = f"- {case}: "
        if blr:
            text += (f"{blr['mesher']} needs {blr['elements'] / b['elements']:.1f}x the elements and "
                     f"{blr['nodes'] / b['nodes']:.1f}x the nodes of vmesh for the same first-layer thickness and layer count"
                     + (f" ({blr['prism_invalid']} of its prisms inverted)" if blr.get("prism_invalid") else ""))
        else:
            text += "no boundary-layer tetrahedral mesh to compare with (gmsh's extruded layer folded)"
        if tet:
            text += f"; without a boundary layer gmsh needs {tet['elements'] / b['elements']:.1f}x the elements, {tet['nodes'] / b['nodes']:.2f}x the nodes"
        claim.append(text)
    print("\n" + "\n".join(claim))
    header = (f"# vs_unstructured\n\n`python benchmarks/vs_unstructured.py` — {time.strftime('%Y-%m-%d %H:%M')}, {load or C.load_line()} "
              "(other jobs ran concurrently: times are noisy). `h` = mean edge of vmesh's wall faces, used as gmsh's mesh size "
              "and for TetGen's max volume; the prism layers have vmesh's layer count, first-layer thickness and total "
              "thickness at the median skeleton radius. `seconds`: vmesh = sum of the default chain's filters; gmsh = "
              "classification + geometry + 2D + 3D meshing (2 threads); TetGen = tetrahedralisation of gmsh's surface mesh.\n")
    js, mdp = C.write_results(name, rows, md + "\n\n## The paper's claim\n\n" + "\n".join(claim) + "\n", header)
    print(f"\nwritten {js.relative_to(C.ROOT)}, {mdp.name}")


if __name__ == "__main__":
    raise SystemExit(main())
