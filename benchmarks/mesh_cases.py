"""Every synthetic and every real case through the default chain: counts, time per filter, quality.

For each case (data_synthetic/* with its known skeleton; every real surface of
``vmesh.realdata.REAL_CASES`` with its centerline, or an extracted skeleton when it has
none): skeleton nodes (input -> resampled), blocks, elements, nodes, seconds per stage,
scaled Jacobian min / mean / 1st percentile, invalid elements and the boundary distance
(wall-face centres to the input surface, relative to the local radius).

Then the two speed targets of the issue:

* the 500-600-node synthetic tree (``cerebral_tree``, 100k triangles) end to end at default
  refinement in under 30 s (the default-chain row of that case; wall time of the chain);
* >= 10^6 mesh nodes per second through ``mesh_transfinite`` on a mesh of >= 10^6 nodes
  (``cerebral_tree`` with ``mesh_transfinite.refinement=2``, exports left out).

Runs use ``compute_quality.fail_on_invalid=false``: invalid elements are counted, and any
exception is a row with its reason. The first case also warms up numba's JIT.

Usage::

    python benchmarks/mesh_cases.py                   # everything (~5 min on 2 cores)
    python benchmarks/mesh_cases.py --quick           # three small cases, no throughput run
    python benchmarks/mesh_cases.py --cases y_bifurcation carotid --refinement 3

Writes ``benchmarks/results/mesh_cases.json`` and ``.md`` and ``mesh_cases_sj.png``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import _common as C  # noqa: E402

QUICK = ["straight_tube", "y_bifurcation", "real_carotid"]
TREE = "cerebral_tree"


def all_cases() -> list[tuple[str, str, Path, Path | None]]:
    """``(name, kind, surface, skeleton)`` for every synthetic and real case."""
    out = [(n, "synthetic", C.SYNTHETIC / n / "surface.ply", C.SYNTHETIC / n / "skeleton.json") for n in C.synthetic_cases()]
    out += [(f"real_{k}", "real", s, c) for k, s, c in C.real_cases()]
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", nargs="+", help="case names (synthetic folder names or real keys); default: all")
    ap.add_argument("--quick", action="store_true", help=f"only {', '.join(QUICK)}, no throughput run")
    ap.add_argument("--refinement", type=int, default=2, help="mesh_transfinite.refinement of the throughput run")
    ap.add_argument("--no-throughput", action="store_true", help="leave out the >=10^6-node throughput run")
    ap.add_argument("--name", default="mesh_cases", help="results file stem")
    args = ap.parse_args(argv)

    cases = all_cases()
    wanted = args.cases or (QUICK if args.quick else None)
    if wanted:
        known = {c[0] for c in cases}
        for w in wanted:
            if w not in known:
                print(f"note: unknown or unavailable case {w!r} skipped (known: {', '.join(sorted(known))})")
        cases = [c for c in cases if c[0] in wanted]
    print(f"{len(cases)} cases; {C.load_line()}", flush=True)
    rows = []
    for i, (name, kind, surface, skeleton) in enumerate(cases):
        print(f"[{i + 1}/{len(cases)}] {name} ({kind}, skeleton {'given' if skeleton else 'extracted'}) ...", flush=True)
        row = C.mesh_row(name, surface, skeleton, label="default")
        row["kind"] = kind
        rows.append(row)
        print(C.progress_line(row), flush=True)

    throughput = None
    if not (args.quick or args.no_throughput) and (not args.cases or TREE in args.cases):
        ov = {"mesh_transfinite.refinement": args.refinement}
        # the second run leaves out the untangling pass: the transfinite maps alone
        runs = [(ov, f"refinement={args.refinement}", "(no exports)"),
                ({**ov, "mesh_transfinite.untangle": False}, f"refinement={args.refinement}, no untangle", "mesh_transfinite.untangle=false")]
        made = []
        for overrides, label, note in runs:
            print(f"[throughput] {TREE} with mesh_transfinite.refinement={args.refinement} {note} ...", flush=True)
            row = C.mesh_row(TREE, C.SYNTHETIC / TREE / "surface.ply", C.SYNTHETIC / TREE / "skeleton.json",
                             overrides=overrides, exports=False, label=label)
            row["kind"] = "synthetic"
            rows.append(row)
            print(C.progress_line(row), flush=True)
            made.append(row)
        throughput, bare = made

    head = ["case", "run", "skel nodes in→used", "blocks", "elements", "nodes", "pre s", "sdf s", "skel s", "blocks s",
            "hex s", "quality s", "export s", "chain s", "cpu s", "untangled nodes", "SJ min", "SJ mean", "SJ p1", "invalid", "bdist max/mean %R", "status"]
    lines = []
    for r in rows:
        st = r.get("stage_s", {})
        si, su = r.get("skeleton_in", {}).get("nodes"), r.get("skeleton_used", {}).get("nodes")
        lines.append([
            r["case"], r["run"], f"{si if si is not None else 'extr.'}→{su if su is not None else '-'}",
            C.fmt(r.get("blocks")), C.fmt(r.get("elements")), C.fmt(r.get("nodes")),
            *[C.fmt(st.get(k), ".2f") for k in C.STAGE_ORDER], C.fmt(r.get("chain_s"), ".1f"), C.fmt(r.get("cpu_s"), ".1f"),
            C.fmt((r.get("untangle") or {}).get("moved", 0) if "elements" in r else None),
            C.fmt(r.get("sj_min"), ".3f"), C.fmt(r.get("sj_mean"), ".3f"), C.fmt(r.get("sj_p01"), ".3f"), C.fmt(r.get("invalid")),
            f"{C.fmt(100 * r['bdist_max_rel'], '.2f')}/{C.fmt(100 * r['bdist_mean_rel'], '.2f')}" if "bdist_max_rel" in r else "-",
            "ok" if r["status"] == "ok" else f"FAILED: {r['error'][:120]}",
        ])
    print()
    md = C.table(head, lines)

    targets = []
    tree = next((r for r in rows if r["case"] == TREE and r["run"] == "default"), None)
    if tree is not None and tree["status"] == "ok":
        targets.append({"target": "cerebral_tree end to end < 30 s (default refinement)", "measured_s": tree["chain_s"],
                        "met": tree["chain_s"] < 30.0})
    if throughput is not None and throughput["status"] == "ok":
        nps = throughput.get("transfinite_nodes_per_s", 0)
        targets.append({"target": ">= 1e6 nodes/s through mesh_transfinite on >= 1e6 nodes",
                        "nodes": throughput.get("nodes"), "mesh_transfinite_s": throughput["step_s"].get("mesh_transfinite"),
                        "nodes_per_s": nps, "met": bool(nps >= 1e6 and throughput.get("nodes", 0) >= 1e6)})
    elif throughput is not None:
        targets.append({"target": ">= 1e6 nodes/s through mesh_transfinite", "met": False, "error": throughput["error"]})
    if throughput is not None and bare["status"] == "ok":
        nps = bare.get("transfinite_nodes_per_s", 0)
        targets.append({"target": "(diagnostic) the same with mesh_transfinite.untangle=false",
                        "nodes": bare.get("nodes"), "mesh_transfinite_s": bare["step_s"].get("mesh_transfinite"),
                        "nodes_per_s": nps, "met": bool(nps >= 1e6 and bare.get("nodes", 0) >= 1e6)})
    quality = [{"case": r["case"], "run": r["run"], "misses": C.check_targets(r)} for r in rows]
    tlines = [f"- {t['target']}: " + (f"{t.get('measured_s', '')} s" if "measured_s" in t else
              f"{t.get('nodes_per_s', 0):,} nodes/s ({t.get('nodes', 0):,} nodes in {t.get('mesh_transfinite_s', 0):.2f} s)" if "nodes_per_s" in t else t.get("error", ""))
              + (" — met" if t["met"] else " — MISSED") for t in targets]
    qlines = [f"- {q['case']} ({q['run']}): " + "; ".join(q["misses"]) for q in quality if q["misses"]]
    print("\n" + "\n".join(tlines or ["(no speed target measured)"]))
    print("\nquality targets (0 invalid, min SJ >= 0.2, mean >= 0.85): " + ("all rows pass" if not qlines else "misses:\n" + "\n".join(qlines)))

    png = C.histogram_figure([(f"{r['case']} ({r['run']}): {r.get('elements', 0):,} hexes", [("vmesh", r.get("_sj"))]) for r in rows],
                             C.RESULTS / f"{args.name}_sj.png", title="Scaled Jacobian, default chain")
    header = (f"# mesh_cases\n\n`python benchmarks/mesh_cases.py` — {time.strftime('%Y-%m-%d %H:%M')}, {C.load_line()} "
              "(other jobs ran concurrently: times are noisy). Default chain, `compute_quality.fail_on_invalid=false`. "
              "Stages: pre = repair + cap + decimate, sdf = build_sdf, skel = load/extract + radii + clean + resample, "
              "blocks = build_block_structure, hex = mesh_transfinite, quality = labels + compute_quality, export = file writers. "
              "`chain s` = sum of the filters' wall seconds, `cpu s` = CPU seconds of the run (all threads, less sensitive to the other jobs); "
              "`untangled nodes` = nodes moved by mesh_transfinite's untangling pass; bdist = wall-face centre distance to the input surface / local radius.\n")
    footer = "\n\n## Targets\n\n" + "\n".join(tlines) + "\n\nQuality (0 invalid, min SJ ≥ 0.2, mean ≥ 0.85): " + \
             ("all rows pass.\n" if not qlines else "\n\n" + "\n".join(qlines) + "\n")
    js, mdp = C.write_results(args.name, rows, md + footer + (f"\n![histograms]({png.name})\n" if png else ""), header,
                              {"targets": targets, "quality_misses": quality})
    print(f"\nwritten {js.relative_to(C.ROOT)}, {mdp.name}" + (f", {png.name}" if png else ""))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
