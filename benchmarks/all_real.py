"""Every real surface through the default chain, with its centerline and with an extracted skeleton.

Every surface file of the real data set ($VMESH_REAL_DATA or ../shared/data/real; the
surfaces of ``vmesh.realdata.REAL_CASES`` plus any other .stl/.vtp/.vtk/.ply/.obj there
that is not a centerline) runs twice where it has a centerline: ``skeleton=given`` (the
centerline file) and ``skeleton=extracted`` (``extract_skeleton`` from the SDF); surfaces
without one run extracted only. Any failure is a row with the reason, not a crash.
Columns as in paper_cases.py; histograms side by side in one PNG.

Usage::

    python benchmarks/all_real.py                    # every real surface (~5 min)
    python benchmarks/all_real.py --quick            # carotid only
    python benchmarks/all_real.py --cases carotid aneurysm --skeleton extracted

Writes ``benchmarks/results/all_real.json``, ``.md`` and ``all_real_sj.png``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import _common as C  # noqa: E402
from vmesh import realdata  # noqa: E402

SURFACE_EXT = {".stl", ".vtp", ".vtk", ".ply", ".obj"}


def real_surfaces() -> list[tuple[str, Path, Path | None]]:
    d = realdata.real_data_dir()
    if d is None:
        print(f"skipped: {realdata.missing_reason()}")
        return []
    out = [(k, s, c) for k, s, c in C.real_cases()]
    known = {p.name for _, s, c in out for p in (s, c) if p is not None}
    for p in sorted(d.iterdir()):
        if p.suffix.lower() in SURFACE_EXT and p.name not in known and "centerline" not in p.name.lower():
            out.append((p.stem, p, None))  # a surface not listed in REAL_CASES
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", nargs="+", help="real case keys (carotid, aorta_simvascular, ...) or file stems")
    ap.add_argument("--quick", action="store_true", help="carotid only")
    ap.add_argument("--skeleton", nargs="+", default=["given", "extracted"], choices=["given", "extracted"])
    ap.add_argument("--name", default="all_real")
    args = ap.parse_args(argv)
    cases = real_surfaces()
    if args.quick:
        cases = [c for c in cases if c[0] == "carotid"]
    if args.cases:
        cases = [c for c in cases if c[0] in args.cases or c[1].stem in args.cases]
    print(f"{len(cases)} real surfaces; {C.load_line()}", flush=True)
    rows = []
    for i, (name, surface, centerline) in enumerate(cases):
        for mode in args.skeleton:
            if mode == "given" and centerline is None:
                rows.append({"case": name, "run": "skeleton=given", "skeleton_source": "given", "status": "n/a",
                             "error": "no centerline file in the data set", "surface_file": surface.name, "wall_s": 0.0})
                continue
            print(f"[{i + 1}/{len(cases)}] {name} ({surface.name}) skeleton={mode} ...", flush=True)
            row = C.mesh_row(name, surface, centerline if mode == "given" else None, label=f"skeleton={mode}")
            row["surface_file"] = surface.name
            if centerline is not None:
                row["centerline_file"] = centerline.name
            rows.append(row)
            print(C.progress_line(row), flush=True)

    head = ["case", "skeleton", "surface file", "skel nodes in→used", "surf nodes", "surf elements", "blocks", "elements", "nodes",
            "pre s", "sdf s", "skel s", "blocks s", "hex s", "quality s", "export s", "chain s", "SJ min", "SJ mean", "SJ p1",
            "invalid", "bdist max/mean %R", "status"]
    lines = []
    for r in rows:
        st = r.get("stage_s", {})
        si, su = (r.get("skeleton_in") or {}).get("nodes"), (r.get("skeleton_used") or {}).get("nodes")
        status = "ok" if r["status"] == "ok" else ("n/a: " if r["status"] == "n/a" else "FAILED: ") + r["error"][:140]
        lines.append([
            r["case"], r["run"].split("=")[-1], r.get("surface_file", ""), "-" if r["status"] == "n/a" else f"{si if si is not None else 'extr.'}→{su if su is not None else '-'}",
            C.fmt(r.get("surface_nodes")), C.fmt(r.get("surface_elements")), C.fmt(r.get("blocks")), C.fmt(r.get("elements")),
            C.fmt(r.get("nodes")), *[C.fmt(st.get(k), ".2f") for k in C.STAGE_ORDER], C.fmt(r.get("chain_s"), ".1f"),
            C.fmt(r.get("sj_min"), ".3f"), C.fmt(r.get("sj_mean"), ".3f"), C.fmt(r.get("sj_p01"), ".3f"), C.fmt(r.get("invalid")),
            f"{C.fmt(100 * r['bdist_max_rel'], '.2f')}/{C.fmt(100 * r['bdist_mean_rel'], '.2f')}" if "bdist_max_rel" in r else "-",
            status,
        ])
    print()
    md = C.table(head, lines)
    misses = [f"- {r['case']} ({r['run']}): " + "; ".join(m) for r in rows if r["status"] != "n/a" and (m := C.check_targets(r))]
    print("\nquality targets (0 invalid, min SJ >= 0.2, mean >= 0.85): " + ("all rows pass" if not misses else "misses:\n" + "\n".join(misses)))
    panels = []
    for name, surface, _ in cases:
        series = [(r["run"], r.get("_sj")) for r in rows if r["case"] == name]
        panels.append((f"{name} ({surface.name})", series))
    png = C.histogram_figure(panels, C.RESULTS / f"{args.name}_sj.png", title="Scaled Jacobian, real surfaces (given vs extracted skeleton)")
    # duplicates: same shape as paper_cases.py's ending (its own header text, then the shared _common writer)
    header = (f"# all_real\n\n`python benchmarks/all_real.py` — {time.strftime('%Y-%m-%d %H:%M')}, {C.load_line()} "
              "(other jobs ran concurrently: times are noisy). Default chain, `compute_quality.fail_on_invalid=false`; "
              "`given` = the data set's centerline file, `extracted` = `extract_skeleton`. Columns as in paper_cases.md.\n")
    C.write_quality_results(args.name, rows, md, misses, png, header)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
